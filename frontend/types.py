"""What the front-end hands to the back-end and the pipeline.

All angles in radians, distances in metres. Frames as pinned in
:mod:`planar_vo.geometry` (``base`` is REP 103 base_link: x forward, y left, z up).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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
class Step:
    """Relative motion of base_link from the previous frame to this one.

    ``pose``: (3,) float64 SE(2) ``T_base_prev_base_curr`` as ``(x, y, theta)``.
    ``information``: (3, 3) float64 inverse covariance in gtsam.Pose2 tangent order
    ``[x, y, theta]``. ``status``: one of STATUS_*. ``inliers``: inlier count of the
    estimator that produced it (0 when bridged; for a partial step, the walls that fixed
    part of the translation). A partial step's information is large on theta and on the
    translation directions its walls observe, small elsewhere.
    """

    pose: np.ndarray
    information: np.ndarray
    status: str
    inliers: int = 0


@dataclass
class FrameResult:
    """Front-end output for one frame: the step into it and its Manhattan observations."""

    index: int
    stamp: float
    step: Step | None  # None for the first frame of a run
    manhattan: list[ManhattanObservation] = field(default_factory=list)  # dominant first
    timings: dict[str, float] = field(default_factory=dict)              # seconds per stage
    info: dict = field(default_factory=dict)                             # diagnostics
