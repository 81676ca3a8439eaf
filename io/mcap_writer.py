"""Write RGB-D logs as MCAP, shaped like real recordings (iai_kinect2 topic names).

Two profiles: ``ros2`` (CDR-encoded sensor_msgs / tf2_msgs / geometry_msgs, what
``ros2 bag record -s mcap`` produces) and ``foxglove`` (protobuf Foxglove schemas).
The file is written under a temporary name and renamed on a successful ``close()``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from planar_vo.io import messages as m
from planar_vo.io import ros2_msgdefs
from planar_vo.io.atomic import AtomicFile
from planar_vo.io.codecs import COLOR_ENCODINGS, DEPTH_ENCODINGS, encode_color, encode_depth
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame

PROFILES = ("ros2", "foxglove")
CHUNK_COMPRESSIONS = ("zstd", "lz4", "none")

#: iai_kinect2 quarter-HD topic names.
KINECT2_QHD = "/kinect2/qhd"
GROUND_TRUTH_TOPIC = "/ground_truth"
TF_STATIC_TOPIC = "/tf_static"
TF_TOPIC = "/tf"
ODOM_TOPIC = "/odom"
#: Where wheel odometry goes: a nav_msgs/Odometry (Foxglove: PoseInFrame) topic, or /tf.
WHEEL_ODOM_ON = ("odom", "tf")


@dataclass(frozen=True)
class LogTopics:
    """Topic names of an RGB-D log."""

    color: str
    depth: str
    info: str
    tf_static: str = TF_STATIC_TOPIC
    ground_truth: str = GROUND_TRUTH_TOPIC
    odom: str = ODOM_TOPIC
    tf: str = TF_TOPIC

    @classmethod
    def kinect2(cls, color_encoding: str, depth_encoding: str, prefix: str = KINECT2_QHD) -> "LogTopics":
        """iai_kinect2 names; ``/compressed`` is appended for compressed encodings."""
        cc = "/compressed" if color_encoding in ("jpeg", "png") else ""
        dc = "/compressed" if depth_encoding in ("png", "compressedDepth") else ""
        return cls(f"{prefix}/image_color_rect{cc}", f"{prefix}/image_depth_rect{dc}",
                   f"{prefix}/camera_info")


class RGBDLogWriter:
    """Context manager writing :class:`RGBDFrame` records (and ground truth) to an MCAP.

    ``write(frame)`` writes the colour image, the depth image and the calibration, all
    stamped ``frame.stamp`` (header stamp = log time = publish time). ``mount`` is
    written once on ``/tf_static`` (``base_frame -> camera_frame``) with the first stamp.
    ``write_ground_truth(stamp, T_world_cam)`` adds a pose of the camera optical frame in
    ``world`` on ``/ground_truth``. ``topics`` overrides names (a :class:`LogTopics` or a
    dict with any of its fields). ``chunk_compression``: ``zstd`` (default), ``lz4`` or
    ``none``.
    """

    def __init__(self, path, intrinsics: CameraIntrinsics, *, profile: str = "ros2",
                 mount: Mount | None = None, color_encoding: str = "jpeg",
                 depth_encoding: str = "png", topics: LogTopics | dict | None = None,
                 jpeg_quality: int = 90, camera_frame: str = "kinect2_rgb_optical_frame",
                 base_frame: str = "base_link", chunk_compression: str = "zstd",
                 chunk_size: int = 4 * 1024 * 1024):
        if profile not in PROFILES:
            raise ValueError(f"profile {profile!r} is not one of {PROFILES}")
        if color_encoding not in COLOR_ENCODINGS:
            raise ValueError(f"color_encoding {color_encoding!r} is not one of {COLOR_ENCODINGS}")
        if depth_encoding not in DEPTH_ENCODINGS:
            raise ValueError(f"depth_encoding {depth_encoding!r} is not one of {DEPTH_ENCODINGS}")
        if chunk_compression not in CHUNK_COMPRESSIONS:
            raise ValueError(f"chunk_compression {chunk_compression!r} is not one of {CHUNK_COMPRESSIONS}")
        if not isinstance(intrinsics, CameraIntrinsics):
            raise TypeError(f"intrinsics must be a CameraIntrinsics, got {type(intrinsics).__name__}")
        defaults = LogTopics.kinect2(color_encoding, depth_encoding)
        if isinstance(topics, dict):
            unknown = set(topics) - set(defaults.__dataclass_fields__)
            if unknown:
                raise ValueError(f"unknown topic keys {sorted(unknown)}; use {sorted(defaults.__dataclass_fields__)}")
            topics = LogTopics(**{**defaults.__dict__, **topics})
        self.topics: LogTopics = topics or defaults
        self.path = os.fspath(path)
        self.intrinsics = intrinsics
        self.profile = profile
        self.mount = mount
        self.color_encoding, self.depth_encoding = color_encoding, depth_encoding
        self.jpeg_quality = int(jpeg_quality)
        self.camera_frame, self.base_frame = camera_frame, base_frame
        self.frames_written = 0
        self.poses_written = 0
        self._mount_written = mount is None
        self._closed = False

        self._open_writer(chunk_compression, chunk_size)

    def _open_writer(self, chunk_compression: str, chunk_size: int) -> None:
        from mcap.writer import CompressionType
        compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                       "none": CompressionType.NONE}[chunk_compression]
        self._file = AtomicFile(self.path)
        try:
            if self.profile == "ros2":
                from mcap_ros2.writer import Writer
                self._writer = Writer(self._file.file, chunk_size=chunk_size, compression=compression)
                self._schemas = {name: self._writer.register_msgdef(name, text)
                                 for name, text in ros2_msgdefs.DEFINITIONS.items()}
            else:
                from mcap_protobuf.writer import Writer
                self._writer = Writer(self._file.file, chunk_size=chunk_size, compression=compression)
        except BaseException:
            self._file.discard()
            raise

    def _finish(self) -> None:
        self._writer.finish()

    # ------------------------------------------------------------------ messages
    def _put(self, topic: str, stamp: float, ros2_type: str, ros2_msg, fox_msg_fn) -> None:
        t = m.stamp_to_ns(stamp)
        if self.profile == "ros2":
            self._writer.write_message(topic, self._schemas[ros2_type], ros2_msg(),
                                       log_time=t, publish_time=t)
        else:
            self._writer.write_message(topic, fox_msg_fn(), log_time=t, publish_time=t)

    def _write_mount(self, stamp: float) -> None:
        if self._mount_written:
            return
        self._mount_written = True
        tf = [(stamp, self.base_frame, self.camera_frame, np.asarray(self.mount.T_base_cam, float))]
        self._put(self.topics.tf_static, stamp, "tf2_msgs/msg/TFMessage",
                  lambda: m.ros2_tf_message(tf), lambda: m.foxglove_frame_transforms(tf))

    def write(self, frame: RGBDFrame) -> None:
        """Write one frame: colour, depth and calibration, all stamped ``frame.stamp``."""
        self._check_open()
        H, W = self.intrinsics.height, self.intrinsics.width
        color, depth = np.asarray(frame.color), np.asarray(frame.depth)
        if color.shape != (H, W, 3) or color.dtype != np.uint8:
            raise ValueError(f"frame {frame.index}: colour must be ({H}, {W}, 3) uint8 BGR to match "
                             f"the intrinsics, got {color.shape} {color.dtype}")
        if depth.shape != (H, W):
            raise ValueError(f"frame {frame.index}: depth must be ({H}, {W}) to match the intrinsics, "
                             f"got {depth.shape}")
        stamp = float(frame.stamp)
        self._write_mount(stamp)
        fox = self.profile == "foxglove"
        cenc = encode_color(color, self.color_encoding, jpeg_quality=self.jpeg_quality, foxglove=fox)
        denc = encode_depth(depth, self.depth_encoding, foxglove=fox)
        for topic, enc in ((self.topics.color, cenc), (self.topics.depth, denc)):
            self._put(topic, stamp,
                      "sensor_msgs/msg/Image" if enc.raw else "sensor_msgs/msg/CompressedImage",
                      lambda enc=enc: m.ros2_image(stamp, self.camera_frame, H, W, enc),
                      lambda enc=enc: m.foxglove_image(stamp, self.camera_frame, H, W, enc))
        self._put(self.topics.info, stamp, "sensor_msgs/msg/CameraInfo",
                  lambda: m.ros2_camera_info(stamp, self.camera_frame, self.intrinsics),
                  lambda: m.foxglove_camera_calibration(stamp, self.camera_frame, self.intrinsics))
        self.frames_written += 1

    def write_ground_truth(self, stamp: float, T_world_cam: np.ndarray) -> None:
        """Write the (4, 4) pose of the camera optical frame in ``world`` at ``stamp``."""
        self._check_open()
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"T_world_cam must be (4, 4), got {T.shape}")
        stamp = float(stamp)
        self._write_mount(stamp)
        self._put(self.topics.ground_truth, stamp, "geometry_msgs/msg/PoseStamped",
                  lambda: m.ros2_pose_stamped(stamp, "world", T),
                  lambda: m.foxglove_pose_in_frame(stamp, "world", T))
        self.poses_written += 1

    def write_wheel_odometry(self, stamp: float, T_odom_base: np.ndarray, *, on: str = "odom",
                             twist=(0.0, 0.0, 0.0)) -> None:
        """Write one wheel odometry sample, the (4, 4) pose of ``base_frame`` in ``odom``:
        ``on="odom"`` as nav_msgs/Odometry (Foxglove profile: PoseInFrame in ``odom``) on
        ``topics.odom``; ``on="tf"`` as the transform ``odom -> base_frame`` on ``topics.tf``.
        ``twist``: ``(vx, vy, omega)`` in base_link (ROS 2 Odometry only)."""
        self._check_open()
        if on not in WHEEL_ODOM_ON:
            raise ValueError(f"wheel odometry on={on!r}: use one of {WHEEL_ODOM_ON}")
        T = np.asarray(T_odom_base, dtype=np.float64)
        stamp = float(stamp)
        if on == "tf":
            tf = [(stamp, "odom", self.base_frame, T)]
            self._put(self.topics.tf, stamp, "tf2_msgs/msg/TFMessage",
                      lambda: m.ros2_tf_message(tf), lambda: m.foxglove_frame_transforms(tf))
            return
        self._put(self.topics.odom, stamp, "nav_msgs/msg/Odometry",
                  lambda: m.ros2_odometry(stamp, "odom", self.base_frame, T, twist, pose_var=(1e-4, 1e-4, 1e-3)),
                  lambda: m.foxglove_pose_in_frame(stamp, "odom", T))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record ``name`` with string keys and values."""
        self._check_open()
        self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    # ----------------------------------------------------------------- lifecycle
    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"RGBDLogWriter for {self.path} is already closed")

    def close(self) -> None:
        """Finish the MCAP (summary, footer) and rename it onto its final name."""
        if self._closed:
            return
        try:
            self._write_mount(0.0)
            self._finish()
        except BaseException:
            self.abort()
            raise
        self._closed = True
        self._file.commit()

    def abort(self) -> None:
        """Drop the partial file; nothing appears under ``path``."""
        if not self._closed:
            self._closed = True
            self._file.discard()

    def __enter__(self) -> "RGBDLogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def __del__(self):  # an abandoned writer leaves no temporary file behind
        try:
            self.abort()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass
