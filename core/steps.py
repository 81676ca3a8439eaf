"""What the front-end hands to the back-end and the pipeline.

All angles in radians, distances in metres. Frames as pinned in
:mod:`planar_vo.core.geometry` (``base`` is REP 103 base_link: x forward, y left, z up).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only: the types module stays a leaf
    from planar_vo.frontend.levelling import LevellingState
    from planar_vo.frontend.planarity import OutOfPlane

#: Step status values.
STATUS_DPP = "dpp"          # direction-plus-point: Manhattan yaw + 1-point translation (Sec. 2.1)
STATUS_2PT = "2pt"          # 2-point planar homography solver + metric scale from depth (Sec. 2.2)
STATUS_PARTIAL = "partial"  # yaw observed (Manhattan frame), translation not: only what walls fix, else a guess
STATUS_BRIDGED = "bridged"  # nothing observed: motion bridged (constant velocity or zero), huge uncertainty
#: Every status, in report order.
STATUSES = (STATUS_DPP, STATUS_2PT, STATUS_PARTIAL, STATUS_BRIDGED)


@dataclass
class ManhattanObservation:
    """One frame's observation of a local Manhattan frame (vertical walls only).

    ``yaw``: heading of the Manhattan frame's horizontal axes relative to base_link,
    wrapped to [-pi/4, pi/4) because of the 90-degree ambiguity. If the robot's world
    heading is ``theta`` and the frame's world heading is ``m``, then
    ``m = theta + yaw + k * pi/2`` for some integer ``k``.
    ``sigma``: standard deviation of ``yaw`` (rad). ``score``: image-area fraction of the
    walls supporting it (Sec. 2.1). ``track_id``: the front-end's id for the local frame
    tracked across frames (-1 if untracked); the back-end does its own association.
    """

    yaw: float
    sigma: float
    score: float
    track_id: int = -1


@dataclass
class WallObservation:
    """One vertical wall seen in one frame, in base_link (REP 103: x forward, y left).

    ``normal_yaw``: heading (rad, counter-clockwise from base_link x) of the wall's
    horizontal normal, pointing from the robot towards the wall. ``offset``: distance (m)
    from the base_link origin to the wall plane along that normal (> 0 in front of the
    wall), i.e. the wall is ``{p : n . p = offset}`` with ``n = (cos, sin)(normal_yaw)``.
    ``sigma``: standard deviation (m) of ``offset`` in one image, the plane fit and the
    depth errors correlated across the plane (:attr:`Plane.yaw_sigma`'s systematic term).
    ``support``: image fraction of the wall's points. The back-end ties frames that see the
    same wall to one wall landmark (backend/walls.py): a wall bounds the drift across it.
    """

    normal_yaw: float
    offset: float
    sigma: float
    support: float = 0.0


@dataclass
class KeyframeLink:
    """The motion of base_link from a keyframe ``lag`` frames back to this frame, measured
    directly (not chained): ``pose`` (3,) ``T_base_k_base_curr`` as ``(x, y, theta)`` with
    (3, 3) ``information`` in gtsam.Pose2 tangent order. The back-end puts this factor in
    place of the step's own (the step is then the difference of two keyframe motions and
    its error is not independent of the previous step's)."""

    lag: int
    pose: np.ndarray
    information: np.ndarray


@dataclass
class KeyframeYaw:
    """The heading change of base_link from a keyframe ``lag`` frames back to this frame,
    measured directly by the 2-point method (its scale refused): ``yaw`` (rad,
    counter-clockwise, REP 103) of ``variance`` (rad^2). Carried by a partial step whose
    yaw is the difference of two such (:meth:`PlanarOdometry._keyframe_yaw`): the back-end
    ties the keyframe's heading to this frame's with it and keeps only the translation of
    the step's own factor, whose yaw error is not independent of the previous step's."""

    lag: int
    yaw: float
    variance: float


@dataclass
class GapLink:
    """The motion of base_link between two frames, measured after a gap of unmeasured steps
    (frontend/gapresection.py): from frame ``lag_from`` back to frame ``lag_to`` back (this
    frame is 0 back), ``pose`` (3,) ``T_base_from_base_to`` as ``(x, y, theta)`` with (3, 3)
    ``information`` in gtsam.Pose2 tangent order. Its translation is a resection's; its
    yaw is stated at the bridged sigma, since the walls that gave the resection its yaw are
    in the steps' own factors already. The back-end adds it as a factor of its own."""

    lag_from: int
    lag_to: int
    pose: np.ndarray
    information: np.ndarray


@dataclass
class Step:
    """Relative motion of base_link from the previous frame to this one.

    ``pose``: (3,) float64 SE(2) ``T_base_prev_base_curr`` as ``(x, y, theta)``.
    ``information``: (3, 3) float64 inverse covariance in gtsam.Pose2 tangent order
    ``[x, y, theta]``. ``status``: one of STATUS_*. ``inliers``: inlier count of the
    estimator that produced it (0 when bridged; for a partial step, the walls that fixed
    part of the translation). A partial step's information is large on theta and on the
    translation directions its walls observe, small elsewhere. ``keyframe``: the motion
    from the keyframe the step was measured against, when that is an earlier frame than
    the previous one (:class:`KeyframeLink`), else None; ``keyframe_yaw``: the heading
    change from the keyframe alone (:class:`KeyframeYaw`), else None. ``guess_information``: (3, 3),
    the part of ``information`` that comes from the front-end's constant-velocity guess
    rather than a measurement (partial and bridged steps), else None: a back-end with a
    motion prior of its own puts that prior in its place, not on top of it.
    ``guess_copies``: for such a step, how many steps in a row (this one included) have
    copied the guessed velocity since the translation was last measured (their guesses err
    alike); 0 for a measured step. ``translation_measured``: a partial step whose whole
    translation was measured, not guessed (resected against far corners,
    frontend/farcorners.py): a back-end's motion prior treats it as a measured step.
    """

    pose: np.ndarray
    information: np.ndarray
    status: str
    inliers: int = 0
    keyframe: KeyframeLink | None = None
    keyframe_yaw: KeyframeYaw | None = None
    guess_information: np.ndarray | None = None
    guess_copies: int = 0
    translation_measured: bool = False


@dataclass
class FrameDiagnostics:
    """What the front-end saw and decided for one frame: for the report and tests only.

    Counts of corners and matches, planes found, the levelling in use, and per estimator
    what it returned (dicts of plain numbers); the back-end never reads it.
    """

    features: int = 0                 # corners in this frame
    new_corners: int = 0              # of which detected in this frame
    matches: int = 0                  # to the previous frame
    matches_with_depth: int = 0       # of which with a depth reading in both frames
    planes: int = 0                   # floor, ceiling and walls found
    walls: int = 0
    wall_fraction: float = 0.0        # image fraction covered by walls
    floor_seen: bool = False
    floor_fraction: float = 0.0
    floor_normal_cam: list | None = None   # (3,) floor normal in the camera frame, when seen
    camera_height_m: float | None = None   # floor offset, when seen
    levelling: LevellingState | None = None  # the levelling after this frame's floor
    out_of_plane: OutOfPlane | None = None   # 6-DoF fit on frames without a floor (planarity)
    dpp: list[dict] = field(default_factory=list)  # direction-plus-point attempts, one per frame tried
    two_point: dict | None = None     # the 2-point estimate: status, inliers, scale inliers, iterations
    yaw_check: dict | None = None     # Manhattan yaw against the 2-point yaw (veto)
    group_changed: dict | None = None  # the frame's yaw disagreed with eq. 1 wall by wall: walls used
    rejected: list[dict] = field(default_factory=list)  # estimates refused, and why
    partial: dict | None = None       # a partial step: the prior's kind and the walls used
    partial_dense: dict | None = None  # a partial step's depth alignment: s (m) along the guessed direction, sigma, points (no s_m: none found)
    #: a partial step's 2-point yaw measured from the keyframe: its age, inliers, the step's
    #: yaw so found and the frame-to-frame one (deg), their disagreement in sigmas
    keyframe_yaw: dict | None = None
    depth_yaw: dict | None = None  # a step no wall or corner turned: its yaw from the depth images (no yaw_deg: none found)
    #: a partial step resected against far corners (frontend/farcorners.py): corners used,
    #: the levelled translation (t_x, t_z) and its sigmas (m), whether it refuted the guess,
    #: or ``refused``: why the platform cannot make that motion ("beyond reach", "sideways")
    far: dict | None = None
    #: a partial step's translation measured from the keyframe: its age, the motion's
    #: inliers and depths, its yaw's disagreement with the chain's in sigmas, and
    #: ``refused`` when the platform cannot make it (PlanarOdometry._keyframe_translation)
    partial_keyframe: dict | None = None
    bridge: str | None = None         # a bridged step: "constant_velocity" or "zero"
    gap_links: int | None = None      # frames of an earlier gap resected at this frame (frontend/gapresection.py)
    #: the keyframe the step was measured against: frames since it, its corners still
    #: tracked, whether the step was re-measured against it (frontend/keyframe.py)
    keyframe: dict | None = None


@dataclass
class FrameResult:
    """Front-end output for one frame: the step into it, its Manhattan observations and
    the walls it saw (``walls``: :class:`WallObservation`, those the Manhattan frames use),
    and the motions into an earlier gap's frames that could be measured only now (``gap_links``)."""

    index: int
    stamp: float
    step: Step | None  # None for the first frame of a run
    manhattan: list[ManhattanObservation] = field(default_factory=list)  # dominant first
    timings: dict[str, float] = field(default_factory=dict)              # seconds per stage
    diagnostics: FrameDiagnostics = field(default_factory=FrameDiagnostics)
    walls: list[WallObservation] = field(default_factory=list)
    #: motions into the frames of an earlier gap, measured now (:class:`GapLink`)
    gap_links: list[GapLink] = field(default_factory=list)
