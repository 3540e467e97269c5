"""Type stubs of the extension module (the Rust side of ``streampf``)."""

from os import PathLike
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

Rect = Tuple[float, float, float, float]

def devices() -> List[Dict[str, Any]]:
    """The GPU adapters wgpu can use, best first, as dicts with ``name``, ``device_type``,
    ``backend``, ``driver``, ``driver_info`` and ``software`` (True for Mesa's lavapipe); an
    empty list when there is none."""

class FaceTracker:
    """Tracks faces in frames given as numpy ``uint8`` arrays, H×W (gray) or H×W×3 (colour,
    converted to gray with the ITU-R BT.601 luma Y = 0.299 R + 0.587 G + 0.114 B, rounded; the
    channel order is ``channel_order``: "rgb", or "bgr" for OpenCV's frames).

    Each face is a particle filter over the 7-D pose (tx, ty, scale, rx, ry, rz, alpha; pixels,
    radians with R = Rx·Ry·Rz: rx pitch, ry yaw, rz roll; alpha the template's contrast gain)
    with ``particles`` particles, weighed by the face's sparse template. Faces start from
    rectangles you give (``add_face``) and, with ``detect=True``, from the Viola–Jones detector
    (OpenCV's Haar cascade, every ``detect_every`` frames; its results are used before the next
    frame is due, so a run is repeatable). ``backend``: "auto" (a hardware GPU when there is
    one, else the CPU), "cpu", "gpu" or "all-gpus" (the faces split over every GPU);
    ``allow_software`` accepts a software GPU (lavapipe). ``layers``: annealing layers per frame
    (default 5; 1 is plain Condensation). ``detector``: where the detector runs, "auto" (on a
    GPU when the tracker runs on one), "cpu" or "gpu"; on the GPU it sums the cascade's features
    in f32 (the CPU, as OpenCV, in f64), so a window within rounding of a threshold may go the
    other way: the same faces in this project's tests, several times faster. ``fov``: the
    camera's horizontal field of view in degrees (1 to 170): faces are seen through a pinhole of
    that angle instead of the paper's weak perspective, which reads a near face's turns as larger
    than they are (docs/ACCURACY.md, "The camera's lens"); give it when you know your camera's.
    ``camera``: instead of ``fov``, the camera's intrinsics ``(fx, fy, cx, cy)`` in pixels, or the
    path of a calibration file as OpenCV's FileStorage writes it (YAML or JSON; scaled when the
    frames are the calibrated images resized), as ``face track --camera`` / ``--calibration``.
    ``face_model``: the built-in head the points' depths come from, "auto" (the photographed
    head, as ``face track`` picks for real frames), "photographed" or "generic" (the synthetic
    video's heads: track ``synthetic_faces`` frames with it). ``scene_cut`` (with ``detect``): a
    frame whose gray-level histogram moved by more than this (L1, 0 to 2) since the frame before
    starts a new shot; the detector looks at it, and the tracks it does not find again end there
    (``lost``), as ``face track --scene-cut``; ``None`` turns it off. ``enlarge_below``: a face
    narrower than this many pixels (its template's rectangle) has its landmarks fitted and its
    template taken in its region enlarged 2–4 times, as ``face track --enlarge-below``; ``None``
    for the default (46), 0 for none (docs/ACCURACY.md, "Small faces").

    Thread-safe; ``step`` releases the GIL, so trackers in different threads run at once.
    """

    def __init__(
        self,
        width: int,
        height: int,
        *,
        max_faces: int = 8,
        particles: int = 1000,
        detect: bool = False,
        cascade: Optional[Union[str, PathLike[str]]] = None,
        detect_every: int = 5,
        min_face: int = 40,
        backend: str = "auto",
        allow_software: bool = False,
        seed: int = 1,
        layers: Optional[int] = None,
        channel_order: str = "rgb",
        detector: str = "auto",
        fov: Optional[float] = None,
        face_model: str = "auto",
        smooth: bool = False,
        camera: Union[Tuple[float, float, float, float], str, PathLike, None] = None,
        scene_cut: Optional[float] = 0.25,
        smooth_motion: Union[float, str, None] = None,
        enlarge_below: Optional[float] = None,
        smooth_lag: Optional[int] = None,
    ) -> None: ...
    def smoothed(self) -> Dict[str, np.ndarray]:
        """With ``smooth=True``: every tracked face-frame so far smoothed by the frames after it
        (each track whole, a running one over the frames it has): ``frame`` and ``track`` (n,)
        int64, the state's ``mean``, ``lower`` and ``upper`` (a 95 % interval), (n, 7) float32,
        in frame and track order. Reads the clouds back every frame on a GPU. ``smooth_motion``
        scales the smoother's motion (1: the tracker's own), or ``"auto"`` lets the evidence
        choose each track's values' motion (on the CPU's cores), as ``--smooth-motion``.

        With ``smooth_lag=L`` (1 to 1 000; not with ``smooth=True``) instead, online as
        ``--smooth-lag L``: each ``step`` also returns ``smoothed``, the rows due at that frame
        (each track's frame L back, smoothed by the L frames after it with the marginal smoother,
        and a track's last frames when it ends), and ``smoothed()`` every row so far, the frames
        of the last L smoothed by what follows them. ``smooth_motion="auto"`` then chooses each
        value's motion by the evidence of the track's frames so far."""
    @property
    def device(self) -> str:
        """"CPU", or the GPUs' names."""
    @property
    def face_model(self) -> str:
        """The built-in head in use: "photographed" or "generic"."""
    @property
    def frames(self) -> int:
        """Frames stepped so far."""
    def add_face(self, frame: npt.NDArray[np.uint8], rect: Rect) -> int:
        """Starts a track on the face in ``rect`` = (x, y, width, height) of ``frame`` (its
        template is extracted there; call it before ``step`` on that frame). Returns the track's
        number: 0, 1, … in order, never reused. ValueError when no slot is free or the
        rectangle is bad."""
    def step(self, frame: npt.NDArray[np.uint8]) -> Dict[str, np.ndarray]:
        """Tracks one frame. One row per track reported (running tracks, and a track lost at
        this frame, once):

        - ``track`` (n,) int64, ``slot`` (n,) int64 (the filter slot: ``particles()``' row),
          ``identity`` (n,) int64 (the person: a face found again after its track ended keeps
          its earlier identity; the track's number otherwise);
        - ``state`` (n, 7) float32 and ``spread`` (n, 7) float32: the estimate and the
          posterior's weighted standard deviation (circular for the roll);
        - ``pitch_yaw_roll_deg`` (n, 3) float32 and ``quaternion`` (n, 4) float32 (w, x, y, z;
          w ≥ 0): the rotation in other forms;
        - ``rect`` (n, 4) float32: the face's rectangle at the estimate;
        - ``ess`` (n,) float64, ``error`` (n,) float64 (ε, the template's robust residual),
          ``confidence`` (n,) float32 in [0, 1] ((1 − ε / the template's ε off its face) × the
          likelihood's sharpness, docs/OUTPUT.md);
        - ``log_evidence`` (n,) float64: log p̂(frame | earlier frames) per track, up to the
          likelihood's constant (summed over frames: the track's log-likelihood);
        - ``lost`` (n,) bool: the track ended at this frame;
        - ``started``, ``restarted`` (int64): tracks the detector started or restarted before
          this frame's step;
        - with ``smooth_lag=L``, ``smoothed``: the rows smoothed at this frame, a dict as
          ``smoothed()`` returns.

        ValueError for a frame of the wrong dtype, shape or memory order (the tracker is left as
        it was). A gray frame is read in place with the GIL released: do not write to it from
        another thread while this runs."""
    def particles(self) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """``(states, log_weights)`` after the last step: (slots, particles, 7) and
        (slots, particles); normalised log-weights. On a GPU this reads them back."""

