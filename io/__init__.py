"""Data layer: RGB-D log readers (MCAP, TUM folders) and writers, trajectory I/O.

``io/`` (installed as ``planar_vo.io``; imports ``planar_vo.core`` and itself only):

* ``log.py``          the reader interface (``RGBDLog``, ``LogSummary``); ``opener.py``: ``open_log``;
* ``mcap_reader.py``  MCAP (ROS 2 CDR, Foxglove protobuf), damaged files too; ``tum.py``: TUM RGB-D folders;
* ``codecs.py``, ``messages.py``, ``ros2_msgdefs.py``, ``topics.py``, ``pairing.py``: decoding,
  message fields, topic choice, colour/depth pairing;
* ``mcap_writer.py``  ``RGBDLogWriter``; ``trajectory.py``: TUM and Foxglove trajectory files;
* ``atomic.py``       every writer's atomic output; ``cliargs.py``: the topic/calibration override path.
"""
from planar_vo.io.atomic import atomic_path
from planar_vo.io.log import LogSummary, RGBDLog
from planar_vo.io.opener import open_log
from planar_vo.io.mcap_writer import LogTopics, RGBDLogWriter
from planar_vo.io.trajectory import read_poses_mcap, read_tum_trajectory, write_poses_mcap, write_tum_trajectory
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame, Trajectory

__all__ = ["CameraIntrinsics", "LogSummary", "LogTopics", "Mount", "RGBDFrame", "RGBDLog",
           "RGBDLogWriter", "Trajectory", "atomic_path", "open_log", "read_poses_mcap",
           "read_tum_trajectory", "write_poses_mcap", "write_tum_trajectory"]
