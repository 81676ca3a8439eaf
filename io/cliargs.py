"""Command-line flags for choosing and calibrating an RGB-D log, shared by commands.

``add_log_arguments(parser)`` adds the positional ``log`` and the topic, intrinsics and
sync flags; ``open_log_from_args(args)`` opens the log with them applied.
"""
from __future__ import annotations

import argparse

from planar_vo.core.errors import InputError
from planar_vo.io.log import INTRINSICS_FLAGS, RGBDLog
from planar_vo.io.opener import open_log
from planar_vo.core.types import CameraIntrinsics


def add_log_arguments(parser: argparse.ArgumentParser, *, positional: bool = True) -> None:
    if positional:
        parser.add_argument("log", help="MCAP log, ROS 1 .bag, rosbag2 folder (or its metadata.yaml) or TUM RGB-D folder")
    g = parser.add_argument_group("input selection")
    g.add_argument("--color-topic", help="colour image topic (default: found automatically)")
    g.add_argument("--depth-topic", help="depth image topic (default: found automatically)")
    g.add_argument("--info-topic", help="CameraInfo / CameraCalibration topic (default: found automatically)")
    g.add_argument("--sync-tolerance", type=float, default=0.02, metavar="S",
                   help="largest colour/depth stamp difference paired, seconds (default 0.02)")
    k = parser.add_argument_group("intrinsics (override the log's calibration; give all four)")
    for name in ("fx", "fy", "cx", "cy"):
        k.add_argument(f"--{name}", type=float, metavar="PX")
    k.add_argument("--distortion", type=float, nargs="+", metavar="D",
                   help="plumb_bob k1 k2 p1 p2 [k3] (default: none)")


def open_log_from_args(args: argparse.Namespace) -> RGBDLog:
    """Open ``args.log`` honouring the flags of :func:`add_log_arguments`."""
    values = [getattr(args, n, None) for n in ("fx", "fy", "cx", "cy")]
    return open_log_with_overrides(
        args.log, color_topic=getattr(args, "color_topic", None), depth_topic=getattr(args, "depth_topic", None),
        info_topic=getattr(args, "info_topic", None), sync_tolerance=getattr(args, "sync_tolerance", 0.02),
        intrinsics=values if any(v is not None for v in values) else None,
        distortion=getattr(args, "distortion", None))


def open_log_with_overrides(path, *, color_topic: str | None = None, depth_topic: str | None = None,
                            info_topic: str | None = None, sync_tolerance: float = 0.02,
                            intrinsics=None, distortion=None) -> RGBDLog:
    """Open the log at ``path`` with topic choices and a calibration override applied -- the one
    override path of every command (``planar-vo run`` passes its ``input`` configuration).

    ``intrinsics``: ``(fx, fy, cx, cy)`` pixels for the images as they are, or None for the
    log's own; ``distortion``: plumb_bob ``(k1, k2, p1, p2[, k3])`` or None (none).
    """
    log = open_log(path, color_topic=color_topic, depth_topic=depth_topic, info_topic=info_topic,
                   sync_tolerance=sync_tolerance)
    try:
        if intrinsics is not None or distortion:
            _override_intrinsics(log, list(intrinsics or (None,) * 4), distortion)
    except BaseException:
        log.close()
        raise
    return log


def _override_intrinsics(log: RGBDLog, values: list, dist) -> None:
    if any(v is None for v in values):
        raise InputError(f"give all four of {INTRINSICS_FLAGS} (missing "
                         f"{', '.join('--' + n for n, v in zip(('fx', 'fy', 'cx', 'cy'), values) if v is None)})")
    if dist is not None and len(dist) not in (4, 5):
        raise InputError(f"--distortion takes 4 or 5 plumb_bob coefficients, got {len(dist)}")
    if values[0] <= 0 or values[1] <= 0:
        raise InputError(f"--fx and --fy must be positive, got {values[0]} and {values[1]}")
    w, h = log.image_size  # the override is for the images as they are
    log.set_intrinsics(CameraIntrinsics(w, h, *values, tuple(dist) if dist else (0.0,) * 5))
