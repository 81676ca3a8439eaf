"""Streaming reader for ROS 1 bags and rosbag2 folders (sqlite3 or mcap storage).

The containers are read by the ``rosbags`` library (no ROS needed): it lists the
connections, streams raw messages in time order and deserialises them (types from the
definitions the bag carries, else ROS 2 Humble's). Everything past that is the MCAP
reader's: :class:`RosbagsRGBDLog` only swaps the message source of
:class:`~planar_vo.io.mcap_reader.McapRGBDLog`, so topic choice, pairing, image
decoding, calibration, mount, ground truth, corrupt-frame skipping and the summary are
one code path for every container. Memory stays flat: messages are read one at a time
(a ROS 1 bag keeps one decompressed chunk, a rosbag2 folder one row or chunk).

A container that breaks off mid-read (a cut ``.db3`` or ``.mcap``) yields what was
readable, then raises :class:`~planar_vo.core.errors.PartialResult`; one that cannot be
opened at all (a ROS 1 bag cut short has no index) is an :class:`InputError`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from planar_vo.core.errors import InputError, PartialResult
from planar_vo.io.log import RGBDLog
from planar_vo.io.mcap_reader import McapRGBDLog, _fmt_stamp, _ns_to_s
from planar_vo.io.rosmsg import CDR, ROS1, typestore
from planar_vo.core.types import CameraIntrinsics

ROSBAG1_MAGIC = b"#ROSBAG"


@dataclass(frozen=True)
class _Channel:
    """A rosbags connection in the shape the MCAP reader's code reads."""

    id: int
    topic: str
    schema_id: int
    message_encoding: str
    connection: object


@dataclass(frozen=True)
class _Schema:
    name: str


@dataclass(frozen=True)
class _Record:
    log_time: int  # ns
    data: bytes


@dataclass
class _Stop:
    """Where a container stopped yielding messages (no byte offset: rosbags does not tell)."""

    reason: str
    last_stamp: float | None = None

    def where(self, size: int) -> str:  # noqa: ARG002 - same signature as the MCAP reader's
        return f"{self.reason}; last readable message at {_fmt_stamp(self.last_stamp)}"


def open_ros_log(path: Path, **kwargs) -> McapRGBDLog:
    """A ROS 1 bag or rosbag2 folder for streaming (``kwargs`` as for RosbagsRGBDLog).

    rosbags needs an MCAP's summary; when a rosbag2 folder's single ``.mcap`` file has none
    (a recording cut short), the MCAP reader reads what it can of that file instead.
    """
    try:
        return RosbagsRGBDLog(path, **kwargs)
    except InputError:
        files = sorted(path.glob("*.mcap")) if path.is_dir() else []
        if len(files) != 1 or _storage(path) != "mcap":
            raise
    return McapRGBDLog(files[0], **kwargs)


def rosbag2_folder(path: Path) -> Path | None:
    """The rosbag2 folder ``path`` names (the folder or its ``metadata.yaml``), or None."""
    if path.is_file() and path.name == "metadata.yaml":
        return path.parent
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    return None


def is_rosbag1(path: Path) -> bool:
    with open(path, "rb") as f:
        return f.read(len(ROSBAG1_MAGIC)) == ROSBAG1_MAGIC


