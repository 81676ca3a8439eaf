"""Data records produced by the readers and consumed by the front-end.

Units: metres, seconds, radians. Images are numpy arrays owned by the record.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole calibration of the colour image (depth is registered to it).

    ``distortion`` follows OpenCV / ROS ``plumb_bob`` order ``(k1, k2, p1, p2, k3)``;
    all zeros for rectified images (iai_kinect2 ``*_rect`` topics).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0.0 for d in self.distortion)

    def scaled(self, width: int, height: int) -> "CameraIntrinsics":
        """The same camera at another resolution (e.g. Kinect v2 hd -> qhd)."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(width, height, self.fx * sx, self.fy * sy,
                                (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5,
                                self.distortion)


@dataclass(frozen=True)
class Mount:
    """Rigid camera mount ``T_base_cam`` (4, 4): pose of the optical frame in base_link."""

    T_base_cam: np.ndarray
    parent_frame: str = "base_link"
    child_frame: str = "camera_optical_frame"


@dataclass
class RGBDFrame:
    """One colour image with its registered depth.

    ``color``: (H, W, 3) uint8 BGR. ``depth``: (H, W) float32 metres, 0 where invalid
    (readers map NaN, inf, negative and zero to 0). ``stamp``: colour timestamp, seconds.
    ``index``: position of the frame in the paired stream (0-based).
    """

    index: int
    stamp: float
    color: np.ndarray
    depth: np.ndarray
    depth_stamp: float | None = None
    meta: dict = field(default_factory=dict)


@dataclass
class Trajectory:
    """Stamped poses: ``stamps`` (N,) float64 seconds, ``poses`` (N, 4, 4) float64 ``T_world_frame``."""

    stamps: np.ndarray
    poses: np.ndarray
    frame_id: str = "world"
    child_frame_id: str = "camera_optical_frame"

    def __post_init__(self) -> None:
        self.stamps = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(self.stamps) != len(self.poses):
            raise ValueError(f"Trajectory: {len(self.stamps)} stamps but {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) float64 translations."""
        return self.poses[:, :3, 3]
