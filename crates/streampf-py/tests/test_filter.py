"""ParticleFilter with your own model: a Python likelihood on the CPU and the same model in WGSL
on the GPU, on a toy problem with a known answer, and the mistakes it reports."""

import numpy as np
import pytest

import streampf

TARGETS, PARTICLES = 4, 512
NOISE = 0.2  # the observation's standard deviation

WGSL = """
struct Observation { x: f32, y: f32 }
struct Constants { inverse_variance: f32 }

fn log_likelihood(x: State, z: Observation, c: Constants) -> f32 {
    let dx = x[0] - z.x;
    let dy = x[1] - z.y;
    return -0.5 * (dx * dx + dy * dy) * c.inverse_variance;
}
"""


def python_likelihood(particles, observations):
    d = particles[..., :2] - observations[:, None, :]
    return -0.5 * (d**2).sum(axis=-1) / NOISE**2


def scenario(steps=15, seed=3):
    """Targets moving on circles, observed in position with Gaussian noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps)[:, None]
    phase = np.arange(TARGETS)[None, :]
    truth = np.stack([np.cos(0.1 * t + phase), np.sin(0.1 * t + phase)], axis=-1).astype(np.float32)
    observations = (truth + rng.normal(0, NOISE, truth.shape)).astype(np.float32)
    initial = (truth[0][:, None, :] + rng.normal(0, 0.5, (TARGETS, PARTICLES, 2))).astype(np.float32)
    return truth, observations, initial


def run(filter_, observations):
    return np.stack([filter_.step(z)["estimate"] for z in observations])


def test_a_python_likelihood_tracks_the_targets():
    truth, observations, initial = scenario()
    pf = streampf.ParticleFilter(initial, sigma=[0.1, 0.1], likelihood=python_likelihood, backend="cpu")
    estimates = run(pf, observations)
    error = np.linalg.norm(estimates - truth, axis=-1)[3:].mean()
    raw = np.linalg.norm(observations - truth, axis=-1)[3:].mean()
    assert error < 0.8 * raw, (error, raw)
    states, log_weights = pf.particles()
    assert states.shape == (TARGETS, PARTICLES, 2) and log_weights.shape == (TARGETS, PARTICLES)


@pytest.mark.parametrize("resampler", ["multinomial", "stratified", "systematic", "residual", "metropolis", "rejection"])
def test_every_resampler_by_name(resampler):
    truth, observations, initial = scenario(steps=6)
    pf = streampf.ParticleFilter(
        initial, sigma=[0.1, 0.1], likelihood=python_likelihood, resampler=resampler, backend="cpu"
    )
    estimates = run(pf, observations)
    assert np.linalg.norm(estimates - truth, axis=-1).mean() < 0.3


def test_the_wgsl_model_on_the_gpu_agrees_with_the_python_twin(gpu_backend):
    truth, observations, initial = scenario()
    gpu = streampf.ParticleFilter(
        initial, sigma=[0.1, 0.1], wgsl=WGSL, observation_size=2,
        constants=np.array([1 / NOISE**2], np.float32), **gpu_backend,
    )
    cpu = streampf.ParticleFilter(initial, sigma=[0.1, 0.1], likelihood=python_likelihood, backend="cpu")
    # The same random numbers: the first step's estimates agree to f32 rounding.
    first_gpu, first_cpu = gpu.step(observations[0]), cpu.step(observations[0])
    np.testing.assert_allclose(first_gpu["estimate"], first_cpu["estimate"], atol=1e-4)
    np.testing.assert_allclose(first_gpu["ess"], first_cpu["ess"], rtol=1e-3)
    later = run(gpu, observations[1:])
    error = np.linalg.norm(later - truth[1:], axis=-1)[2:].mean()
    raw = np.linalg.norm(observations[1:] - truth[1:], axis=-1)[2:].mean()
    assert error < 0.8 * raw, (error, raw)


def test_model_mistakes_are_reported(gpu_backend):
    _, observations, initial = scenario(steps=2)
    constants = np.array([1.0], np.float32)
    with pytest.raises(ValueError, match="Observation"):
        streampf.ParticleFilter(initial, sigma=[0.1, 0.1], wgsl=WGSL, observation_size=3, constants=constants, **gpu_backend)
    with pytest.raises(ValueError, match=r"model:\d+"):
        streampf.ParticleFilter(
            initial, sigma=[0.1, 0.1], wgsl=WGSL.replace("dx * dx", "dx * undefined_name"),
            observation_size=2, constants=constants, **gpu_backend,
        )
    pf = streampf.ParticleFilter(initial, sigma=[0.1, 0.1], wgsl=WGSL, observation_size=2, constants=constants, **gpu_backend)
    with pytest.raises(ValueError, match="shape"):
        pf.step(observations[0][:, :1].copy())
    bad = observations[0].copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        pf.step(bad)


def test_python_likelihood_mistakes_are_reported():
    _, observations, initial = scenario(steps=2)

    def make(likelihood):
        return streampf.ParticleFilter(initial, sigma=[0.1, 0.1], likelihood=likelihood, backend="cpu")

    class Oops(Exception):
        pass

    def raises(p, z):
        raise Oops("from the model")

    with pytest.raises(Oops):
        make(raises).step(observations[0])
    with pytest.raises(ValueError, match="shape"):
        make(lambda p, z: np.zeros(PARTICLES)).step(observations[0])
    with pytest.raises(ValueError, match="non-finite"):
        make(lambda p, z: np.full((TARGETS, PARTICLES), np.nan)).step(observations[0])
    # −∞ everywhere is a zero likelihood: the filter says so.
    with pytest.raises(RuntimeError, match="zero"):
        make(lambda p, z: np.full((TARGETS, PARTICLES), -np.inf)).step(observations[0])


def test_bad_construction_is_a_value_error():
    _, _, initial = scenario(steps=1)
    with pytest.raises(ValueError, match="either"):
        streampf.ParticleFilter(initial, sigma=[0.1, 0.1])
    with pytest.raises(ValueError, match="sigma"):
        streampf.ParticleFilter(initial, sigma=[0.1], likelihood=python_likelihood)
    with pytest.raises(ValueError, match="shape"):
        streampf.ParticleFilter(initial[0], sigma=[0.1, 0.1], likelihood=python_likelihood)
    with pytest.raises(ValueError, match="dtype float32"):
        streampf.ParticleFilter(initial.astype(np.float64), sigma=[0.1, 0.1], likelihood=python_likelihood)
    with pytest.raises(ValueError, match="seed must be a whole number >= 0, got -1"):
        streampf.ParticleFilter(initial, sigma=[0.1, 0.1], likelihood=python_likelihood, seed=-1)
    with pytest.raises(ValueError, match="resampler"):
        streampf.ParticleFilter(initial, sigma=[0.1, 0.1], likelihood=python_likelihood, resampler="best")
    with pytest.raises(ValueError, match="WGSL model runs on the GPU"):
        streampf.ParticleFilter(initial, sigma=[0.1, 0.1], wgsl=WGSL, observation_size=2, backend="cpu")


# A 1-D random walk observed with Gaussian noise: linear-Gaussian, so the Kalman filter gives the
# sequence's exact log-likelihood, which each step's log_evidence summed must estimate.
WALK, SEEN = 0.3, 0.5  # the walk's step and the observation's standard deviations
WALK_WGSL = """
struct Observation { y: f32 }
struct Constants { sigma: f32, log_norm: f32 }