class BodyTracker:
    """Tracks one articulated body (the default human of ``capsules`` capsules, or a skeleton
    JSON file) in depth data: ``step`` takes N×3 ``float32`` points in the camera frame (x
    right, y up, z forward, metres), ``step_depth`` a 16-bit depth image and its intrinsics.
    ``initial_pose`` (float32, one value per ``pose_names``) defaults to standing 3 m in front
    of the camera. ``backend`` as FaceTracker's ("all-gpus": an island of the samples per GPU);
    ``layers``: annealing layers per frame (default 8); ``partitioned``: the first half of them
    move only the trunk (root, pelvis, spine, chest), the rest only the limbs (partitioned
    sampling, the default; False: every layer moves every value); the first ``coarse_layers``
    layers weigh at most ``coarse_points`` of a frame's points (every k-th; the last layer every
    point; ``coarse_layers=0``: every layer every point). Thread-safe; steps release the GIL."""

    def __init__(
        self,
        initial_pose: Optional[npt.NDArray[np.float32]] = None,
        *,
        capsules: int = 19,
        skeleton: Optional[Union[str, PathLike[str]]] = None,
        particles: int = 1500,
        backend: str = "auto",
        allow_software: bool = False,
        seed: int = 1,
        layers: Optional[int] = None,
        partitioned: bool = True,
        coarse_points: int = 5000,
        coarse_layers: int = 7,
        smooth: bool = False,
        smooth_motion: Union[float, str, None] = None,
        smooth_lag: Optional[int] = None,
    ) -> None: ...
    def smoothed(self) -> Dict[str, np.ndarray]:
        """With ``smooth=True``: every frame so far smoothed by the frames after it: ``frame``
        (n,) int64 and the pose's ``mean``, ``lower`` and ``upper`` (a 95 % interval), (n, P)
        float32. With ``smooth_lag=L`` instead (1 to 1 000), as ``FaceTracker``'s: each ``step``
        also returns ``smoothed`` (frame t − L at frame t), and this every row so far."""
    @property
    def device(self) -> str: ...
    @property
    def pose_names(self) -> List[str]:
        """The pose's values: the root's translation (m) and rotation (rad), then every joint
        angle (rad)."""
    @property
    def joint_names(self) -> List[str]:
        """The tracked joints (the root and every bone with an angle), in ``joints``' order."""
    def joints(self, pose: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """The tracked joints' positions (J, 3) for a pose (metres, camera frame)."""
    def step(self, points: npt.NDArray[np.float32]) -> Dict[str, Any]:
        """Tracks one frame of points (N, 3). Returns ``pose`` (P,) float32, ``spread`` (P,)
        float32, ``joints`` (J, 3) float32, ``ess`` (float), ``log_evidence`` (float: log
        p̂(frame | earlier frames), up to the likelihood's constant), ``confidence`` (float in [0, 1]:
        the share of the points the estimate explains) and ``points`` (the points used, after
        thinning). ValueError for a bad array (dtype, shape, order, NaN or infinity)."""
    def step_depth(
        self,
        depth: npt.NDArray[np.uint16],
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        depth_scale: float = 0.001,
    ) -> Dict[str, Any]:
        """Tracks one depth image (H, W): z in units of ``depth_scale`` metres, 0 for no
        measurement; pinhole intrinsics in pixels (image y down)."""
    def particles(self) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """``(poses, log_weights)``: (J, P) and (J,) after the last step."""

class ParticleFilter:
    """The generic engine for T targets × M particles × D dimensions (``initial``: float32
    (T, M, D)), resampling every step, diffusing with the Gaussian random walk ``sigma`` (D
    values; ``angular`` marks angle dimensions, wrapped and averaged on the circle;
    ``bounds`` = (lower, upper) clamps), then weighing with your model:

    - ``wgsl``: WGSL source declaring ``struct Observation``, ``struct Constants`` and
      ``fn log_likelihood(x: State, z: Observation, c: Constants) -> f32`` (optionally ``fn
      propagate(x: State, noise: State, c: Constants) -> State``, replacing the random walk);
      the whole step runs on the GPU. ``observation_size``: the 32-bit values of one
      Observation; ``constants``: float32 values of Constants. See docs/EXTENDING.md.
    - ``likelihood``: a Python callable ``f(particles, observations) -> log_likelihoods`` taking
      the (T, M, D) float32 particles and whatever ``step`` was given, returning (T, M) numbers
      (−inf: zero likelihood); the rest of the step runs in Rust on the CPU.

    ``resampler``: "systematic", "stratified", "metropolis" (GPU and CPU), "multinomial",
    "residual", "rejection" (CPU). ``layers`` > 1 anneals (survival rate 0.5, noise ×0.7 a
    layer). The GPU and CPU paths draw the same random numbers. ``smooth=True`` keeps every
    step's particles for ``smoothed()`` (not with a WGSL ``propagate``, whose density is unknown).
    ``lag`` (1 to 256) smooths online: each step also returns the step ``lag`` back smoothed
    from the particles' ancestry (on the GPU the window stays there and only the summaries come
    back).
    """

    def __init__(
        self,
        initial: npt.NDArray[np.float32],
        *,
        sigma: Sequence[float],
        wgsl: Optional[str] = None,
        likelihood: Optional[Callable[[npt.NDArray[np.float32], Any], npt.ArrayLike]] = None,
        observation_size: Optional[int] = None,
        constants: Optional[npt.NDArray[np.float32]] = None,
        name: str = "model",
        angular: Optional[Sequence[bool]] = None,
        bounds: Optional[Tuple[Sequence[float], Sequence[float]]] = None,
        resampler: str = "systematic",
        layers: int = 1,
        seed: int = 1,
        backend: str = "auto",
        allow_software: bool = False,
        smooth: bool = False,
        lag: Optional[int] = None,
    ) -> None: ...
    @property
    def device(self) -> str: ...
    @property
    def shape(self) -> Tuple[int, int, int]:
        """(targets, particles, dimensions)."""
    def step(self, observations: Any) -> Dict[str, np.ndarray]:
        """One step. For a WGSL model ``observations`` is float32 (T, observation_size); for a
        Python likelihood anything it accepts. Returns ``estimate`` (T, D) float32 (the weighted
        mean), ``spread`` (T, D) float32, ``ess`` (T,) float64, ``resampled`` (T,) bool and
        ``log_evidence`` (T,) float64: each target's log p̂(z_t | z_1:t−1) up to the likelihood's
        constant (include the constant in the likelihood for the true value); summed over steps,
        the log-likelihood of the sequence. With ``lag``: ``lagged``, ``None`` for the first
        ``lag`` steps, then a dict of ``lag``, ``mean``, ``lower``, ``upper`` (T, D) float32 (the
        step ``lag`` back, smoothed from its particles' descendants now, with a 95 % interval)
        and ``kept`` (T,) float32 (the share of that step's effective sample size the trace
        kept); NaN for a target whose particles were restarted within the window. Without
        ``lag``, ``lagged`` is ``None``."""
    def particles(self) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """``(states, log_weights)``: (T, M, D) and (T, M), normalised log-weights."""
    def smoothed(self, *, motion: Union[float, str, None] = None) -> Dict[str, np.ndarray]:
        """Every step so far smoothed by the steps after it (needs ``smooth=True``): ``mean``,
        ``lower`` and ``upper`` (a 95 % credible interval), each (steps, T, D) float32. The
        marginal particle smoother, each value its own block, the random walk's density (all
        annealing layers' together). ``motion`` scales that random walk's σ (0.001 to 1000), or
        ``"auto"`` lets the evidence choose each target's values' scale among 1, 1/2 … 1/64
        (the filter re-weighted to each; its intervals take in those at the filter's own
        motion); the dict then has ``motion`` too, (T, D) float32, the scales chosen."""

def synthetic_faces(
    frames: int = 30,
    *,
    width: int = 640,
    height: int = 480,
    faces: int = 2,
    half_width: float = 50.0,
    max_yaw_deg: float = 50.0,
    occlusion: bool = False,
    seed: int = 11,
    fov: Optional[float] = None,
) -> Dict[str, np.ndarray]:
    """A synthetic video of textured heads: ``frames`` (F, H, W) uint8, ``truth`` (F, K, 7)
    float32 (each face's state), ``rects`` (K, 4) float32 (the first frame's rectangles).
    ``fov``: render through a pinhole of that horizontal field of view in degrees (default: weak
    perspective)."""

def synthetic_body(
    frames: int = 20,
    *,
    width: int = 160,
    height: int = 120,
    motion: str = "walk-wave",
    capsules: int = 19,
    seed: int = 7,
) -> Dict[str, Any]:
    """A synthetic depth sequence of the default human: ``points`` (list of (N, 3) float32),
    ``depth`` (F, H, W) uint16 (mm), ``truth`` (F, P) float32, ``joints`` (F, J, 3) float32,
    ``intrinsics`` (fx, fy, cx, cy, depth_scale) and ``pose_names``. ``motion``: "walk",
    "wave" or "walk-wave"."""

def run_command(args: List[str]) -> None:
    """Runs ``streampf ARGS…`` in this process (what ``track_video`` calls): ValueError for a
    bad command line, RuntimeError for a failed run, KeyboardInterrupt after Ctrl-C (the run
    closes its files first)."""

def mot_scores(
    truth: Sequence[Tuple[int, int, float, float, float]],
    tracks: Sequence[Tuple[int, int, float, float]],
) -> Dict[str, float]:
    """The MOT benchmarks' scores (idf1, idp, idr, mota, num_switches, num_matches, num_misses,
    num_false_positives, num_objects) of `tracks` — (frame, track, x, y) each — against `truth`
    — (frame, identity, x, y, radius) each, a track matching within `radius` of the centre — as
    py-motmetrics computes them (num_matches, as its, leaves out the matches that switched
    identity). ValueError for a bad row."""

def _rust_face_step_times(
    frames: npt.NDArray[np.uint8],
    rects: Sequence[Rect],
    *,
    particles: int = 1000,
    backend: str = "auto",
    allow_software: bool = False,
    seed: int = 1,
) -> npt.NDArray[np.float64]:
    """The yardstick of bench/face_overhead.py: the same tracking through the Rust API alone,
    each step's wall time in seconds (frames made images before the clock starts)."""
