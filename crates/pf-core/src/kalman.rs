//! The exact answers on a linear-Gaussian model, the yardstick of the particle filter's
//! evidence and smoother: a scalar random walk x_t = x_{t−1} + σ_p·n observed as
//! y_t = x_t + σ_r·n, from the prior N(m₀, p₀). The Kalman filter gives each frame's exact
//! log p(y_t | y_1:t−1); the Rauch–Tung–Striebel smoother each frame's exact p(x_t | y_1:T).

/// The scalar random walk observed in noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RandomWalk {
    /// σ_p: the walk's step.
    pub step: f64,
    /// σ_r: the observations' noise.
    pub noise: f64,
    /// The prior's mean and variance at frame 0, before its step.
    pub prior: (f64, f64),
}

/// One frame of the Kalman filter: the predicted and filtered (mean, variance), and the frame's
/// log-likelihood log p(y_t | y_1:t−1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KalmanFrame {
    /// p(x_t | y_1:t−1): (mean, variance).
    pub predicted: (f64, f64),
    /// p(x_t | y_1:t): (mean, variance).
    pub filtered: (f64, f64),
    /// log p(y_t | y_1:t−1).
    pub log_likelihood: f64,
}

impl RandomWalk {
    /// The Kalman filter over `observations`.
    pub fn filter(&self, observations: &[f64]) -> Vec<KalmanFrame> {
        let (mut m, mut p) = self.prior;
        let r = self.noise * self.noise;
        observations
            .iter()
            .map(|&y| {
                p += self.step * self.step;
                let predicted = (m, p);
                let innovation = p + r;
                let log_likelihood = -0.5
                    * ((2.0 * std::f64::consts::PI * innovation).ln()
                        + (y - m).powi(2) / innovation);
                let gain = p / innovation;
                m += gain * (y - m);
                p *= 1.0 - gain;
                KalmanFrame {
                    predicted,
                    filtered: (m, p),
                    log_likelihood,
                }
            })
            .collect()
    }

    /// The Rauch–Tung–Striebel smoother's (mean, variance) of every frame given all of
    /// `observations`.
    pub fn smooth(&self, observations: &[f64]) -> Vec<(f64, f64)> {
        let frames = self.filter(observations);
        let mut smoothed: Vec<(f64, f64)> = frames.iter().map(|f| f.filtered).collect();
        for t in (0..frames.len().saturating_sub(1)).rev() {
            let (mf, pf) = frames[t].filtered;
            let (mp, pp) = frames[t + 1].predicted;
            let (ms, ps) = smoothed[t + 1];
            let g = pf / pp;
            smoothed[t] = (mf + g * (ms - mp), pf + g * g * (ps - pp));
        }
        smoothed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_observation_is_the_conjugate_update() {
        let walk = RandomWalk {
            step: 0.0,
            noise: 1.0,
            prior: (0.0, 1.0),
        };
        let f = walk.filter(&[2.0])[0];
        // Prior N(0, 1), y = 2 with unit noise: posterior N(1, 1/2), evidence N(2; 0, 2).
        assert!((f.filtered.0 - 1.0).abs() < 1e-12 && (f.filtered.1 - 0.5).abs() < 1e-12);
        let want = -0.5 * ((2.0 * std::f64::consts::PI * 2.0).ln() + 2.0);
        assert!((f.log_likelihood - want).abs() < 1e-12);
        // The last frame's smoothed value is its filtered one; earlier frames shrink towards it.
        let s = walk.smooth(&[0.0, 2.0]);
        assert_eq!(s[1], walk.filter(&[0.0, 2.0])[1].filtered);
        assert!(s[0].0 > walk.filter(&[0.0, 2.0])[0].filtered.0);
    }
}
