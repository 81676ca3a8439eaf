"""Back-end configuration: typed, defaults in code, loaded with :func:`planar_vo.configtools.from_dict`.

Angles in configuration are degrees (readable in YAML); the code converts once.
Robust-kernel parameters are in whitened units (multiples of the factor's sigma).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from planar_vo.core.errors import ConfigError

KernelName = Literal["huber", "cauchy", "none"]


@dataclass
class BackendConfig:
    """Everything the pose graph, its data association and its solvers need.

    Prior: the first pose is the origin of ``odom`` (a tight prior, not a hard constraint,
    so the graph stays a plain least-squares problem).

    Robust kernels (on both factor kinds): ``cauchy`` is the default because it holds up
    better than ``huber`` when wrong Manhattan associations slip through the gate (see
    ``planar-vo bench backend``): Huber's influence stays constant for large residuals,
    Cauchy's fades, so a 10-degree wrong association does not bend the yaw.

    Manhattan association: an observation joins the local Manhattan frame whose predicted
    residual ``wrap(m_j - theta_k - yaw_obs - b * pi / 2)`` is smallest, provided it is
    within ``gate_sigmas`` of its predicted standard deviation AND within
    ``gate_max_deg``. Observations that fit no frame start (or extend) a candidate frame;
    a candidate becomes a graph variable once ``new_frame_min_observations`` mutually
    consistent observations arrived within ``new_frame_window`` frames (so one stray
    wall does not create a frame). An observation within ``same_frame_deg`` of a frame
    the same pose already observed is that frame seen twice and is ignored; one beyond
    every gate but within ``same_frame_deg`` of a known frame joins that frame on the same
    evidence a new frame needs.
    """

    # --- prior on the first pose (odom = base at the first frame)
    prior_sigma_xy: float = 1e-6          # m
    prior_sigma_theta_deg: float = 1e-6   # deg

    # --- robust noise models
    robust_kernel: KernelName = "cauchy"
    step_robust_parameter: float = 3.0       # whitened units
    manhattan_robust_parameter: float = 2.0  # whitened units

    # --- steps (BetweenFactorPose2 per frame)
    step_min_sigma_xy: float = 1e-3          # m; marginal sigmas raised to at least this
    step_min_sigma_theta_deg: float = 0.02   # deg
    #: "frontend": use a bridged step's information as given (the front-end states the
    #: uncertainty of its constant-velocity guess); "override": replace it by the sigmas below.
    bridged_policy: Literal["frontend", "override"] = "frontend"
    bridged_sigma_xy: float = 0.5            # m
    bridged_sigma_theta_deg: float = 30.0    # deg
    #: A step the front-end measured against an earlier keyframe (``Step.keyframe``) enters
    #: as a factor from that keyframe, not from the previous frame. False: every step is a
    #: factor from the previous frame (the steps are then not independent).
    keyframe_links: bool = True
    #: A partial step whose yaw the front-end measured from a keyframe (``Step.keyframe_yaw``)
    #: keeps only its translation; that yaw enters as a heading factor from the keyframe.
    #: False: the step's yaw stays on its own factor, and a correction it takes back from
    #: the guessed yaws since the keyframe looks like one step's jump to the motion prior.
    keyframe_yaw_links: bool = True

    #: Motion prior next to steps whose translation vision did not measure (partial,
    #: bridged): the base_link velocity of consecutive steps agrees within this acceleration
    #: times their spacing (m/s^2; a sigma, not a limit). About what an indoor base does when
    #: it speeds up or brakes. 0 turns it off (the gap keeps the front-end's forward guess).
    motion_prior_accel: float = 0.5
    #: The prior also ties the velocity of this many steps on each side of such a step, so a
    #: gap takes the speed of the measured steps around it, not of the one step next to it
    #: (on a held-out low-texture L a gap of 18 partial steps took the -5 mm error of the
    #: one measured step before it: 69 mm). 0: only the steps next to the gap.
    motion_prior_window: int = 10
    #: Where the prior ties measured steps, its acceleration is what those steps show: the
    #: RMS change of their base_link velocity, their stated noise kept in, per axis, between
    #: this floor (m/s^2) and ``motion_prior_accel``. A robot cruising at constant speed
    #: then carries its speed over a gap; one speeding up or braking keeps the looser prior.
    motion_prior_min_accel: float = 0.05
    #: For the priors on steps in a gap (or next to one), the velocity changes of the fine
    #: steps are taken at least this far apart (s), not between consecutive ones: consecutive
    #: measured steps' changes are mostly their noise, and at that looseness a few partial
    #: steps measured short pulled a whole gap's speed down with them
    #: (:meth:`_GraphBuilder._gap_prior_accel`). 0: consecutive steps, as for the others.
    #: A gap at the start of a run (a batch solve) longer than ``motion_prior_window`` steps
    #: is tied to four windows this long of the measured steps after it, at the acceleration
    #: they show (:meth:`_GraphBuilder._start_gap_accel`); 0 leaves it at the loose bound.
    motion_prior_gap_baseline_s: float = 0.5
    #: The same for the turn rate (deg/s^2): a heading weaving with a 1 m period at 0.5 m/s
    #: and turn rates up to 10 deg/s (the randomized scenes' cap) changes its turn rate by
    #: up to 10 x 2 pi 0.5 / 1 ~ 31 deg/s^2 (the front-end's bridged guess uses the same 30).
    motion_prior_yaw_accel_deg: float = 30.0
    #: Where the motion prior applies, what of a step's information the front-end's own
    #: constant-velocity guess contributed (``Step.guess_information``) is kept:
    #: ``"keep"``: all of it, next to the prior; ``"correlated"``: weighted as one error
    #: shared by every step of a gap that copies one velocity
    #: (:meth:`_GraphBuilder._guess_weighted`); ``"replace"``: none, the prior states the
    #: same constant velocity, tied to the measured steps on both sides of a gap.
    #: "keep" by default (docs/bench/guess_weight_session37.md): "correlated" made the
    #: smoothed end point of 5 logs better and 3 worse over the tuning seeds 3700-3707 and
    #: the seen sets 6800-6907 (the gaps' own errors 52 -> 44, 55 -> 40, 49 -> 34 mm RMS),
    #: "replace" 1 better and 3 worse on the tuning seeds. A guess's sigma grows as though
    #: the velocity changed at up to 0.5 m/s^2, far more than a cruising base's guess errs,
    #: so a long gap weighted as one error is left to its noisy partial measurements.
    motion_prior_guess: Literal["keep", "correlated", "replace"] = "keep"
    #: True: a gap at the start of a run (no step's forward speed measured yet) starts from
    #: rest: the prior expects the base to speed up at ``motion_prior_accel`` from the first
    #: frame to the speed measured after the gap (the median of the first three measured
    #: steps), then hold it. False: the speed after the gap is carried back to the first
    #: frame, as though the base had been moving when the log began; a base that started
    #: from rest is then put about v^2 / 2a too far. Off by default: on the held-out logs
    #: with a start gap of 8 or more steps it cut the error where the gap ends on six of seven
    #: (two_frames_s4404 28.8 -> 10.1 cm), but the end-point drift went 3 better / 3 worse
    #: (hall_s4502 3.69 -> 6.85 %: its start overshoot had cancelled the hall's forward
    #: shortfall), and a base speeding up faster than 0.5 m/s^2 (a dev hall at 0.8) is put
    #: short (docs/bench/start_at_rest_session24.md).
    motion_prior_start_at_rest: bool = False
    #: True: where the measured steps on one side of a gap show a brake or a speed-up (a
    #: slope of their velocity beyond 3 sigmas) and those on the other side a steady speed,
    #: the prior expects that change of speed to go on into the gap until it meets the
    #: steady speed, not to be spread over the whole gap (:meth:`_GraphBuilder._gap_trend`).
    #: A base braking in front of the wall that ends a gap (its end wall coming into range)
    #: is the common case: spread over a 100-step gap, a brake that began 4 steps before
    #: the gap's end lost 0.19 m on unseen lturn_s10604 while the raw chain kept it.
    #: False: no change expected, the speeds on both sides joined by a straight ramp. A batch
    #: solve only: iSAM2 takes a gap's priors where the gap ends, before the steps after it.
    motion_prior_gap_trend: bool = True

    # --- wheel odometry (a BetweenFactorPose2 per step when the log has it)
    #: Use the log's wheel odometry when it has one (``--no-wheel-odom`` turns it off).
    wheel_odom: bool = True
    #: Noise model of one odometry step of length d (m) and rotation r (rad), in base_link:
    #: sigma_xy = hypot(min_m, per_m * d), sigma_theta = hypot(min_deg, deg_per_m * d,
    #: per_rad * r). The sigmas are generous on purpose: they must cover the odometry's
    #: systematic errors (scale, wheelbase, heading drift of a few %), which are not noise,
    #: so that good vision steps (mm, 0.05 deg) and the Manhattan headings dominate where
    #: they exist. The messages' covariances are ignored (drivers often fill in constants).
    wheel_odom_sigma_min_m: float = 0.002
    wheel_odom_sigma_per_m: float = 0.3
    wheel_odom_sigma_min_deg: float = 0.05
    wheel_odom_sigma_deg_per_m: float = 5.0
    wheel_odom_sigma_per_rad: float = 0.2
    #: The odometry's scale, turn scale and heading drift are always estimated from the
    #: steps vision measured (report.json); true: also correct each odometry step with
    #: them (planar_vo.backend.wheel). Off by default: it did not measurably help (README).
    wheel_odom_calibrate: bool = False
    #: Where vision's forward motion differs from the odometry's by more than this fraction
    #: over the last wheel_odom_check_m metres, vision's translation is distrusted (its
    #: information on x, y scaled by wheel_odom_distrust) and the odometry carries it.
    wheel_odom_max_disagreement: float = 0.15
    wheel_odom_check_m: float = 2.0
    wheel_odom_distrust: float = 1e-4
    #: A bridged step (no estimator had the motion) is left out when the wheel odometry
    #: covers it: the odometry carries the graph instead of the constant-velocity guess.
    wheel_odom_replaces_bridge: bool = True

    # --- Manhattan-frame rotation factors
    manhattan: bool = True
    #: "native": BetweenFactorPose2 with zero information on translation (exact, C++ speed);
    #: "custom": gtsam.CustomFactor on (Pose2, Rot2) with analytic Jacobians (Python callback).
    manhattan_factor: Literal["native", "custom"] = "native"
    #: Observations per variable instance of a frame. A frame seen by thousands of poses
    #: would be one very high-degree variable, which makes every iSAM2 update O(N);
    #: instead a frame is a chain of instances tied by equality factors (sigma below),
    #: a new one every ``manhattan_instance_size`` links or at each revisit.
    #: 0 = one variable per frame.
    manhattan_instance_size: int = 25
    #: Effectively equality next to the 0.3-degree links, yet not so tight that iSAM2's
    #: Cholesky meets a near-singular pivot (1e-4 deg made it throw on a hall run).
    manhattan_tie_sigma_deg: float = 1e-3
    manhattan_min_sigma_deg: float = 0.3     # floor on ManhattanObservation.sigma
    #: Observations covering less image area are ignored: box faces and pillar facets
    #: (a few % of the image) made 10-18 spurious frames in a hall and biased the yaw.
    manhattan_min_score: float = 0.08
    gate_sigmas: float = 4.0
    gate_max_deg: float = 10.0
    #: "any": every unmatched observation may start a frame; "dominant": only the
    #: frame's dominant (first) observation; "never": only the frames already known.
    new_frame_policy: Literal["any", "dominant", "never"] = "any"
    #: An observation within this of a known frame (modulo 90 deg) joins it even beyond
    #: the sigma gate: local frames of one building differ by more, so the chained
    #: heading drifted. It joins once ``new_frame_min_observations`` consistent ones
    #: arrived within ``new_frame_window`` frames, as a new frame would: one or two
    #: sightings of a box a few degrees off the walls are not a drift.
    #: Must stay below half the smallest angle between two corridors.
    same_frame_deg: float = 8.0
    new_frame_min_observations: int = 3
    new_frame_window: int = 15               # frames
    new_frame_gate_deg: float = 3.0          # consistency of a candidate's observations

    # --- wall landmarks (backend/walls.py): the offsets of walls seen from many poses
    #: A wall seen along a corridor is one landmark whose offset every few tenths of a
    #: metre bounds the drift across it (the paper's walls give the heading; their distance
    #: is the same measurement's other half). False: no wall factors.
    walls: bool = True
    #: Floor on a wall offset's sigma (m): door frames and posters stand a few mm proud,
    #: and a wall's depth bias changes with the angle it is seen at.
    wall_min_sigma_m: float = 0.005
    #: An observation joins a landmark on the same Manhattan axis whose last offset is
    #: within this (m): a box against a wall is 0.3 m or more in front of it.
    wall_gate_m: float = 0.1
    #: Landmarks not seen for this much travel (m) are no longer searched (a revisit is a
    #: loop closure's job: the chained pose has drifted by then).
    wall_window_m: float = 3.0
    #: One factor per landmark every this much travel (m): nearby frames share their errors.
    wall_spacing_m: float = 0.5
    #: A wall normal further than this from every Manhattan axis of the frame is skipped.
    wall_axis_tol_deg: float = 3.0
    wall_robust_parameter: float = 2.0       # whitened units

    #: After the robust solve, Manhattan and extra relative factors whose whitened residual
    #: exceeds this many sigmas are removed and the graph re-solved (batch only): even a
    #: Cauchy kernel keeps a residual pull ~ k^2 / u per wrong factor. 0 disables.
    prune_sigmas: float = 10.0

    # --- loop closures (add_closure: a BetweenFactorPose2 T_base_i_base_j from place recognition)
    #: Kernel and parameter (whitened units) of an accepted closure. Robust so that a closure
    #: a little off (a few sigma: an optimistic verification covariance, a slightly wrong
    #: match) pulls with bounded force. Closures are first solved Gaussian, then with this
    #: kernel: at the drifted initial guess a true closure's residual is the accumulated drift,
    #: tens of its sigma, where a redescending kernel would ignore it (see graph.py).
    #: Floors on a closure's marginal sigmas (as the step floors): a verification's covariance
    #: from its fit reflects the matched points' noise, not systematic errors (depth scale,
    #: levelling), and residuals are judged in its sigmas. Not tuned on logs; the order of
    #: the accuracy a closure must have (issue 10: within 5 cm and 0.5 deg).
    closure_min_sigma_xy: float = 0.01       # m
    closure_min_sigma_theta_deg: float = 0.1  # deg
    closure_robust_kernel: KernelName = "cauchy"
    closure_robust_parameter: float = 3.0
    #: After each solve the active closure with the largest Mahalanobis residual beyond this
    #: many sigma is removed and the graph re-solved, worst first, until none is left
    #: (RTAB-Map's RGBD/OptimizeMaxError): a false closure bends the graph and raises the
    #: residuals of true ones too, so removing them all at once would take true ones with it.
    #: 0 keeps every closure: then only the kernel guards against false ones, which holds in
    #: batch (solved from the all-Gaussian solution) but not in iSAM2, where a closure enters
    #: Gaussian into the robust graph and a false one can tear it (1.6 m ATE on a test ring).
    closure_max_error_sigmas: float = 5.0
    #: iSAM2: relinearisation passes after closures entered (or left) the graph, stopping early
    #: once no variable moves beyond the relinearisation thresholds. A loop closure moves the
    #: whole loop, further than one Gauss-Newton step on its linearisation point reaches.
    closure_isam2_max_passes: int = 10

    # --- batch Levenberg-Marquardt
    lm_max_iterations: int = 100
    lm_relative_error_tol: float = 1e-10
    lm_absolute_error_tol: float = 1e-10

    # --- iSAM2
    #: Relinearisation thresholds on the linear delta. They must sit well below the factor
    #: sigmas: a robust kernel's weights are frozen at the linearisation point, so a loose
    #: threshold leaves stale weights and a solution off the batch optimum.
    isam2_relinearize_xy: float = 1e-3           # m
    isam2_relinearize_theta_deg: float = 0.005   # deg
    isam2_relinearize_skip: int = 10
    isam2_wildfire_threshold: float = 1e-3    # per-update back-substitution stops below this change
    isam2_factorization: Literal["CHOLESKY", "QR"] = "CHOLESKY"

    def __post_init__(self) -> None:
        positive = ("prior_sigma_xy", "prior_sigma_theta_deg", "step_robust_parameter",
                    "manhattan_robust_parameter", "bridged_sigma_xy", "bridged_sigma_theta_deg",
                    "manhattan_min_sigma_deg", "manhattan_tie_sigma_deg", "gate_sigmas", "gate_max_deg", "new_frame_gate_deg",
                    "same_frame_deg",
                    "isam2_relinearize_xy", "isam2_relinearize_theta_deg", "motion_prior_yaw_accel_deg",
                    "wheel_odom_sigma_min_m", "wheel_odom_sigma_min_deg", "wheel_odom_max_disagreement",
                    "wheel_odom_check_m", "wheel_odom_distrust", "closure_robust_parameter",
                    "wall_min_sigma_m", "wall_gate_m", "wall_window_m", "wall_axis_tol_deg", "wall_robust_parameter")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"config key 'backend.{name}' must be > 0, got {getattr(self, name)!r}")
        for name in ("step_min_sigma_xy", "step_min_sigma_theta_deg", "manhattan_min_score", "prune_sigmas",
                     "wheel_odom_sigma_per_m", "wheel_odom_sigma_deg_per_m", "wheel_odom_sigma_per_rad",
                     "manhattan_instance_size", "closure_max_error_sigmas", "motion_prior_accel", "motion_prior_window",
                     "motion_prior_min_accel", "motion_prior_gap_baseline_s",
                     "closure_min_sigma_xy",
                     "closure_min_sigma_theta_deg", "wall_spacing_m",
                     "lm_relative_error_tol", "lm_absolute_error_tol"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"config key 'backend.{name}' must be >= 0, got {getattr(self, name)!r}")
        for name in ("new_frame_min_observations", "new_frame_window", "lm_max_iterations",
                     "isam2_relinearize_skip", "closure_isam2_max_passes"):
            if getattr(self, name) < 1:
                raise ConfigError(f"config key 'backend.{name}' must be >= 1, got {getattr(self, name)!r}")
        if self.same_frame_deg >= 22.5:
            raise ConfigError(f"config key 'backend.same_frame_deg' must be < 22.5 (frames closer than 45 deg are told apart), "
                             f"got {self.same_frame_deg}")
        if self.wall_axis_tol_deg >= 45.0:
            raise ConfigError(f"config key 'backend.wall_axis_tol_deg' must be < 45 (a wall is on one axis), "
                              f"got {self.wall_axis_tol_deg}")
        if self.gate_max_deg >= 45.0:
            raise ConfigError(f"config key 'backend.gate_max_deg' must be < 45 (the 90-degree ambiguity), got {self.gate_max_deg}")
