"""``open_log``: an MCAP log, a ROS 1 bag, a rosbag2 folder or a TUM RGB-D folder, by what the path is.

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
from planar_vo.io.rosbags_reader import is_rosbag1, open_ros_log, rosbag2_folder
from planar_vo.io.tum import TumRGBDLog


def open_log(path, *, color_topic: str | None = None, depth_topic: str | None = None,
             info_topic: str | None = None, intrinsics: CameraIntrinsics | None = None,
             sync_tolerance: float = 0.02) -> RGBDLog:
    """Open an RGB-D log for streaming: an MCAP file (ROS 2, ROS 1 or Foxglove profile), a ROS 1
    ``.bag``, a rosbag2 folder (sqlite3 or mcap storage; the folder or its ``metadata.yaml``)
    or a TUM RGB-D folder.

    ``intrinsics`` overrides any calibration found in the log. ``sync_tolerance``:
    largest colour/depth stamp difference (s) accepted when pairing.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if not sync_tolerance >= 0:
        raise InputError(f"--sync-tolerance must be >= 0 s, got {sync_tolerance}")
    if p.is_file() and not os.access(p, os.R_OK):
        raise InputError(f"{p}: file is not readable (check its permissions)")
    topics = {"color_topic": color_topic, "depth_topic": depth_topic, "info_topic": info_topic}
    folder = rosbag2_folder(p)
    if folder is not None or (p.is_file() and is_rosbag1(p)):
        return open_ros_log(folder or p, **topics, intrinsics=intrinsics, sync_tolerance=sync_tolerance)
    if p.is_dir():
        _reject_rosbag2_without_metadata(p)
        if any(t is not None for t in topics.values()):
            raise InputError(f"{p}: --color-topic/--depth-topic/--info-topic apply to MCAP logs and bags, "
                             "not TUM folders")
        return TumRGBDLog(p, intrinsics=intrinsics, sync_tolerance=sync_tolerance)
    return McapRGBDLog(p, **topics, intrinsics=intrinsics, sync_tolerance=sync_tolerance)


def _reject_rosbag2_without_metadata(folder: Path) -> None:
    """A folder of ``.db3`` / ``.mcap`` files but no metadata.yaml: a rosbag2 folder missing it."""
    stores = sorted(f.name for f in folder.iterdir() if f.suffix in (".db3", ".mcap"))
    if stores and not (folder / "rgb.txt").exists():
        raise InputError(f"{folder}: looks like a rosbag2 folder ({', '.join(stores[:3])}) but has no "
                         "metadata.yaml; restore it (`ros2 bag reindex FOLDER`) or give the .mcap file itself")