class RosbagsRGBDLog(McapRGBDLog):
    """A ROS 1 ``.bag`` or a rosbag2 folder; see :func:`planar_vo.io.open_log` for the arguments."""

    def __init__(self, path, *, color_topic=None, depth_topic=None, info_topic=None,
                 intrinsics: CameraIntrinsics | None = None, sync_tolerance: float = 0.02):
        RGBDLog.__init__(self, path)
        self.sync_tolerance = float(sync_tolerance)
        self._intrinsics_override = intrinsics
        self._odom_cache: dict = {}  # --odom-topic -> WheelOdometry or None (as McapRGBDLog)
        self._reader = None
        self.size = _size(self.path)
        self.profile = ""
        self.indexed = True
        try:
            self._open_container()
            self._choose_streams(color_topic, depth_topic, info_topic)
        except BaseException:
            self.close()
            raise

    def _open_container(self) -> None:
        from rosbags.highlevel import AnyReader
        bag = self.path.is_file()
        self.container = "ROS 1 bag" if bag else "rosbag2 folder"
        self.storage = "ros1" if bag else _storage(self.path)
        # A .bag suffix is how rosbags tells ROS 1 from rosbag2; a bag by another name is linked.
        src = self.path if not bag or self.path.suffix == ".bag" else _bag_alias(self.path)
        try:
            reader = AnyReader([src], default_typestore=typestore(CDR))
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises several error types
            hint = (" (a bag cut short or not closed has no index; `rosbag reindex` rebuilds it)"
                    if bag else "")
            raise InputError(f"{self.path}: cannot open the {self.container} ({type(exc).__name__}: "
                             f"{_first_line(exc)}){hint}") from None
        self._reader = reader
        enc = ROS1 if bag else CDR
        conns = list(reader.connections)
        self._channels = {c.id: _Channel(c.id, c.topic, c.id, enc, c) for c in conns}
        self._schemas = {c.id: _Schema(c.msgtype) for c in conns}
        self._counts = {c.id: int(c.msgcount) for c in conns}
        if not conns:
            raise InputError(f"{self.path}: the {self.container} holds no topics")

    def reopen(self) -> None:
        # The inherited reader is left alone, not closed: it is the parent's (an SQLite
        # connection must not be used across fork, not even to close it).
        self._reader = None
        self._open_container()

    def close(self) -> None:
        if self._reader is not None:
            reader, self._reader = self._reader, None
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a damaged container
                pass

    # ------------------------------------------------------------- raw messages
    def _iter_messages(self, topics, corrupt: list, stop: list | None = None) -> Iterator[tuple]:
        """Yield ``(schema, channel, record)`` on ``topics`` in log-time order.

        A container that breaks off appends a :class:`_Stop` to ``stop`` (the frame pass)
        and ends the iteration.
        """
        conns = [self._channels[cid].connection for cid in self._channel_ids(topics)]
        if not conns:
            return
        last = None
        try:
            for conn, t, raw in self._reader.messages(connections=conns):
                last = t
                channel = self._channels[conn.id]
                yield self._schemas[conn.id], channel, _Record(t, raw)
        except Exception as exc:  # noqa: BLE001 - damaged data: keep what was read
            cut = _Stop(f"the {self.container} breaks off ({type(exc).__name__}: {_first_line(exc)})",
                        None if last is None else _ns_to_s(last))
            if stop is not None:
                stop.append(cut)

    def _decode(self, schema, channel, message):
        return self._reader.deserialize(message.data, schema.name)

    def _raise_cut(self, stop, yielded: int, paired: int) -> None:
        where = stop.where(self.size)
        if yielded == 0 and paired == 0:
            raise InputError(f"{self.path}: no readable frame; the {self.container} is damaged ({where})")
        raise PartialResult(f"{self.path}: log is cut short: {where}; read {paired} frames before it")

    @property
    def format(self) -> str:
        """``"ROS 1 bag (ros1)"``, ``"rosbag2 (sqlite3, cdr)"`` or ``"rosbag2 (mcap, cdr)"``."""
        return "ROS 1 bag (ros1)" if self.storage == "ros1" else f"rosbag2 ({self.storage}, cdr)"


def _first_line(exc: Exception) -> str:
    text = str(exc).strip() or "no detail"
    return text.splitlines()[0]


def _size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.iterdir() if p.is_file())


def _storage(folder: Path) -> str:
    """Storage plugin named in a rosbag2 folder's metadata.yaml (``sqlite3`` or ``mcap``)."""
    import yaml
    try:
        meta = yaml.safe_load((folder / "metadata.yaml").read_text(encoding="utf-8"))
        return str(meta["rosbag2_bagfile_information"]["storage_identifier"])
    except Exception:  # noqa: BLE001 - rosbags reports a broken metadata.yaml on open
        return "folder"


def _bag_alias(path: Path) -> Path:
    raise InputError(f"{path}: a ROS 1 bag must be named *.bag for the reader; rename it")
