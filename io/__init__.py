"""Data layer: RGB-D log readers (MCAP, TUM folders) and writers, trajectory I/O."""
from planar_vo.io.atomic import atomic_path
from planar_vo.io.log import LogSummary, RGBDLog
from planar_vo.io.opener import open_log
from planar_vo.io.mcap_writer import LogTopics, RGBDLogWriter
from planar_vo.io.trajectory import read_poses_mcap, read_tum_trajectory, write_poses_mcap, write_tum_trajectory
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame, Trajectory

__all__ = ["CameraIntrinsics", "LogSummary", "LogTopics", "Mount", "RGBDFrame", "RGBDLog",
           "RGBDLogWriter", "Trajectory", "atomic_path", "open_log", "read_poses_mcap",
           "read_tum_trajectory", "write_poses_mcap", "write_tum_trajectory"]
