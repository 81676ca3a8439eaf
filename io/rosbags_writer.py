"""Write RGB-D logs as ROS 1 bags, rosbag2 folders or ROS 1-profile MCAP (for tests and tools).

:class:`RosLogWriter` is :class:`~planar_vo.io.mcap_writer.RGBDLogWriter` with another
container under it: the same topics, frames, calibration, mount and ground truth, built
by the same ROS 2 message builders, serialised by ``rosbags`` as ROS 1 or CDR and
written by ``rosbags``' bag writers (or ``mcap``'s, for the ROS 1 profile of MCAP, which
``rosbags`` does not write). :func:`open_log_writer` picks the writer for a container.
"""
from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

from planar_vo.io import messages as m
from planar_vo.io import rosmsg
from planar_vo.io.atomic import AtomicFile, AtomicTree
from planar_vo.io.mcap_writer import RGBDLogWriter
from planar_vo.core.types import CameraIntrinsics

#: Containers a log can be written in. ``mcap`` is the MCAP writer's own (``profile``
#: ros2 or foxglove); the rest are ROS containers with ROS 1 or ROS 2 messages.
CONTAINERS = ("mcap", "bag", "rosbag2-sqlite3", "rosbag2-mcap", "mcap-ros1")
#: rosbag2 metadata version written (what ROS 2 Jazzy writes).
ROSBAG2_VERSION = 8


def open_log_writer(path, intrinsics: CameraIntrinsics, *, container: str = "mcap", **kwargs) -> RGBDLogWriter:
    """A log writer for ``container`` (see :data:`CONTAINERS`); ``kwargs`` as for RGBDLogWriter."""
    if container not in CONTAINERS:
        raise ValueError(f"container {container!r} is not one of {CONTAINERS}")
    if container == "mcap":
        return RGBDLogWriter(path, intrinsics, **kwargs)
    if kwargs.get("profile", "ros2") != "ros2":
        raise ValueError(f"container {container} holds ROS messages; profile {kwargs['profile']!r} applies "
                         "to the mcap container only")
    kwargs.pop("profile", None)
    return RosLogWriter(path, intrinsics, container=container, **kwargs)


class RosLogWriter(RGBDLogWriter):
    """:class:`RGBDLogWriter` writing a ROS 1 bag (``bag``), a rosbag2 folder
    (``rosbag2-sqlite3``, ``rosbag2-mcap``) or an MCAP in the ROS 1 profile (``mcap-ros1``)."""

    def __init__(self, path, intrinsics: CameraIntrinsics, *, container: str, **kwargs):
        if container not in CONTAINERS[1:]:
            raise ValueError(f"container {container!r} is not one of {CONTAINERS[1:]}")
        self.container = container
        self.encoding = rosmsg.CDR if container.startswith("rosbag2") else rosmsg.ROS1
        self._connections: dict[str, object] = {}
        super().__init__(path, intrinsics, profile="ros2", **kwargs)

    def _open_writer(self, chunk_compression: str, chunk_size: int) -> None:  # noqa: ARG002
        if self.container == "mcap-ros1":
            from mcap.writer import CompressionType, Writer
            self._file = AtomicFile(self.path)
            compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                           "none": CompressionType.NONE}[chunk_compression]
            self._writer = Writer(self._file.file, chunk_size=chunk_size, compression=compression)
            self._writer.start(profile="ros1", library="planar-vo")
            return
        self._file = AtomicTree(self.path)
        # One thread makes every call into the rosbags writer: its sqlite3 connection may
        # only be used by the thread that opened it, and callers write from worker threads.
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="planar-vo-bag-writer")
        try:
            if self.container == "bag":
                from rosbags.rosbag1 import Writer
                self._writer = Writer(self._file.tmp_path)
            else:
                from rosbags.rosbag2 import StoragePlugin, Writer
                plugin = StoragePlugin.SQLITE3 if self.container.endswith("sqlite3") else StoragePlugin.MCAP
                self._writer = Writer(self._file.tmp_path, version=ROSBAG2_VERSION, storage_plugin=plugin)
            self._call(self._writer.open)
        except BaseException:
            self._file.discard()
            self._thread.shutdown()
            raise

    def _call(self, fn, *args, **kwargs):
        thread = getattr(self, "_thread", None)
        return fn(*args, **kwargs) if thread is None else thread.submit(fn, *args, **kwargs).result()

    def _connection(self, topic: str, typename: str):
        conn = self._connections.get(topic)
        if conn is None:
            if self.container == "mcap-ros1":
                text, md5 = rosmsg.ros1_msgdef(typename)
                name = typename.replace("/msg/", "/")
                schema = self._writer.register_schema(name, "ros1msg", text.encode("utf-8"))
                conn = self._writer.register_channel(topic, rosmsg.ROS1, schema, {"md5sum": md5})
            else:
                conn = self._call(self._writer.add_connection, topic, typename,
                                  typestore=rosmsg.typestore(self.encoding))
            self._connections[topic] = conn
        return conn

    def _put(self, topic: str, stamp: float, ros2_type: str, ros2_msg, fox_msg_fn) -> None:  # noqa: ARG002
        t = m.stamp_to_ns(stamp)
        conn = self._connection(topic, ros2_type)
        data = rosmsg.serialize(self.encoding, ros2_type, ros2_msg())
        if self.container == "mcap-ros1":
            self._writer.add_message(conn, log_time=t, data=data, publish_time=t)
        else:
            self._call(self._writer.write, conn, t, data)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """``name`` as an MCAP metadata record (``mcap-ros1``), as one ``custom_data`` entry of
        a rosbag2 folder's metadata.yaml (``name`` -> the dict as JSON text), and nowhere in a
        ROS 1 bag, whose format has no place for it (its messages carry everything read)."""
        self._check_open()
        data = {str(k): str(v) for k, v in data.items()}
        if self.container == "mcap-ros1":
            self._writer.add_metadata(name, data)
        elif self.container.startswith("rosbag2"):
            self._call(self._writer.set_custom_data, name, json.dumps(data, sort_keys=True))

    def _finish(self) -> None:
        if self.container == "mcap-ros1":
            self._writer.finish()
            return
        try:
            self._call(self._writer.close)
        finally:
            self._thread.shutdown()

    def abort(self) -> None:
        super().abort()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            thread.shutdown(wait=False)