fn log_likelihood(x: State, z: Observation, c: Constants) -> f32 {
    let e = (x[0] - z.y) / c.sigma;
    return -0.5 * e * e + c.log_norm;
}
"""
LOG_NORM = -np.log(SEEN * np.sqrt(2 * np.pi))


def walk_likelihood(particles, observations):
    e = (particles[..., 0] - observations[:, None, 0]) / SEEN
    return -0.5 * e**2 + LOG_NORM


def kalman_log_likelihood(ys, mean, variance):
    total = 0.0
    for y in ys:
        variance += WALK**2
        s = variance + SEEN**2
        total -= 0.5 * ((y - mean) ** 2 / s + np.log(2 * np.pi * s))
        gain = variance / s
        mean, variance = mean + gain * (y - mean), (1 - gain) * variance
    return total


def test_log_evidence_sums_to_the_kalman_log_likelihood_on_cpu_and_gpu(gpu_backend):
    filters, particles, steps = 64, 1000, 25
    rng = np.random.default_rng(8)
    walk = np.cumsum(rng.normal(0, WALK, steps))
    ys = (walk + rng.normal(0, SEEN, steps)).astype(np.float32)
    initial = rng.normal(0, 1, (filters, particles, 1)).astype(np.float32)
    # The filters start from their own clouds: the exact answer of each is the Kalman filter's
    # from that cloud's mean and variance.
    exact = np.array([kalman_log_likelihood(ys, c.mean(), c.var()) for c in initial[..., 0]])
    gpu = streampf.ParticleFilter(
        initial, sigma=[WALK], wgsl=WALK_WGSL, observation_size=1,
        constants=np.array([SEEN, LOG_NORM], np.float32), seed=5, **gpu_backend,
    )
    cpu = streampf.ParticleFilter(initial, sigma=[WALK], likelihood=walk_likelihood, seed=5, backend="cpu")
    for name, pf in [("gpu", gpu), ("cpu", cpu)]:
        evidence = np.array([pf.step(np.full((filters, 1), y, np.float32))["log_evidence"] for y in ys])
        assert evidence.shape == (steps, filters) and evidence.dtype == np.float64
        delta = evidence.sum(axis=0) - exact
        # Unbiased in the likelihood, so about −Var/2 in its log; four standard errors.
        expected, standard_error = -delta.var() / 2, delta.std() / np.sqrt(filters)
        assert abs(delta.mean() - expected) <= 4 * standard_error, (name, delta.mean(), delta.std())


def kalman_smoother(ys, mean, variance):
    """Rauch–Tung–Striebel for the random walk: each step's smoothed mean and variance."""
    filtered, predicted = [], []
    for y in ys:
        variance += WALK**2
        predicted.append((mean, variance))
        gain = variance / (variance + SEEN**2)
        mean, variance = mean + gain * (y - mean), (1 - gain) * variance
        filtered.append((mean, variance))
    smoothed = list(filtered)
    for t in range(len(ys) - 2, -1, -1):
        (mf, pf), (mp, pp), (ms, ps) = filtered[t], predicted[t + 1], smoothed[t + 1]
        g = pf / pp
        smoothed[t] = (mf + g * (ms - mp), pf + g * g * (ps - pp))
    return np.array(smoothed)


def test_smoothed_means_match_rauch_tung_striebel_on_cpu_and_gpu(gpu_backend):
    filters, particles, steps = 24, 800, 20
    rng = np.random.default_rng(9)
    ys = (np.cumsum(rng.normal(0, WALK, steps)) + rng.normal(0, SEEN, steps)).astype(np.float32)
    initial = rng.normal(0, 1, (filters, particles, 1)).astype(np.float32)
    exact = np.array([kalman_smoother(ys, c.mean(), c.var()) for c in initial[..., 0]])  # (T, S, 2)
    gpu = streampf.ParticleFilter(
        initial, sigma=[WALK], wgsl=WALK_WGSL, observation_size=1,
        constants=np.array([SEEN, LOG_NORM], np.float32), seed=3, smooth=True, **gpu_backend,
    )
    cpu = streampf.ParticleFilter(
        initial, sigma=[WALK], likelihood=walk_likelihood, seed=3, backend="cpu", smooth=True
    )
    for name, pf in [("gpu", gpu), ("cpu", cpu)]:
        for y in ys:
            pf.step(np.full((filters, 1), y, np.float32))
        s = pf.smoothed()
        assert s["mean"].shape == (steps, filters, 1) and s["mean"].dtype == np.float32
        assert np.all(s["lower"] <= s["mean"]) and np.all(s["mean"] <= s["upper"])
        sd = np.sqrt(exact[..., 1]).T  # (S, T)
        errors = (s["mean"][..., 0] - exact[..., 0].T) / sd
        # Each step's average over the filters within four standard errors (plus 0.02 sd).
        bound = 4 * errors.std(axis=1, ddof=1) / np.sqrt(filters) + 0.02
        assert np.all(np.abs(errors.mean(axis=1)) <= bound), (name, errors.mean(axis=1), bound)
    with pytest.raises(ValueError, match="smooth=True"):
        streampf.ParticleFilter(initial, sigma=[WALK], likelihood=walk_likelihood, backend="cpu").smoothed()


