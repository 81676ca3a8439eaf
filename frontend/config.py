"""Front-end configuration: typed dataclasses, defaults in code.

Load from a nested dict (YAML section ``frontend``) with
``planar_vo.configtools.from_dict(FrontendConfig, d)``; unknown keys are rejected.
Angles in configuration are degrees (names end in ``_deg``), distances metres.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

#: Depth readings used (m), ``(min, max)``: Kinect v2 reads from ~0.5 m. Default of
#: :attr:`FrontendConfig.min_depth` / ``max_depth``, which the plane detector and the
#: feature tracker both take.
DEFAULT_DEPTH_RANGE = (0.3, 8.0)

from planar_vo.core.errors import ConfigError


def _positive(section: str, **values: float) -> None:
    for name, v in values.items():
        if not v > 0:
            raise ConfigError(f"config key '{section}.{name}' must be > 0, got {v!r}")


@dataclass
class LevellingConfig:
    """Camera pitch/roll/height: the one place a mount is set (``planar-vo run --pitch-deg
    --roll-deg --height`` write these keys). Precedence: these keys, then the log's mount,
    then the floor.

    ``pitch_deg``/``roll_deg`` fix the tilt (REP 103 mount angles: pitch > 0 looks down; both or neither);
    ``height_m`` fixes the camera height above the floor. Whatever is left unset is
    estimated from the ground plane over the first ``init_frames`` frames (robust median)
    and, with ``refine``, refined as the run goes.
    """

    pitch_deg: float | None = None
    roll_deg: float | None = None
    height_m: float | None = None
    init_frames: int = 5             # floor estimates pooled before the tilt is trusted
    refine: bool = True              # keep refining after initialisation
    window: int = 200                # robust median over at most this many floor estimates
    min_floor_support: float = 0.03  # floor must cover this image fraction to be used
    max_tilt_jump_deg: float = 3.0   # floor estimates this far from the current tilt are outliers
    initial_pitch_deg: float = 0.0   # starting guess while estimating (helps very tilted mounts)

    def __post_init__(self) -> None:
        if self.init_frames < 1 or self.window < self.init_frames:
            raise ConfigError("config key 'levelling.init_frames' must be >= 1 and <= 'levelling.window'")
        if self.height_m is not None:
            _positive("levelling", height_m=self.height_m)
        if (self.pitch_deg is None) != (self.roll_deg is None):
            raise ConfigError("mount tilt needs both pitch_deg and roll_deg (config keys "
                              "'levelling.pitch_deg', 'levelling.roll_deg'; flags --pitch-deg --roll-deg)")


@dataclass
class PlaneConfig:
    """Inverse-depth histogram plane detection (paper Sec. 2.1)."""

    stride: int = 4                  # use every stride-th pixel in both directions
    n_invdepth_bins: int = 192       # inverse-depth axis of both histograms
    n_image_bins: int = 160          # levelled row / column axis
    min_cell_count: int = 6          # a histogram cell must hold this many samples to vote
    hough_step_deg: float = 1.0      # plane orientation step of the Hough vote
    inlier_rel_depth: float = 0.03   # point-to-plane test: |Z - Z_plane| / Z
    min_support: float = 0.01        # planes covering less of the image are dropped
    max_walls: int = 6
    horizontal_tilt_deg: float = 3.0  # floor/ceiling normal within this of vertical (levelled)
    wall_tilt_deg: float = 6.0       # wall normal within this of horizontal
    unlevelled_tilt_deg: float = 30.0  # floor search range while the tilt is still unknown
    refit_iterations: int = 2
    refit_sigmas: float = 3.0        # refits keep points within this many noise sigmas of the fit
    systematic_fraction: float = 0.3  # share of the depth noise assumed correlated across a plane
    #: Walls are fitted where their depth is at most ``1 - range_margin`` of the sensor's
    #: range, learnt from the log (PlaneDetector._learn_range): a sensor drops the readings
    #: its noise pushes past its range, so a wall near it keeps only near-side errors.
    #: Hall walls 4.4-4.7 m away with a 4.5 m range read 3.3 -> 0.1 deg off as they came
    #: into range (0.01 deg with the range at 6 m, the same frames rendered again), and
    #: the direction-plus-point yaw followed that drift step by step. 0.05 (~0.2 m, 2-7
    #: noise sigmas at 4.5 m) was chosen over 0.1 on the tuning halls (seeds 3100-3107,
    #: 3200-3207): 0.1 also dropped the walls the return legs need. 0 disables.
    range_margin: float = 0.05
    #: A wall whose inliers hold parallel layers in contiguous sections along it (doors and
    #: posters 3-10 mm proud, each filling one part of the wall's extent) is fitted as one
    #: plane plus an offset per section, when each section's offset is clear in the band
    #: medians (planes._layer_step): a single fit across the layers tilted held-out walls by
    #: 0.2-0.44 deg. The distance stays the single fit's (docs/bench/wall_layers_session29.md).
    layer_step: bool = True

    def __post_init__(self) -> None:
        _positive("planes", stride=self.stride,
                  n_invdepth_bins=self.n_invdepth_bins, n_image_bins=self.n_image_bins,
                  hough_step_deg=self.hough_step_deg, inlier_rel_depth=self.inlier_rel_depth,
                  refit_sigmas=self.refit_sigmas)
        if not 0.0 <= self.range_margin < 1.0:
            raise ConfigError(f"config key 'planes.range_margin' must be in [0, 1), got {self.range_margin!r}")


@dataclass
class ManhattanConfig:
    """Grouping vertical planes into local Manhattan frames and tracking them."""

    group_tol_deg: float = 2.5       # normals parallel/perpendicular within this
    group_sigmas: float = 3.0        # ... and within this many combined sigmas
    min_sigma_deg: float = 0.15      # floor on a frame's yaw sigma (model error, levelling)
    track_gate_deg: float = 8.0      # association gate after rotation prediction
    max_missed: int = 15             # frames a track survives unseen
    min_score: float = 0.02          # frames with less wall area are not reported
    #: Observations at most this uncertain become their track's reference heading for
    #: the direction-plus-point yaw; weaker ones leave the carried reference in place.
    ref_max_sigma_deg: float = 0.35
    #: Frames are reported to the back-end (Manhattan-frame priors on the heading) only
    #: if the walls of one of them fill at least this many metres across (Plane.width):
    #: box faces (synthetic ones 0.3-0.7 m), pillars and rows of pillars are vertical
    #: planes at any angle, and one a few degrees off the walls' frame joins it and pulls
    #: the heading. On a small synthetic hall the observations the back-end takes were up
    #: to 43 deg off the hall's axes, within 0.81 deg with this (tests/test_odometry.py).
    #: Steps still use them: the heading *change* between two views of one box face is as
    #: good as a wall's. The heading the back-end takes from a frame that has such a wall
    #: comes from its walls this wide only (manhattan._compass): a box face that joined a
    #: corridor's frame pulled it by up to 1.5 deg. 0 reports every frame and weighs every
    #: wall in.
    min_wall_width_m: float = 1.0

    def __post_init__(self) -> None:
        if not self.min_wall_width_m >= 0:
            raise ConfigError("config key 'manhattan.min_wall_width_m' must be >= 0 (0 reports every frame)")
        _positive("manhattan", group_tol_deg=self.group_tol_deg, min_sigma_deg=self.min_sigma_deg,
                  track_gate_deg=self.track_gate_deg)


@dataclass
class FeatureConfig:
    """Corner detection and frame-to-frame association in the colour image."""

    method: Literal["klt", "orb"] = "klt"
    max_corners: int = 300
    quality_level: float = 0.01      # Shi-Tomasi relative quality (klt)
    min_distance: int = 12           # pixels between corners (klt)
    block_size: int = 3
    #: New corners whose gradient structure tensor is edge-like (smaller over larger
    #: eigenvalue below this, over a (2 corner_window + 1)^2 window of the detection image)
    #: are dropped: KLT slides along edges. Tracked corners are checked again in every
    #: frame over LK's window (klt_window): on the low-texture tuning logs those below
    #: 0.05 there followed only half of their image motion. 0 disables.
    min_corner_ratio: float = 0.05
    corner_window: int = 3
    detect_half: bool = True         # detect at half resolution, refine at full (klt)
    klt_window: int = 11
    klt_levels: int = 3
    klt_iterations: int = 10
    klt_min_eig: float = 2e-3        # LK's minimum eigenvalue (per pixel^2, grey levels / 255)
    fb_check: bool = True            # forward-backward consistency (klt)
    fb_max_px: float = 1.0
    #: Auto-exposure and mains flicker change the image gain between frames, which biases
    #: LK's brightness-constancy fit; when the tracked corners' local brightness changed by
    #: more than this fraction, the current image is rescaled and tracked again (klt).
    #: 0 disables.
    gain_tolerance: float = 0.01
    orb_features: int = 800
    orb_max_hamming: int = 64
    depth_window: int = 1            # depth from a (2w+1)^2 neighbourhood
    depth_edge_rel: float = 0.03     # reject if the neighbourhood spans more than this (relative)
    #: A corner's depth is dropped when LK's window (klt_window) spans a depth jump: its
    #: inverse depth, less a plane, spreads by more than this fraction (features.
    #: straddles_depth_jump; occlusion corners slide along the edge). 0 disables.
    occlusion_rel: float = 0.1

    def __post_init__(self) -> None:
        _positive("features", max_corners=self.max_corners, klt_window=self.klt_window,
                  orb_features=self.orb_features, depth_edge_rel=self.depth_edge_rel)
        if not self.occlusion_rel >= 0:
            raise ConfigError("config key 'features.occlusion_rel' must be >= 0 (0 disables)")


@dataclass
class OdometryConfig:
    """Estimator choice, acceptance and bridging."""

    min_inliers: int = 20            # 2-point: fewer inliers and the estimator failed
    min_inlier_ratio: float = 0.3
    min_scale_inliers: int = 12      # 2-point: matches with depth that agree on the metric scale
    #: ... or this many when no Manhattan frame gives a partial step instead (open halls:
    #: most corners beyond the depth range); fewer, and only the 2-point yaw is used.
    weak_scale_inliers: int = 5
    #: A pure rotation (every match explained by the yaw alone) gives a partial step its yaw
    #: from this many inliers on (a hall's U-turn with few corners; whole steps: min_inliers).
    yaw_only_min_inliers: int = 10
    #: The 2-point covariance assumes independent match errors. Matches crowded into a few
    #: image cells (1/8 of a normalised unit, ~70 px on a qhd Kinect) share theirs: the same
    #: texture blob, the same far wall, where yaw and sideways motion trade off. Below this
    #: many occupied cells the yaw's sigma grows as min_cells / cells, the variance added
    #: along the yaw / sideways valley (measured on the halls of tuning seeds 3300-3407:
    #: yaw errors 0.10 deg at 13 cells, 0.04 at 32, 0.01 at 74, all stated at ~0.02 deg).
    two_point_min_cells: float = 60.0
    #: A 2-point step whose translation departs from the constant-velocity guess by more
    #: than this many sigmas (its own and the guess's, whose sigma is the platform's
    #: acceleration limit) is not a measurement: matches agreeing on a wrong motion (a tile
    #: grid aliased under KLT). 0 turns the gate off.
    velocity_gate_sigmas: float = 6.0
    #: The base is wheeled and does not slide sideways (differential drive, Ackermann): the
    #: 2-point refinement asks each base_link step to follow its heading, at a sigma of
    #: lateral_floor_m + lateral_slip x the step's length. It resolves the yaw / sideways
    #: translation ambiguity of far features (not used on pure rotations, whose images do
    #: not see the translation). 0 turns it off (holonomic bases).
    lateral_slip: float = 0.03
    lateral_floor_m: float = 0.0005
    #: True: a 2-point step whose images the yaw alone explains (a pure rotation) is fitted
    #: on the wheeled base's heading itself (``estimators._wheeled_refine``) instead of
    #: without the sideways prior. Far corners on one side make a forward step's parallax
    #: look like a turn: on a seen hall (hall_s8203) such steps erred +0.05 deg each for 60
    #: steps, and the option took it from 1.98 to 0.33 % smoothed drift. Off by default: on
    #: the tuning halls three of eight drifted further along the path (hall_s3704 0.74 ->
    #: 1.16 %, hall_s3702 0.29 -> 0.53 %, hall_s3707 0.90 -> 1.06 %), none less
    #: (docs/bench/changes_session46.md). Needs ``lateral_slip`` > 0.
    pure_rotation_on_heading: bool = False
    #: Direction-plus-point needs only the translation from the matches (the yaw comes from
    #: the walls), so a few agreeing 3-D matches suffice; its covariance grows as they fall.
    dpp_min_inliers: int = 6
    #: A partial step (yaw known, no whole step) takes its translation also from this many
    #: 3-D matches agreeing at its yaw (eq. 2), at their own covariance.
    partial_min_points: int = 3
    #: Matched corners whose depths agree with the same wall or floor in both frames get
    #: them refined by the plane (planar_vo.frontend.pointplanes) for the 1-point
    #: translation: ``plane_sigma_m`` is a fitted plane offset's error; a reading's sigma
    #: grows by ``1 + depth_incidence * (1 / cos - 1)`` at oblique incidence (time of flight).
    plane_refine: bool = True
    plane_sigma_m: float = 0.002
    #: Only corners seen within acos(plane_min_cos) of the plane's normal. 0.5 (60 deg) gave
    #: smoothed drift median / p90 / worst 0.23 / 0.79 / 1.45 % on the 15 low-texture tuning
    #: logs, 0.05 gave 0.13 / 0.77 / 1.77 (README "Low-texture corridors").
    plane_min_cos: float = 0.05
    depth_incidence: float = 0.5
    dpp_min_inlier_ratio: float = 0.6  # a wrong Manhattan yaw shows as a low 1-point inlier ratio
    dpp_max_yaw_sigma_deg: float = 0.5  # weaker Manhattan yaws leave the step to the 2-point method
    dpp_min_score: float = 0.08      # local frames covering less image area (in both views) are not used
    dpp_min_track_age: int = 3       # nor frames seen for fewer consecutive frames (walls entering view)
    #: The 2-point yaw may veto a Manhattan yaw (a wrong association), never bend it: the
    #: veto needs a disagreement beyond this many combined sigmas and this many degrees.
    #: A local frame whose walls change between the views (a wall 1 deg off the others
    #: joins or leaves) jumps by up to 1.4 deg while its step sigma, the walls' fit noise
    #: alone, stays at 0.04-0.16 deg. Over the 24 488 steps of tuning seeds 3500-3507 and
    #: 3700-3707 with both estimates, 70 direction-plus-point yaws erred beyond 0.3 deg
    #: (39.7 deg in all); a 2 deg gate vetoed 1 of them. Beyond the gate the 3-D matches
    #: decide: the 2-point yaw vetoes when it explains them at a lower truncated cost, each
    #: yaw with its best translation (``PlanarOdometry._vetoed``); otherwise the walls stand.
    dpp_veto_sigmas: float = 4.0
    dpp_veto_min_deg: float = 0.3
    #: A track's carried reference jumped to another surface when the step's yaw and the
    #: frame-to-frame one differ beyond ``dpp_veto_sigmas`` and this many degrees (the
    #: correction they differ by is normally a few tenths of a degree, and its sigma is in
    #: the first term). 2 deg let eleven 0.7-1.45 deg jumps through on the tuning hall of
    #: seed 3707 (smoothed drift 4.98 -> 1.07 % with 0.5; one other log of seeds 3700-3707
    #: moved, lturn_s3701 0.10 -> 0.18 %).
    reference_jump_min_deg: float = 0.5
    #: A direction-plus-point step's yaw is the difference of its local frame's headings
    #: (eq. 1), which telescopes along the track: a face off the building's grid that
    #: joins the frame turns the chain by its pull, and turns it back when it leaves.
    #: With this > 0, the step takes eq. 1 applied wall by wall instead where the two
    #: disagree beyond this many sigmas (3 until the fifty-ninth stop). That catches an
    #: abrupt change and not a face fading out over several frames, so the chain kept one
    #: half of the pair for good: on the tuning seeds 3700-3703 the raw chain's final
    #: |yaw| was 0.085 / 0.230 deg (median / mean) with 3, 0.027 / 0.200 with 0
    #: (docs/bench/changes_session62.md, section 4).
    #: 0 turns the check off.
    wall_yaw_check_sigmas: float = 0.0
    #: Partial steps: a wall seen in both frames fixes the translation along its normal
    #: (d2 - d1 = n2 . t); walls must match within these after the predicted motion.
    wall_match_deg: float = 3.0
    wall_match_m: float = 0.15
    wall_min_support: float = 0.03   # image fraction of a wall used for translation
    #: ... and a wall's offset change must agree with the step's guess within this many
    #: combined sigmas (wall fit and guess): a 10 cm jump stated at 2 mm was another plane.
    wall_gate_sigmas: float = 5.0
    #: floor on the sigma of a wall offset difference d2 - d1 (model error): at 2 mm, with the
    #: sideways floor of whole steps on top, partial steps stated 2.9x their sideways errors
    #: (254 partial steps of tuning logs 3100-3107: normalised RMS 0.35 -> 0.54 with this
    #: floor and none sideways on partial steps, A/B at 8ed9658; 0.61 over 334 at 3e78abf)
    wall_min_sigma_m: float = 0.0015
    #: Steps measured from points are re-measured against a keyframe (frontend/keyframe.py):
    #: the motion from the keyframe with the same estimator, the step the difference of two
    #: such motions, so that depth noise does not add up step by step. A keyframe is renewed
    #: when fewer than ``keyframe_min_fraction`` of the corners it had one frame later are
    #: still tracked, or the motion from it exceeds ``keyframe_max_baseline_m`` /
    #: ``keyframe_max_yaw_deg``. The re-measured motion must agree with the chained steps
    #: within ``keyframe_gate_chi2`` (3 dof, both covariances). False: frame to frame only.
    keyframes: bool = True
    #: Direction-plus-point steps too (their translation solved again from the keyframe at
    #: the chained yaw). Off: a direction-plus-point step makes its frame the keyframe. On
    #: the corridors of tuning seeds 3700-3707, where such steps dominate, re-measuring them
    #: made the chains' errors over 100 frames larger (3.3 -> 5.4 mm on straight_s3707):
    #: their frame-to-frame errors do not add up as the 2-point steps' do.
    keyframe_dpp: bool = False
    #: A partial step whose yaw is the 2-point method's (no wall, too few depths for its
    #: scale) takes that yaw from the keyframe too: the step's yaw is the difference of two
    #: yaws measured from the keyframe, so that a per-step bias does not add up frame by frame.
    keyframe_partial_yaw: bool = True
    #: True: a partial step whose yaw was measured and whose whole translation nothing
    #: else measured takes it from the 2-point motion from K when two or more agreeing
    #: depths give that motion's scale (``PlanarOdometry._keyframe_translation``). Off by
    #: default: it took a seen hall that sped up from rest (hall_s8105) from 6.43 to 0.74 %
    #: smoothed drift, but a slow tuning hall (hall_s3702, 30 Hz, 8 mm steps) from 0.29 to
    #: 1.80 %, and the variant that kept that hall (one depth enough) let a textureless
    #: start from rest copy a wrong velocity (docs/bench/changes_session45.md).
    keyframe_partial_translation: bool = False
    keyframe_min_fraction: float = 0.5
    keyframe_max_baseline_m: float = 1.0
    keyframe_max_yaw_deg: float = 30.0
    keyframe_gate_chi2: float = 16.27
    #: Image error (pixels) a tracked corner gains per frame since the keyframe, as a random
    #: walk (sigma ``keyframe_track_px * sqrt(age)``, added in variance to the 2-point
    #: pixel sigma of a motion from the keyframe): KLT finds each corner again in every
    #: frame, each time a little off. Without it the 2-point motions from a keyframe stated
    #: too little, the more the older the keyframe: on the nine halls of tuning seeds
    #: 3700-3707 their mean ``e^T C^-1 e`` (3 if honest) was 3.2 at 2-4 frames, 5.2 at 5-9,
    #: 8.9 at 10-14 (a motion 22 frames long erred -1.04 deg in yaw at a stated 0.11 deg).
    #: Measured KLT drift on renders is 0.13-0.2 px a frame (tests/test_keyframe.py); 0.5,
    #: chosen on those tuning seeds over 0.3 (smoothed drift median / p90 / worst of the 38
    #: estimated logs 0.16 / 0.48 / 1.43 -> 0.13 / 0.34 / 1.26 %, docs/bench/
    #: sweep_tuning_3700-3707_session18*.txt; 0.3: worst 1.60), also covers errors that grow
    #: with the motion's length and are not modelled yet. 0: off.
    keyframe_track_px: float = 0.5
    #: Corners beyond the depth range are triangulated from the measured steps, and a step
    #: that no estimator measured (partial, bridged) is resected against them
    #: (frontend/farcorners.py): in an open hall most corners are out of range, and where the
    #: base stopped and drove on among such steps the constant-velocity guess held the stop.
    far_corners: bool = True
    #: A step that no wall, no 2-point fit and no depth image turned takes the yaw of its
    #: resection against the far corners (at that resection's sigma) in place of the
    #: constant-turn-rate guess, where the two agree within 3 of their joint sigmas
    #: (:meth:`PlanarOdometry._far_yaw`). A guess copies the last turn rate into a weave
    #: that turns back: on seen hall_s10602 four such steps of a 0.2 deg/step weave went
    #: 0.1-0.4 deg off each (1.0 deg over the four, kept to the end: no wall in that hall),
    #: their resected yaws 0.02-0.05 deg at stated 0.07-0.08. Needs ``far_corners``.
    far_yaw: bool = True
    #: The gap of unmeasured steps a log starts with (no far corners before it to resect
    #: against) is resected backwards, against the corners tracked across it, once the base
    #: has driven half a metre on measured steps after it (frontend/gapresection.py); each
    #: gap frame's motion goes to the back-end as a factor of its own. Needs ``far_corners``.
    start_gap_resection: bool = True
    #: A partial step's translation along the direction its walls left to the guess (walls
    #: of one direction, with or without a few 3-D matches) is measured by aligning the two
    #: frames' depth images along it (box sides, door frames, end walls;
    #: frontend/depthalign.py), over
    #: +-4 guess sigmas clipped to [min_range, max_range]. On the tuning seeds 3700-3707
    #: (docs/bench/depth_align_tuning_3700-3707.txt) the textureless L went 3.08 -> 1.65 %
    #: smoothed drift (raw 2.36 -> 1.63 %), the estimated logs' p90 / worst 0.60 / 1.92 ->
    #: 0.59 / 1.92 %, a hall 0.95 -> 1.15 % (raw 0.85 -> 0.80 %).
    depth_align: bool = True
    depth_align_min_range_m: float = 0.02
    depth_align_max_range_m: float = 0.2
    #: A step whose yaw neither walls nor the 2-point method measure (a textureless hall,
    #: walls out of range) takes its yaw from the depth images, aligned about the yaw
    #: (pillars, boxes; frontend/depthalign.py ``coarse_yaw_along``, ``align_yaw``) over
    #: +-``depth_yaw_range_deg`` of the guess, not a multiple of the guess's sigma: a robot
    #: entering a turn changes its yaw rate faster than the guess's 30 deg/s^2 allows
    #: (entering the U-turn of a textureless hall, hall_s4502, the guess was 1.6 deg a step
    #: off for 12 steps, outside a 0.5 deg range). Without a yaw, a step whose translation
    #: was measured is partial at the guessed yaw; else it is bridged.
    depth_yaw: bool = True
    depth_yaw_range_deg: float = 3.0
    #: A 2-point step whose metric scale came from fewer than ``min_scale_inliers`` depths
    #: (weak scale) also takes the depth alignment's distance along its long axis, fused by
    #: the two variances (``PlanarOdometry._aligned``): thousands of depth pixels against a
    #: handful of corners. On eight tuning hall logs (seeds 3700-3706), 337 of 870 such
    #: frame-to-frame steps found an alignment; they erred 8.3 mm rms along it (1.15 of
    #: their sigma), fused 2.1 mm (0.95, none beyond 4 sigmas). The motion from the
    #: keyframe is aligned against the keyframe's depth the same way.
    weak_scale_align: bool = True
    #: Inliers along one image line (smaller / larger principal spread below this) do not
    #: fix the motion along that line (KLT's aperture problem on a floor-wall junction).
    min_inlier_spread: float = 0.1
    #: ... and lying within this rms distance of that line (pixels): a wide, flat band of
    #: corners (boxes and pillars across a hall, 10-25 px off its axis) is not a line.
    min_inlier_spread_px: float = 5.0
    #: Walls farther than this do not fix translations: Kinect v2 depth ends at 4.5 m, and
    #: a plane near the cut-off keeps only the points noise brought nearer (7-11 cm bias).
    wall_max_offset_m: float = 4.0
    planarity_check: bool = True     # fit a 6-DoF motion on steps into frames without a floor, to judge planarity
    ransac_threshold_px: float = 1.5     # image error (2pt), converted with fx
    ransac_iterations: int = 200
    seed: int = 0
    max_step_yaw_deg: float = 20.0   # larger per-frame turns are implausible for a robot
    max_sigma_xy: float = 0.05       # estimates less certain than this (m, deg) are failures
    max_sigma_theta_deg: float = 1.0
    bridge: Literal["constant_velocity", "zero"] = "constant_velocity"
    #: A constant-velocity guess errs by the velocity change since the last measurement:
    #: sigma = accel * k * dt^2 after k unmeasured frames of dt seconds (indoor robots),
    #: capped at the sigmas below, which also apply when no motion was ever measured.
    bridge_accel_xy: float = 0.5          # m/s^2
    bridge_accel_theta_deg: float = 30.0  # deg/s^2
    #: The guess's error also counts the frames from the middle of the window it averages
    #: (``velocity_window``) to the guessed frame, at the slope the window's steps show
    #: (speeding up or braking; :meth:`PlanarOdometry._window_trend_drift`), not only the
    #: frames since the last measured step. False: only those.
    bridge_trend_lag: bool = True
    bridge_sigma_xy: float = 1.0     # metres
    #: The guessed velocity's drift stays within the platform's top speed (m/s; indoor
    #: bases drive at up to ~1 m/s, the randomized scenes at 0.2-0.8).
    bridge_max_speed: float = 1.0
    bridge_sigma_theta_deg: float = 30.0
    bridge_min_score: float = 0.15   # a bridge takes the Manhattan yaw only from walls this large
    #: frames whose measured steps are averaged (by their variances) into the constant-velocity guess
    velocity_window: int = 5
    #: Floors on a step's std (unmodelled errors). Calibrated on the randomized tuning seeds
    #: 1-2 (`planar-vo bench sweep`): at 2 mm / 0.05 deg / 5 mm (walls) the floors alone
    #: made the stated sigmas of 2-point and partial steps 2-5x their real errors (normalised
    #: RMS 0.2-0.4); at these values the direction-plus-point, 2-point and partial steps'
    #: normalised RMS is 0.5-1.5 there (bridged steps: 0.04-0.6, their own model).
    #: The translation floor is on the sideways component only (levelling and calibration
    #: errors turn the step; along the motion the depth models hold: direction-plus-point
    #: forward errors were 0.64 of their sigma with it, 0.86 without, tuning seeds).
    min_sigma_xy: float = 0.001
    min_sigma_theta_deg: float = 0.02
    #: Floors for 2-point steps, in every direction of the translation (its covariance is
    #: a thin valley, direction from the images, length from the depths, whose width the
    #: inlier residuals understate): ``two_point_min_sigma_xy`` plus an image error of
    #: ``two_point_shared_px`` pixels that all matches share, at their typical depth Z
    #: (``shared_px * Z / fx`` metres). Across the valley the tuning seeds' (3700-3707,
    #: mostly halls) errors stayed near 1.2 mm where the stated sigma was 0.4-0.7 mm, and
    #: grew with Z (0.3 mm under 1.5 m, 0.8 mm at 1.5-2.5 m on three tuning halls). The
    #: yaw floor lies along the yaw-sideways coupling
    #: (``PlanarOdometry._yaw_floor``). The graph floors every step again
    #: (backend.step_min_sigma_xy), for errors shared by many steps that no step's sigma states.
    two_point_min_sigma_xy: float = 0.0002
    two_point_shared_px: float = 0.2
    two_point_min_sigma_theta_deg: float = 0.02

    def __post_init__(self) -> None:
        _positive("odometry", plane_sigma_m=self.plane_sigma_m, plane_min_cos=self.plane_min_cos,
                  velocity_window=self.velocity_window, wall_gate_sigmas=self.wall_gate_sigmas,
                  two_point_min_cells=self.two_point_min_cells, lateral_floor_m=self.lateral_floor_m,
                  two_point_min_sigma_xy=self.two_point_min_sigma_xy, bridge_max_speed=self.bridge_max_speed,
                  two_point_min_sigma_theta_deg=self.two_point_min_sigma_theta_deg,
                  two_point_shared_px=self.two_point_shared_px,
                  keyframe_max_baseline_m=self.keyframe_max_baseline_m, keyframe_max_yaw_deg=self.keyframe_max_yaw_deg,
                  keyframe_gate_chi2=self.keyframe_gate_chi2, depth_align_min_range_m=self.depth_align_min_range_m,
                  depth_yaw_range_deg=self.depth_yaw_range_deg)
        if not self.depth_align_max_range_m >= self.depth_align_min_range_m:
            raise ConfigError(f"config key 'odometry.depth_align_max_range_m' must be >= depth_align_min_range_m "
                              f"({self.depth_align_min_range_m!r}), got {self.depth_align_max_range_m!r}")
        if not 0.0 < self.keyframe_min_fraction <= 1.0:
            raise ConfigError(f"config key 'odometry.keyframe_min_fraction' must be in (0, 1], "
                              f"got {self.keyframe_min_fraction!r}")
        if not self.min_inlier_spread_px >= 0:
            raise ConfigError(f"config key 'odometry.min_inlier_spread_px' must be >= 0, "
                              f"got {self.min_inlier_spread_px!r}")
        if self.velocity_gate_sigmas < 0:
            raise ConfigError("config key 'odometry.velocity_gate_sigmas' must be >= 0 (0 turns the gate off)")
        if self.lateral_slip < 0:
            raise ConfigError("config key 'odometry.lateral_slip' must be >= 0 (0 turns the prior off)")
        if not self.keyframe_track_px >= 0:
            raise ConfigError(f"config key 'odometry.keyframe_track_px' must be >= 0 (0 turns it off), "
                              f"got {self.keyframe_track_px!r}")
        if self.depth_incidence < 0:
            raise ConfigError("config key 'odometry.depth_incidence' must be >= 0")
        if not self.wall_yaw_check_sigmas >= 0:
            raise ConfigError("config key 'odometry.wall_yaw_check_sigmas' must be >= 0 (0 turns the check off)")


@dataclass
class FrontendConfig:
    #: Depth readings used by the plane detector and the feature tracker, metres.
    min_depth: float = DEFAULT_DEPTH_RANGE[0]
    max_depth: float = DEFAULT_DEPTH_RANGE[1]
    levelling: LevellingConfig = field(default_factory=LevellingConfig)
    planes: PlaneConfig = field(default_factory=PlaneConfig)
    manhattan: ManhattanConfig = field(default_factory=ManhattanConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)

    def __post_init__(self) -> None:
        _positive("frontend", min_depth=self.min_depth)
        if self.max_depth <= self.min_depth:
            raise ConfigError("config key 'frontend.max_depth' must exceed 'frontend.min_depth'")


@dataclass
class PlaceConfig:
    """Loop-closure front-end (:mod:`planar_vo.frontend.places`): keyframe contents, place
    recognition and geometric verification. Not part of :class:`FrontendConfig`: the run's
    configuration carries it as its own ``places`` section.

    Keyframes: ``orb_features`` ORB keypoints (FAST threshold ``orb_fast_threshold``,
    halved down to ``orb_min_fast_threshold`` while fewer keypoints with depth are found),
    kept evenly over a ``grid_cols`` x ``grid_rows`` grid of the image (ORB's own
    ranking piles them onto the few high-contrast decals, which are exactly the repeated posters and doors).
    Place recognition: a bag of words without a trained vocabulary: ``hash_tables``
    random subsets of ``hash_bits`` descriptor bits (locality-sensitive hashing for the
    Hamming distance, seeded by ``hash_seed``) are the words, weighted by tf-idf over the
    keyframes indexed so far. Verification: descriptor matches passing the ``ratio`` test
    and mutual, then a planar 2-point RANSAC on the levelled 3-D points under the depth
    noise model ``depth_sigma_const + depth_sigma_quad * Z^2`` (m) and ``pixel_sigma``
    (px), chi-square ``chi2`` (3 dof: the height of a point is kept by a planar motion;
    ``height_sigma_m`` more on each point's height for levelling errors).
    Accepted only with ``min_inliers`` inliers, ``min_inlier_ratio`` of the matches with
    depth, and a spread of at least ``min_spread_m`` (std of the inliers' horizontal
    positions along their weaker principal axis; ``min_spread_many_m`` from
    ``many_inliers`` inliers on: near a corner a true revisit sees one wall and a little
    floor, while the consensus of a repeated poster, door or box at another place stayed
    within 2 cm of one line, or 0.17-0.18 m over two of them with 17-30 inliers, on the
    tuning ring). A narrow consensus is accepted only when both keyframes see a Manhattan
    frame and the odometry prior's largest translation sigma is at most
    ``narrow_max_prior_sigma_m``: the prior then tells the place from a look-alike a few
    metres away (its 99.9 % gate is ~4 sigma wide). True narrow closures on the tuning rings
    had priors of 0.10-0.27 m; a textureless corridor whose motion was not measured (prior
    8.7 m) closed frame 0 onto frame 210, 10.7 m on, through one repeated door frame (29
    inliers, 0.17 m spread). With a Manhattan frame in both
    keyframes, their relative yaw (paper eq. 1) must agree with the points' yaw within
    ``manhattan_gate_sigmas`` and ``manhattan_gate_deg`` (else rejected:
    ``manhattan_mismatch``); ``yaw_from: fused`` (default) then takes the inverse-variance
    mean of the two yaws and refits the translation at it, ``manhattan`` eq. 1 alone
    (direction-plus-point), ``points`` the points alone (worst yaw errors over 205 closures
    on the tuning rings 0.14 / 0.31 / 0.16 deg). The points' yaw is independent of the
    Manhattan factors the graph already holds; the Manhattan yaw is not. ``min_sigma_xy`` / ``min_sigma_theta_deg``: floors
    on the closure's stated sigmas (what the residuals cannot see: calibration, levelling).
    ``prior_gate_chi2``: with the graph's prediction of the relative pose given to
    ``verify_closure(prior=...)``, closures beyond this chi-square (3 dof; 16.27 is 99.9 %)
    are rejected.
    """

    orb_features: int = 1000
    orb_fast_threshold: int = 12
    orb_min_fast_threshold: int = 4
    grid_cols: int = 8
    grid_rows: int = 6
    hash_tables: int = 8
    hash_bits: int = 16
    hash_seed: int = 0
    ratio: float = 0.9
    max_hamming: int = 64
    min_matches: int = 20
    min_inliers: int = 25
    min_inlier_ratio: float = 0.25
    min_spread_m: float = 0.2
    min_spread_many_m: float = 0.08
    many_inliers: int = 80
    narrow_max_prior_sigma_m: float = 1.0
    ransac_iterations: int = 512
    chi2: float = 11.34
    depth_sigma_const: float = 0.002
    depth_sigma_quad: float = 0.002
    pixel_sigma: float = 1.0
    height_sigma_m: float = 0.01
    yaw_from: Literal["points", "manhattan", "fused"] = "fused"
    manhattan_gate_sigmas: float = 4.0
    manhattan_gate_deg: float = 1.0
    manhattan_min_score: float = 0.05
    min_sigma_xy: float = 0.005
    min_sigma_theta_deg: float = 0.05
    prior_gate_chi2: float = 16.27

    def __post_init__(self) -> None:
        _positive("places", orb_min_fast_threshold=self.orb_min_fast_threshold, prior_gate_chi2=self.prior_gate_chi2,
                  orb_features=self.orb_features,
                  grid_cols=self.grid_cols, grid_rows=self.grid_rows,
                  hash_tables=self.hash_tables, ratio=self.ratio, max_hamming=self.max_hamming,
                  min_inliers=self.min_inliers, min_spread_m=self.min_spread_m,
                  min_spread_many_m=self.min_spread_many_m, many_inliers=self.many_inliers,
                  ransac_iterations=self.ransac_iterations, chi2=self.chi2,
                  depth_sigma_const=self.depth_sigma_const, pixel_sigma=self.pixel_sigma, height_sigma_m=self.height_sigma_m,
                  manhattan_gate_sigmas=self.manhattan_gate_sigmas, manhattan_gate_deg=self.manhattan_gate_deg,
                  min_sigma_xy=self.min_sigma_xy, min_sigma_theta_deg=self.min_sigma_theta_deg)
        if not 8 <= self.hash_bits <= 24:
            raise ConfigError(f"config key 'places.hash_bits' must be within [8, 24], got {self.hash_bits!r}")
        if not self.ratio <= 1.0 or not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise ConfigError("config keys 'places.ratio' and 'places.min_inlier_ratio' must be within (0, 1]")
        if self.min_matches < 2 or self.min_inliers < 3:
            raise ConfigError("config keys 'places.min_matches' >= 2 and 'places.min_inliers' >= 3 "
                              f"required, got {self.min_matches!r} and {self.min_inliers!r}")
        if self.yaw_from not in ("points", "manhattan", "fused"):
            raise ConfigError(f"config key 'places.yaw_from' must be 'points', 'manhattan' or 'fused', "
                              f"got {self.yaw_from!r}")
        if not self.narrow_max_prior_sigma_m > 0:
            raise ConfigError("config key 'places.narrow_max_prior_sigma_m' must be > 0, "
                              f"got {self.narrow_max_prior_sigma_m!r}")
        if self.depth_sigma_quad < 0 or self.manhattan_min_score < 0:
            raise ConfigError("config keys 'places.depth_sigma_quad' and 'places.manhattan_min_score' must be >= 0")
