"""The reading interface every RGB-D source implements, and :func:`open_log`."""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from planar_vo.core.errors import InputError
from planar_vo.core.geometry import mount_angles
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame, Trajectory

#: Frames whose depth is decoded by ``summary()`` to judge depth validity.
DEPTH_SAMPLES = 12

INTRINSICS_FLAGS = "--fx/--fy/--cx/--cy"


@dataclass
class LogSummary:
    """What a run would read from a log; ``str()`` gives the text ``planar-vo info`` prints."""

    path: str
    format: str
    color_topic: str
    depth_topic: str
    info_topic: str | None = None
    color_encoding: str = ""
    depth_encoding: str = ""
    width: int = 0
    height: int = 0
    frames: int = 0
    color_messages: int = 0
    depth_messages: int = 0
    unpaired_color: int = 0
    unpaired_depth: int = 0
    corrupt: int = 0
    first_stamp: float | None = None
    last_stamp: float | None = None
    intrinsics: CameraIntrinsics | None = None
    intrinsics_source: str = ""
    mount: Mount | None = None
    ground_truth_poses: int = 0
    depth_valid_fraction: float | None = None  # mean over the sampled frames
    depth_frames_sampled: int = 0
    truncated: str | None = None  # where reading stopped, for a cut log
    wheel_odometry: str | None = None  # WheelOdometry.describe() of the odometry found
    notes: list[str] = field(default_factory=list)

    @property
    def duration(self) -> float:
        if self.first_stamp is None or self.last_stamp is None:
            return 0.0
        return self.last_stamp - self.first_stamp

    @property
    def rate_hz(self) -> float:
        return (self.frames - 1) / self.duration if self.frames > 1 and self.duration > 0 else 0.0

    @property
    def depth_all_invalid(self) -> bool:
        return self.depth_frames_sampled > 0 and not self.depth_valid_fraction

    def __str__(self) -> str:
        lines = [f"log:          {self.path} ({self.format})",
                 f"colour:       {self.color_topic}  [{self.color_encoding}]  {self.color_messages} msgs",
                 f"depth:        {self.depth_topic}  [{self.depth_encoding}]  {self.depth_messages} msgs",
                 f"calibration:  {self.info_topic or '-'}"]
        lines.append(f"frames:       {self.frames} paired ({self.unpaired_color} colour and "
                     f"{self.unpaired_depth} depth unpaired, {self.corrupt} corrupt)")
        lines.append(f"resolution:   {self.width}x{self.height}")
        if self.first_stamp is not None:
            lines.append(f"time:         {self.first_stamp:.6f} .. {self.last_stamp:.6f}  "
                         f"duration {self.duration:.3f} s, {self.rate_hz:.2f} frames/s")
        if self.intrinsics is not None:
            k = self.intrinsics
            dist = " ".join(f"{d:g}" for d in k.distortion) if k.has_distortion else "none"
            lines.append(f"intrinsics:   fx {k.fx:.3f} fy {k.fy:.3f} cx {k.cx:.3f} cy {k.cy:.3f} "
                         f"({k.width}x{k.height}), distortion {dist}  [{self.intrinsics_source}]")
        else:
            lines.append(f"intrinsics:   none found (give {INTRINSICS_FLAGS})")
        if self.mount is not None:
            T = self.mount.T_base_cam
            pitch, roll, yaw = (math.degrees(a) for a in mount_angles(T[:3, :3]))
            lines.append(f"mount:        {self.mount.parent_frame} -> {self.mount.child_frame}: "
                         f"xyz ({T[0, 3]:.3f}, {T[1, 3]:.3f}, {T[2, 3]:.3f}) m, pitch {pitch:.2f} "
                         f"roll {roll:.2f} yaw {yaw:.2f} deg")
        else:
            lines.append("mount:        none found (no static transform chain from base_link to the camera)")
        lines.append(f"ground truth: {f'{self.ground_truth_poses} poses' if self.ground_truth_poses else 'none'}")
        lines.append(f"odometry:     {self.wheel_odometry or 'none (no nav_msgs/Odometry, no /tf odom -> base_link)'}")
        if self.depth_frames_sampled:
            lines.append(f"depth valid:  {100.0 * (self.depth_valid_fraction or 0.0):.1f} % of pixels "
                         f"(mean of {self.depth_frames_sampled} sampled frames)")
        if self.truncated:
            lines.append(f"truncated:    {self.truncated}")
        lines.extend(f"note:         {n}" for n in self.notes)
        return "\n".join(lines)