def test_the_evidence_chooses_the_smoothers_motion():
    """A walk filtered with eight times its own step (as a tracker's search is): ``motion="auto"``
    chooses about the walk's own step for every filter (within one candidate of 1/8), and its
    smoothed means lie nearer the truth than those at the filter's motion, near the exact RTS
    smoother's at the walk's own step."""
    filters, particles, steps, wide = 6, 1000, 120, 8 * WALK
    rng = np.random.default_rng(21)
    walk = np.cumsum(rng.normal(0, WALK, steps))
    ys = (walk + rng.normal(0, SEEN, steps)).astype(np.float32)
    initial = rng.normal(0, 1, (filters, particles, 1)).astype(np.float32)
    pf = streampf.ParticleFilter(
        initial, sigma=[wide], likelihood=walk_likelihood, seed=4, backend="cpu", smooth=True
    )
    for y in ys:
        pf.step(np.full((filters, 1), y, np.float32))
    own, auto = pf.smoothed(), pf.smoothed(motion="auto")
    assert auto["motion"].shape == (filters, 1) and auto["motion"].dtype == np.float32
    assert np.all((auto["motion"] >= 1 / 16) & (auto["motion"] <= 1 / 4)), auto["motion"]
    assert "motion" not in own
    assert np.all(auto["lower"] <= auto["mean"]) and np.all(auto["mean"] <= auto["upper"])
    rms = lambda s: np.sqrt(np.mean((s["mean"][..., 0] - walk[:, None]) ** 2))
    exact = np.array([kalman_smoother(ys, c.mean(), c.var())[:, 0] for c in initial[..., 0]]).T
    exact_rms = np.sqrt(np.mean((exact - walk[:, None]) ** 2))
    assert rms(auto) < 0.8 * rms(own), (rms(auto), rms(own))
    assert rms(auto) < 1.15 * exact_rms, (rms(auto), exact_rms)
    # A fixed scale is the same smoother with the walk's σ scaled; bad ones are refused.
    slow = pf.smoothed(motion=0.125)
    assert np.all(np.isfinite(slow["mean"])) and "motion" not in slow
    for bad in ["fast", 0.0, float("nan"), 1e9]:
        with pytest.raises(ValueError, match="motion"):
            pf.smoothed(motion=bad)
    for wrong_type in [[1.0], True]:
        with pytest.raises(TypeError, match="motion"):
            pf.smoothed(motion=wrong_type)


def test_smoothing_a_wgsl_propagate_is_refused(gpu_backend):
    own_dynamics = WALK_WGSL + """
fn propagate(x: State, n: State, c: Constants) -> State {
    return State(x[0] + 0.5 * n[0]);
}
"""
    initial = np.zeros((2, 64, 1), np.float32)
    with pytest.raises(ValueError, match="propagate"):
        streampf.ParticleFilter(
            initial, sigma=[WALK], wgsl=own_dynamics, observation_size=1,
            constants=np.array([SEEN, LOG_NORM], np.float32), smooth=True, **gpu_backend,
        )


def test_lagged_means_match_the_fixed_lag_kalman_smoother_on_cpu_and_gpu(gpu_backend):
    """lag=L: each step returns the step L back smoothed from the particles' ancestry (on the
    GPU summarised there). Against the exact fixed-lag answer, RTS over the observations up to
    now, within the filters' Monte Carlo error; None before the window fills."""
    filters, particles, steps, lag = 24, 800, 16, 3
    rng = np.random.default_rng(10)
    ys = (np.cumsum(rng.normal(0, WALK, steps)) + rng.normal(0, SEEN, steps)).astype(np.float32)
    initial = rng.normal(0, 1, (filters, particles, 1)).astype(np.float32)
    gpu = streampf.ParticleFilter(
        initial, sigma=[WALK], wgsl=WALK_WGSL, observation_size=1,
        constants=np.array([SEEN, LOG_NORM], np.float32), seed=4, lag=lag, **gpu_backend,
    )
    cpu = streampf.ParticleFilter(
        initial, sigma=[WALK], likelihood=walk_likelihood, seed=4, backend="cpu", lag=lag
    )
    for name, pf in [("gpu", gpu), ("cpu", cpu)]:
        errors = []
        for t, y in enumerate(ys):
            lagged = pf.step(np.full((filters, 1), y, np.float32))["lagged"]
            if t < lag:
                assert lagged is None, (name, t)
                continue
            assert lagged["lag"] == lag and lagged["mean"].shape == (filters, 1)
            assert np.all(lagged["lower"] <= lagged["upper"])
            assert np.all((lagged["kept"] > 0) & (lagged["kept"] <= 1.0 + 1e-4)), lagged["kept"]
            exact = np.array(
                [kalman_smoother(ys[: t + 1], c.mean(), c.var())[t - lag] for c in initial[..., 0]]
            )
            errors.append((lagged["mean"][:, 0] - exact[:, 0]) / np.sqrt(exact[:, 1]))
        errors = np.array(errors)  # (steps - lag, filters)
        bound = 4 * errors.std(axis=1, ddof=1) / np.sqrt(filters) + 0.05
        assert np.all(np.abs(errors.mean(axis=1)) <= bound), (name, errors.mean(axis=1), bound)
    plain = streampf.ParticleFilter(initial, sigma=[WALK], likelihood=walk_likelihood, backend="cpu")
    assert plain.step(np.full((filters, 1), ys[0], np.float32))["lagged"] is None
    for bad in (0, 257, -1):
        with pytest.raises(ValueError, match="lag"):
            streampf.ParticleFilter(initial, sigma=[WALK], likelihood=walk_likelihood, backend="cpu", lag=bad)
