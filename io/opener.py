"""``open_log``: an MCAP log or a TUM RGB-D folder, by what the path is.

Apart from :mod:`planar_vo.io.log` (the reader interface every format implements) so
that the readers import the interface and this module imports the readers, with no cycle.
"""
from __future__ import annotations

import os
from pathlib import Path

from planar_vo.core.errors import InputError
from planar_vo.core.types import CameraIntrinsics
from planar_vo.io.log import RGBDLog
from planar_vo.io.mcap_reader import McapRGBDLog
from planar_vo.io.tum import TumRGBDLog


def open_log(path, *, color_topic: str | None = None, depth_topic: str | None = None,
             info_topic: str | None = None, intrinsics: CameraIntrinsics | None = None,
             sync_tolerance: float = 0.02) -> RGBDLog:
    """Open an MCAP log or a TUM RGB-D folder for streaming.

    ``intrinsics`` overrides any calibration found in the log. ``sync_tolerance``:
    largest colour/depth stamp difference (s) accepted when pairing.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if not sync_tolerance >= 0:
        raise InputError(f"--sync-tolerance must be >= 0 s, got {sync_tolerance}")
    if p.is_dir():
        if any(t is not None for t in (color_topic, depth_topic, info_topic)):
            raise InputError(f"{p}: --color-topic/--depth-topic/--info-topic apply to MCAP logs, "
                             "not TUM folders")
        return TumRGBDLog(p, intrinsics=intrinsics, sync_tolerance=sync_tolerance)
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: file is not readable (check its permissions)")
    return McapRGBDLog(p, color_topic=color_topic, depth_topic=depth_topic, info_topic=info_topic,
                       intrinsics=intrinsics, sync_tolerance=sync_tolerance)
