"""Camera levelling: the mount's pitch, roll and height, given or estimated from the floor.

The paper removes the camera's pitch and roll so that planar motion reduces to yaw plus
a horizontal translation (Sec. 2.1, Fig. 1). Precedence for each quantity:
configuration (``LevellingConfig.pitch_deg`` / ``roll_deg`` / ``height_m``), then the
log's mount (``Mount.T_base_cam`` from /tf_static), then the floor: the floor normal seen
in the camera is gravity (:func:`planar_vo.core.geometry.tilt_from_gravity`) and its offset is
the camera height. Floor estimates are pooled by a running median over a window, with
estimates far from the current value rejected once initialised.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from planar_vo.core import geometry
from planar_vo.frontend.config import LevellingConfig
from planar_vo.core.types import Mount


@dataclass
class LevellingState:
    """Current levelling. Angles in radians (REP 103 mount pitch/roll), height in metres.

    ``source``: where the tilt comes from ("config", "mount", "floor", "initial").
    ``ready``: the tilt is trusted (given, or pooled from ``init_frames`` floor estimates).
    ``n_floor``: floor estimates accepted so far; ``n_rejected``: estimates gated out.
    """

    pitch: float
    roll: float
    height: float | None
    source: str
    ready: bool
    n_floor: int = 0
    n_rejected: int = 0

    @property
    def R_lev_cam(self) -> np.ndarray:
        """(3, 3) float64 rotation cam -> lev."""
        return geometry.levelling_rotation(self.pitch, self.roll)

    def as_dict(self) -> dict:
        return {"pitch_deg": math.degrees(self.pitch), "roll_deg": math.degrees(self.roll),
                "height_m": self.height, "source": self.source, "ready": self.ready,
                "n_floor": self.n_floor, "n_rejected": self.n_rejected}


class Levelling:
    """Holds the levelling of one camera and refines it from floor observations.

    ``mount``: the log's mount, if any. Use :meth:`observe_floor` with each frame's floor
    plane (normal and offset in the *current* levelled frame) and read :attr:`state`.
    """

    def __init__(self, config: LevellingConfig | None = None, mount: Mount | None = None):
        self.config = config or LevellingConfig()
        c = self.config
        self._given_mount = mount
        pitch, roll = math.radians(c.initial_pitch_deg), 0.0
        height = None
        source, tilt_fixed = "initial", False
        self._mount_xy_yaw = np.zeros(3)  # base x, y and yaw of the camera (from the mount)
        if mount is not None:
            T = np.asarray(mount.T_base_cam, dtype=float)
            if T.shape != (4, 4):
                raise ValueError(f"Mount.T_base_cam must be (4, 4), got {T.shape}")
            if not np.isfinite(T[:3, :3]).all():
                raise ValueError("Mount.T_base_cam has a non-finite rotation")
            pitch, roll, yaw = geometry.mount_angles(T[:3, :3])
            height = float(T[2, 3]) if math.isfinite(T[2, 3]) else None  # NaN: measure it
            self._mount_xy_yaw = np.nan_to_num(np.array([T[0, 3], T[1, 3], yaw]))
            source, tilt_fixed = "mount", True
        if c.pitch_deg is not None or c.roll_deg is not None:
            pitch = math.radians(c.pitch_deg) if c.pitch_deg is not None else pitch
            roll = math.radians(c.roll_deg) if c.roll_deg is not None else roll
            source, tilt_fixed = "config", c.pitch_deg is not None and c.roll_deg is not None
        self.tilt_fixed = tilt_fixed
        self.height_fixed = c.height_m is not None or height is not None
        if c.height_m is not None:
            height = float(c.height_m)
        self.state = LevellingState(pitch, roll, height, source, ready=tilt_fixed)
        self._pitch = deque(maxlen=c.window)
        self._roll = deque(maxlen=c.window)
        self._height = deque(maxlen=c.window)

    @property
    def needs_floor(self) -> bool:
        """Whether floor observations can still change the levelling."""
        if self.tilt_fixed and self.height_fixed:
            return False
        s = self.state
        return not (s.ready and (s.height is not None) and not self.config.refine)

    def observe_floor(self, normal_lev: np.ndarray, offset: float, support: float) -> bool:
        """Feed one floor plane ``normal_lev . X_lev = offset`` (normal pointing down, (3,)).

        Returns True when the levelling rotation changed (callers re-level cached rays).
        """
        c = self.config
        s = self.state
        if support < c.min_floor_support or not self.needs_floor:
            return False
        n_cam = s.R_lev_cam.T @ np.asarray(normal_lev, dtype=float)
        pitch, roll = geometry.tilt_from_gravity(n_cam)
        if s.ready and not self.tilt_fixed:
            jump = math.hypot(pitch - s.pitch, roll - s.roll)
            if jump > math.radians(c.max_tilt_jump_deg):
                s.n_rejected += 1
                return False
        if s.height is not None and self.height_fixed is False and len(self._height) >= c.init_frames:
            if abs(offset - s.height) > 0.2 * s.height:
                s.n_rejected += 1
                return False
        s.n_floor += 1
        old = (s.pitch, s.roll)
        if not self.tilt_fixed:
            self._pitch.append(pitch)
            self._roll.append(roll)
            s.pitch = float(np.median(self._pitch))
            s.roll = float(np.median(self._roll))
            s.source = "floor"
            s.ready = len(self._pitch) >= c.init_frames
        if not self.height_fixed:
            self._height.append(float(offset))
            s.height = float(np.median(self._height))
        # Re-levelling below 0.01 deg changes nothing measurable; skip the cache rebuild.
        return math.hypot(s.pitch - old[0], s.roll - old[1]) > math.radians(0.01)

    def mount(self) -> Mount:
        """The mount in use: the given one, or one built from the levelling.

        A built mount puts base_link on the floor under the camera (x = y = 0, z = height)
        with the camera's heading along base x; given x, y and yaw are kept.
        """
        s = self.state
        if self._given_mount is not None and s.source == "mount" and self.height_fixed and self.config.height_m is None:
            return self._given_mount
        x, y, yaw = self._mount_xy_yaw
        T = np.eye(4)
        T[:3, :3] = geometry.mount_rotation(s.pitch, s.roll, yaw)
        T[:3, 3] = (x, y, s.height if s.height is not None else 0.0)
        if self._given_mount is not None:
            return Mount(T, self._given_mount.parent_frame, self._given_mount.child_frame)
        return Mount(T)