class RGBDLog(ABC):
    """A source of paired colour + depth frames. Use as a context manager.

    ``stats`` holds the counts of the most recent pass (``frames()`` or ``summary()``):
    ``paired``, ``unpaired_color``, ``unpaired_depth`` and ``corrupt``, a list of
    ``(stamp, reason)`` for frames that were skipped because they failed to decode.

    ``color_mode``: ``"bgr"`` (default) yields ``RGBDFrame.color`` as (H, W, 3) uint8 BGR;
    ``"gray"`` as (H, W) uint8 intensity, decoded as such (see :meth:`set_color_mode`).
    """

    path: Path
    color_mode: str = "bgr"

    def __init__(self, path) -> None:
        self.path = Path(path)
        self.stats: dict = _empty_stats()

    def set_color_mode(self, mode: str) -> None:
        """``"gray"``: decode only the intensity of the colour images, for consumers that
        use nothing else (the odometry and loop closure): a JPEG's luma plane is read
        without the colour conversion (1.1 against 2.4 + 0.4 ms for BGR and ``cvtColor``
        on a 960x540 frame). ``"bgr"``: full colour."""
        if mode not in ("bgr", "gray"):
            raise ValueError(f"color mode must be 'bgr' or 'gray', got {mode!r}")
        self.color_mode = mode

    @property
    @abstractmethod
    def intrinsics(self) -> CameraIntrinsics:
        """Calibration of the colour (and registered depth) images."""

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` of the colour images."""
        raise NotImplementedError

    def set_intrinsics(self, intrinsics: CameraIntrinsics | None) -> None:
        """Use ``intrinsics`` instead of the log's calibration (e.g. from command-line flags)."""
        if intrinsics is not None and not isinstance(intrinsics, CameraIntrinsics):
            raise TypeError(f"expected CameraIntrinsics, got {type(intrinsics).__name__}")
        self._intrinsics_override = intrinsics
        self._intrinsics_cache = None

    @property
    def mount(self) -> Mount | None:
        return None

    @property
    def ground_truth(self) -> Trajectory | None:
        return None

    def wheel_odometry(self, topic: str | None = None):
        """The robot's wheel odometry (:class:`planar_vo.io.wheel_odom.WheelOdometry`,
        stamped SE(2) ``T_odom_base``) or None; ``topic`` overrides the automatic choice."""
        if topic is not None:
            raise InputError(f"{self.path}: --odom-topic {topic}: this log format carries no odometry topics")
        return None

    @abstractmethod
    def frames(self, start: int = 0, stop: int | None = None, stride: int = 1) -> Iterator[RGBDFrame]:
        """Stream the paired frames with index in ``range(start, stop, stride)``, one at a time."""

    @abstractmethod
    def summary(self) -> LogSummary:
        """Scan the log (stamps, a sample of depth images) and describe it."""

    def expected_frames(self) -> int | None:
        """Colour/depth pairs the log holds at most, when known without reading it."""
        return None

    def close(self) -> None:  # noqa: B027 - optional for sources without open files
        pass

    # -------------------------------------------- a frames() pass in another process
    def reopen(self) -> None:  # noqa: B027 - optional for sources without open files
        """Open the log's files afresh, for a forked process that iterates :meth:`frames`:
        a descriptor inherited across ``fork`` shares its offset with the parent's."""

    def pass_state(self) -> dict:
        """What a :meth:`frames` pass recorded on this object (picklable), so that the
        process that forked the pass's process can :meth:`restore_pass_state` it."""
        return {"stats": self.stats}

    def restore_pass_state(self, state: dict) -> None:
        """Take over what a :meth:`frames` pass in another process recorded (:meth:`pass_state`)."""
        self.stats = state["stats"]

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[RGBDFrame]:
        return self.frames()


def _empty_stats() -> dict:
    return {"paired": 0, "unpaired_color": 0, "unpaired_depth": 0, "corrupt": []}


def check_range(start: int, stop: int | None, stride: int) -> None:
    if start < 0 or (stop is not None and stop < 0) or stride < 1:
        raise ValueError(f"frames(start={start}, stop={stop}, stride={stride}): start and stop "
                         "must be >= 0 and stride >= 1")


def depth_valid_fraction(depth: np.ndarray) -> float:
    return float(np.count_nonzero(depth)) / depth.size if depth.size else 0.0
