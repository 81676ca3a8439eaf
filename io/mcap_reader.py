"""Streaming reader for RGB-D logs stored as MCAP (ROS 2 CDR, ROS 1 or Foxglove protobuf).

Messages are read chunk by chunk through the MCAP chunk index (or, for a log without a
readable summary such as a recording cut short, by a linear scan of its records), so
memory stays flat whatever the length of the log. Colour and depth are paired by
header stamp (:mod:`planar_vo.io.pairing`) and only the selected frames are decoded.

Damage is contained: a message that fails to decode is skipped and listed in
``stats['corrupt']``; an unreadable chunk is skipped when the index lets reading resume
after it; a log cut mid-file yields every readable frame and then raises
:class:`~planar_vo.core.errors.PartialResult` naming the byte offset where it stops.
"""
from __future__ import annotations

import heapq
import io
import math
import os
from collections import defaultdict
from dataclasses import dataclass
from typing import Iterator

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Header, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

from planar_vo.core.errors import InputError, PartialResult
from planar_vo.io import messages as m
from planar_vo.io.codecs import (DecodeError, decode_compressed_color, decode_compressed_depth,
                                 decode_raw_color, decode_raw_depth)
from planar_vo.io.log import (DEPTH_SAMPLES, INTRINSICS_FLAGS, LogSummary, RGBDLog, _empty_stats,
                              check_range, depth_valid_fraction)
from planar_vo.io.pairing import COLOR, DEPTH, Pair, StampPairer, Unpaired
from planar_vo.io.rosmsg import Ros1DecoderFactory
from planar_vo.io.topics import choose_topics
from planar_vo.io.wheel_odom import choose_odometry_topic, odometry_from_messages
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame, Trajectory

MCAP_MAGIC = b"\x89MCAP0\r\n"
_ROSBAG1_MAGIC = b"#ROSBAG"
_BASE_FRAMES = ("base_link", "base_footprint")


@dataclass
class _Stop:
    """Where a linear read of a damaged log had to stop."""

    offset: int
    reason: str
    last_stamp: float | None = None  # log time of the last readable message

    def where(self, size: int) -> str:
        return (f"at byte {self.offset} of {size}: {self.reason}; last readable message at "
                f"{_fmt_stamp(self.last_stamp)}")


class _ScanFacts:
    """What summary() needs from a pass over every pair, gathered by ``frames()``.

    ``errors`` mirrors the list summary()'s own scan would build: the message- and
    chunk-level errors (taken from the pass's list as they appear, skipping the entries
    only ``frames()`` adds) and the sampled depths that fail to decode, in scan order.
    """

    def __init__(self, every: int):
        self.every = every
        self.first = self.last = None
        self.fractions: list[float] = []
        self.errors: list = []
        self.stats: dict = {}
        self.stop_at: list = []
        self._seen = 0

    def take_errors(self, corrupt: list) -> None:
        self.errors.extend(corrupt[self._seen:])
        self._seen = len(corrupt)

    def skip_errors(self, n: int) -> None:
        self._seen += n

    def paired(self, stamp: float) -> None:
        self.first = stamp if self.first is None else self.first
        self.last = stamp

    def sampled(self, index: int) -> bool:
        return index % self.every == 0

    def finish(self, stats: dict, stop_at: list) -> None:
        self.stats = {k: v for k, v in stats.items() if k != "corrupt"}
        self.stop_at = list(stop_at)


def _ns_to_s(ns: int) -> float:
    return ns * 1e-9


def _fmt_stamp(stamp: float | None) -> str:
    return "none" if stamp is None else f"{stamp:.6f} s"


class McapRGBDLog(RGBDLog):
    """An MCAP RGB-D log; see :func:`planar_vo.io.open_log` for the arguments."""

    def __init__(self, path, *, color_topic=None, depth_topic=None, info_topic=None,
                 intrinsics: CameraIntrinsics | None = None, sync_tolerance: float = 0.02):
        super().__init__(path)
        self.sync_tolerance = float(sync_tolerance)
        self._intrinsics_override = intrinsics
        self._odom_cache: dict = {}  # --odom-topic -> WheelOdometry or None
        self._file = open(self.path, "rb")  # noqa: SIM115 - closed in close()
        try:
            self._open(color_topic, depth_topic, info_topic)
        except BaseException:
            self._file.close()
            raise

    # ------------------------------------------------------------------ opening
    def _open(self, color_topic, depth_topic, info_topic) -> None:
        self.size = os.fstat(self._file.fileno()).st_size
        head = self._file.read(8)
        if head.startswith(_ROSBAG1_MAGIC):
            raise InputError(f"{self.path}: a ROS 1 bag, not MCAP; open it with open_log()")
        if head != MCAP_MAGIC:
            raise InputError(f"{self.path}: not an MCAP file (no MCAP magic bytes); give an .mcap log, "
                             "a ROS 1 .bag, a rosbag2 folder or a TUM RGB-D folder")
        self._factories = (Ros2Decoders(), ProtobufDecoders(), Ros1DecoderFactory())
        self._decoders: dict[int, object] = {}
        self._file.seek(0)
        try:
            header = next(StreamReader(self._file, skip_magic=False).records)
            self.profile = header.profile if isinstance(header, Header) else ""
        except Exception:  # noqa: BLE001 - a damaged header is reported by the scan below
            self.profile = ""
        self._summary_reason = None
        summary = self._read_summary()
        self.indexed = summary is not None and len(summary.chunk_indexes) > 0
        self.scan_stop: _Stop | None = None
        if summary is not None:
            self._schemas, self._channels = dict(summary.schemas), dict(summary.channels)
            stats = summary.statistics
            self._counts = dict(stats.channel_message_counts) if stats else None
            self._chunk_indexes = sorted(summary.chunk_indexes,
                                         key=lambda c: (c.message_start_time, c.chunk_start_offset))
        if summary is None or not self.indexed or self._counts is None:
            # No usable index: one linear pass learns the channels and counts.
            self._schemas, self._channels, self._counts = {}, {}, defaultdict(int)
            for _, channel, _ in self._iter_linear(None, scan=True):
                self._counts[channel.id] += 1
            if self.scan_stop is not None and not self._channels:
                raise InputError(f"{self.path}: no readable MCAP records "
                                 f"({self.scan_stop.where(self.size)})")
        self._choose_streams(color_topic, depth_topic, info_topic)

    def _choose_streams(self, color_topic, depth_topic, info_topic) -> None:
        """Sort the channels by message type and pick the topics a run reads.

        The one place where message types are dispatched to roles, for every container
        (MCAP here, ROS 1 bags and rosbag2 folders in :mod:`planar_vo.io.rosbags_reader`):
        needs ``self._channels`` (id -> object with ``topic``, ``schema_id``) and
        ``self._schemas`` (id -> object with ``name``). A new role (e.g. odometry) is a
        kind in :func:`planar_vo.io.messages.schema_kind` and a topic list picked here.
        """
        self._kinds = {}
        for cid, ch in self._channels.items():
            schema = self._schemas.get(ch.schema_id)
            self._kinds[cid] = m.schema_kind(schema.name) if schema is not None else None
        topics_of = self._topics_of_kind = defaultdict(list)  # kind -> topics
        for cid, kind in self._kinds.items():
            topics_of[kind].append(self._channels[cid].topic)
        image_topics = sorted(set(topics_of[m.IMAGE] + topics_of[m.COMPRESSED]))
        info_topics = sorted(set(topics_of[m.CAMERA_INFO]))
        self.color_topic, self.depth_topic, self.info_topic = choose_topics(
            image_topics, info_topics, color_topic=color_topic, depth_topic=depth_topic,
            info_topic=info_topic, source=str(self.path))
        self._tf_topics = sorted({t for t in topics_of[m.TRANSFORMS] if t.endswith("tf_static")})
        gt = [t for t in topics_of[m.POSE] if "ground_truth" in t or "groundtruth" in t]
        self._gt_topic = "/ground_truth" if "/ground_truth" in gt else (sorted(gt)[0] if gt else None)
        self._probe_cache = None
        self._facts: _ScanFacts | None = None  # what the last complete frames() pass saw
        self._intrinsics_cache = None
        self._mount_cache: tuple | None = None
        self._gt_cache: tuple | None = None

    def _read_summary(self):
        try:
            self._file.seek(0)
            return SeekingReader(self._file).get_summary()
        except Exception as exc:  # noqa: BLE001 - any damage means "no usable summary"
            self._summary_reason = f"{type(exc).__name__}: {exc}"
            return None

    def close(self) -> None:
        self._file.close()

    # ------------------------------------------------------------- raw messages
    def _channel_ids(self, topics) -> set[int]:
        return {cid for cid, ch in self._channels.items() if ch.topic in topics}

    def _iter_messages(self, topics, corrupt: list, stop: list | None = None) -> Iterator[tuple]:
        """Yield ``(schema, channel, message)`` on ``topics`` in log-time order.

        Unreadable chunks are skipped (and listed in ``corrupt``) when the chunk index lets
        reading resume; a cut-off linear scan stops and appends a :class:`_Stop` to ``stop``.
        Several of these generators may be interleaved: each seeks before it reads.
        """
        ids = self._channel_ids(topics)
        if not self.indexed:
            yield from self._iter_linear(ids, corrupt=corrupt, stop_out=stop)
            return

        chunks = [c for c in self._chunk_indexes if ids & set(c.message_index_offsets)]
        heap: list = []
        seq = 0
        for i, ci in enumerate(chunks):
            try:
                self._file.seek(ci.chunk_start_offset + 1 + 8)  # opcode + record length
                chunk = Chunk.read(ReadDataStream(self._file))
                records = breakup_chunk(chunk, validate_crc=True)
            except Exception as exc:  # noqa: BLE001 - damaged chunk: skip it, keep reading
                corrupt.append((_ns_to_s(ci.message_start_time),
                                f"chunk at byte {ci.chunk_start_offset} unreadable "
                                f"({type(exc).__name__}: {exc}); its messages are skipped"))
                records = ()
            for rec in records:
                if isinstance(rec, Message) and rec.channel_id in ids:
                    heapq.heappush(heap, (rec.log_time, seq, rec))
                    seq += 1
            # Chunks may overlap in time: release only what no later chunk can precede.
            horizon = chunks[i + 1].message_start_time if i + 1 < len(chunks) else math.inf
            while heap and heap[0][0] <= horizon:
                rec = heapq.heappop(heap)[2]
                channel = self._channels[rec.channel_id]
                yield self._schemas.get(channel.schema_id), channel, rec

    def _iter_linear(self, ids, corrupt: list | None = None, scan: bool = False,
                     stop_out: list | None = None) -> Iterator[tuple]:
        """Records in file order; for logs without a usable index. ``scan``: learn channels."""
        f = self._file
        offset = len(MCAP_MAGIC)
        stop = None
        last_ns = None
        while True:
            f.seek(offset)
            head = f.read(9)
            if len(head) == 0:
                stop = _Stop(offset, "the file ends without an MCAP footer")
                break
            if len(head) < 9:
                stop = _Stop(offset, "the file ends inside a record header")
                break
            opcode, length = head[0], int.from_bytes(head[1:], "little")
            if offset + 9 + length > self.size:
                stop = _Stop(offset, f"a record of {length} bytes runs past the end of the file")
                break
            if opcode in (Opcode.FOOTER, Opcode.DATA_END):
                break
            record_offset, offset = offset, offset + 9 + length
            if opcode not in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK):
                continue
            body = f.read(length)
            try:
                stream = ReadDataStream(io.BytesIO(body))
                if opcode == Opcode.CHUNK:
                    records = breakup_chunk(Chunk.read(stream), validate_crc=True)
                else:
                    records = [{Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
                                Opcode.MESSAGE: Message}[opcode].read(stream)]
            except Exception as exc:  # noqa: BLE001 - damaged record, framing still intact
                if corrupt is not None:
                    corrupt.append((None, f"record at byte {record_offset} unreadable "
                                          f"({type(exc).__name__}: {exc}); skipped"))
                continue
            for rec in records:
                if isinstance(rec, Message):
                    last_ns = rec.log_time
                if isinstance(rec, Schema):
                    self._schemas.setdefault(rec.id, rec) if scan else None
                elif isinstance(rec, Channel):
                    self._channels.setdefault(rec.id, rec) if scan else None
                elif isinstance(rec, Message) and rec.channel_id in self._channels and \
                        (ids is None or rec.channel_id in ids):
                    channel = self._channels[rec.channel_id]
                    yield self._schemas.get(channel.schema_id), channel, rec
        if stop is not None and last_ns is not None:
            stop.last_stamp = _ns_to_s(last_ns)
        if scan:
            self.scan_stop = stop
        elif stop is not None and stop_out is not None:
            stop_out.append(stop)

    def _decode(self, schema, channel, message):
        decoder = self._decoders.get(channel.id)
        if decoder is None:
            for factory in self._factories:
                decoder = factory.decoder_for(channel.message_encoding, schema)
                if decoder is not None:
                    break
            else:
                name = schema.name if schema is not None else "no schema"
                raise InputError(f"{self.path}: topic {channel.topic} uses message encoding "
                                 f"'{channel.message_encoding}' ({name}), which cannot be decoded")
            self._decoders[channel.id] = decoder
        return decoder(message.data)

    def _messages_of(self, topic: str, corrupt: list) -> Iterator[tuple]:
        """Decoded messages on one topic as ``(log_stamp, kind, msg)``; bad ones listed in corrupt."""
        for schema, channel, rec in self._iter_messages({topic}, corrupt):
            try:
                msg = self._decode(schema, channel, rec)
            except InputError:
                raise
            except Exception as exc:  # noqa: BLE001
                corrupt.append((_ns_to_s(rec.log_time), f"{topic}: message undecodable ({exc})"))
                continue
            yield _ns_to_s(rec.log_time), self._kinds[channel.id], msg

    # --------------------------------------------------------------- pairing
    def _pair_events(self, stats: dict, stop: list) -> Iterator[Pair | Unpaired]:
        pairer = StampPairer(self.sync_tolerance)
        side_of = {self.color_topic: COLOR, self.depth_topic: DEPTH}
        for schema, channel, rec in self._iter_messages(side_of, stats["corrupt"], stop):
            log_stamp = _ns_to_s(rec.log_time)
            try:
                img = m.parse_image(self._kinds[channel.id], self._decode(schema, channel, rec))
            except InputError:
                raise
            except Exception as exc:  # noqa: BLE001 - one bad message does not end the log
                stats["corrupt"].append((log_stamp, f"{channel.topic}: message undecodable ({exc})"))
                continue
            stamp = img.stamp if img.stamp > 0 else log_stamp  # drivers that leave stamps unset
            yield from pairer.push(side_of[channel.topic], stamp, img)
        yield from pairer.finish()

    def _decode_color(self, img: m.ImageMessage) -> np.ndarray:
        if img.raw:
            return decode_raw_color(img.encoding, img.height, img.width, img.step, img.data,
                                    gray=self.color_mode == "gray")
        return decode_compressed_color(img.data, gray=self.color_mode == "gray")

    def _decode_depth(self, img: m.ImageMessage) -> np.ndarray:
        if img.raw:
            return decode_raw_depth(img.encoding, img.height, img.width, img.step, img.data,
                                    img.is_bigendian)
        return decode_compressed_depth(img.format, img.data)

    def frames(self, start: int = 0, stop: int | None = None, stride: int = 1) -> Iterator[RGBDFrame]:
        check_range(start, stop, stride)
        stats = self.stats = _empty_stats()
        index = 0
        yielded = 0
        shape_checked = False
        stop_at: list = []
        # A pass over every frame sees all that summary() would scan for: it records that on
        # the way (``facts``), and a later summary() uses it instead of reading the log again.
        facts = _ScanFacts(self._sample_every()) if (start, stop, stride) == (0, None, 1) else None
        self._facts = None
        for ev in self._pair_events(stats, stop_at):
            if facts is not None:
                facts.take_errors(stats["corrupt"])
            if isinstance(ev, Unpaired):
                stats["unpaired_color" if ev.side == COLOR else "unpaired_depth"] += 1
                continue
            i = index
            index += 1
            if stop is not None and i >= stop:
                return
            stats["paired"] += 1
            if facts is not None:
                facts.paired(ev.color_stamp)
            if i < start or (i - start) % stride:
                continue
            depth = None
            try:
                color = self._decode_color(ev.color)
                depth = self._decode_depth(ev.depth)
            except DecodeError as exc:
                stats["corrupt"].append((ev.color_stamp, str(exc)))
                if facts is not None:
                    facts.skip_errors(1)
                    if facts.sampled(i):
                        self._sample_depth(facts, ev, depth)
                continue
            if facts is not None and facts.sampled(i):
                facts.fractions.append(depth_valid_fraction(depth))
            if color.shape[:2] != depth.shape:
                msg = (f"colour is {color.shape[1]}x{color.shape[0]} but depth is "
                       f"{depth.shape[1]}x{depth.shape[0]}")
                if not shape_checked:
                    raise InputError(f"{self.path}: {msg} ({self.color_topic} vs {self.depth_topic}); "
                                     "depth must be registered to colour (choose e.g. an *_rect "
                                     "pair with --color-topic/--depth-topic)")
                stats["corrupt"].append((ev.color_stamp, msg))
                if facts is not None:
                    facts.skip_errors(1)
                continue
            shape_checked = True
            yielded += 1
            yield RGBDFrame(i, ev.color_stamp, color, depth, depth_stamp=ev.depth_stamp)
        if facts is not None:
            facts.take_errors(stats["corrupt"])
            facts.finish(stats, stop_at)
            self._facts = facts
        if stop_at:
            self._raise_cut(stop_at[0], yielded, stats["paired"])

    def reopen(self) -> None:
        self._file = open(self.path, "rb")  # noqa: SIM115 - closed in close(); the inherited one is the parent's

    def pass_state(self) -> dict:
        # the ground truth too, once read (a reader process reads it when its pass is done)
        return {**super().pass_state(), "facts": self._facts, "gt": self._gt_cache}

    def restore_pass_state(self, state: dict) -> None:
        super().restore_pass_state(state)
        self._facts = state["facts"]
        if state.get("gt") is not None:
            self._gt_cache = state["gt"]

    def _sample_every(self) -> int:
        """summary() decodes the depth of every n-th paired frame; this n."""
        expected = min(self._count(self.color_topic), self._count(self.depth_topic))
        return max(1, expected // DEPTH_SAMPLES)

    def _sample_depth(self, facts: "_ScanFacts", ev: Pair, depth) -> None:
        """The sampled depth of a frame that failed to decode, as summary() would see it."""
        try:
            d = depth if depth is not None else self._decode_depth(ev.depth)
        except DecodeError as exc:
            facts.errors.append((ev.color_stamp, str(exc)))
            return
        facts.fractions.append(depth_valid_fraction(d))

    def expected_frames(self) -> int:
        """Colour/depth pairs the log holds at most, from its index (nothing is read)."""
        return min(self._count(self.color_topic), self._count(self.depth_topic))

    def _raise_cut(self, stop: _Stop, yielded: int, paired: int) -> None:
        where = stop.where(self.size)
        if yielded == 0 and paired == 0:
            raise InputError(f"{self.path}: no readable frame; the log is damaged ({where})")
        raise PartialResult(f"{self.path}: log is cut short {where}; read {paired} frames before it")

    # -------------------------------------------------------------- metadata
    def _probe(self) -> tuple:
        """First decodable colour and depth images: ``(color ImageMessage, (H, W), depth msg)``."""
        if self._probe_cache is None:
            found = {}
            for topic, decode in ((self.color_topic, self._decode_color),
                                  (self.depth_topic, self._decode_depth)):
                for _, kind, msg in self._messages_of(topic, []):
                    img = m.parse_image(kind, msg)
                    try:
                        found[topic] = (img, decode(img).shape[:2])
                        break
                    except DecodeError:
                        continue
                if topic not in found:
                    raise InputError(f"{self.path}: no decodable image on {topic}")
            self._probe_cache = (found[self.color_topic], found[self.depth_topic])
        return self._probe_cache

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` of the colour images."""
        (_, (h, w)), _ = self._probe()
        return w, h

    @property
    def camera_frame(self) -> str:
        return self._probe()[0][0].frame_id

    def _intrinsics_and_source(self) -> tuple[CameraIntrinsics, str]:
        if self._intrinsics_cache is None:
            self._intrinsics_cache = self._find_intrinsics()
        return self._intrinsics_cache

    def _find_intrinsics(self) -> tuple[CameraIntrinsics, str]:
        w, h = self.image_size
        if self._intrinsics_override is not None:
            k = self._intrinsics_override
            if (k.width, k.height) != (w, h):
                raise InputError(f"{self.path}: the given intrinsics are for {k.width}x{k.height} but the "
                                 f"images are {w}x{h}")
            return k, "given"
        if self.info_topic is None:
            raise InputError(f"{self.path}: no camera calibration in the log (no CameraInfo or "
                             f"CameraCalibration topic); give the intrinsics with {INTRINSICS_FLAGS}")
        k = None
        for _, _, msg in self._messages_of(self.info_topic, []):
            k = m.parse_camera_info(msg, rectified="rect" in self.color_topic)
            break
        if k is None:
            raise InputError(f"{self.path}: {self.info_topic} holds no usable calibration (K is zero); "
                             f"give the intrinsics with {INTRINSICS_FLAGS}")
        source = self.info_topic
        if (k.width, k.height) != (w, h):
            if k.width <= 0 or k.height <= 0 or abs(k.width * h - k.height * w) > max(w, h):
                raise InputError(f"{self.path}: {self.info_topic} is for {k.width}x{k.height} but the images "
                                 f"are {w}x{h}; give the intrinsics with {INTRINSICS_FLAGS}")
            source += f" (scaled from {k.width}x{k.height})"
            k = k.scaled(w, h)
        return k, source

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics_and_source()[0]

    @property
    def mount(self) -> Mount | None:
        if self._mount_cache is None:
            self._mount_cache = (self._find_mount(),)
        return self._mount_cache[0]

    def _find_mount(self) -> Mount | None:
        if not self._tf_topics:
            return None
        edges: dict[str, list] = defaultdict(list)
        for topic in self._tf_topics:
            for _, _, msg in self._messages_of(topic, []):
                for _, parent, child, T in m.parse_transforms(msg):
                    parent, child = parent.lstrip("/"), child.lstrip("/")
                    edges[parent].append((child, T))
                    edges[child].append((parent, np.linalg.inv(T)))
        camera = self.camera_frame.lstrip("/")
        for base in _BASE_FRAMES:
            T = _chain(edges, base, camera)
            if T is not None:
                return Mount(T, parent_frame=base, child_frame=camera)
        return None

    def wheel_odometry(self, topic: str | None = None):
        """Wheel odometry found in the log (see :mod:`planar_vo.io.wheel_odom` for the order
        of sources) or None; ``topic`` (``--odom-topic``) overrides the choice. Read once."""
        if topic not in self._odom_cache:
            found = choose_odometry_topic(self._topics_of_kind, topic, source=str(self.path))
            odo = None
            if found is not None:
                name, kind = found
                msgs = ((stamp, msg) for stamp, _, msg in self._messages_of(name, []))
                schema = next((self._schemas[ch.schema_id].name for ch in self._channels.values()
                               if ch.topic == name and ch.schema_id in self._schemas), "")
                odo = odometry_from_messages(name, kind, msgs, schema.replace("/msg/", "/"))
                if odo is None and topic is not None:
                    raise InputError(f"{self.path}: --odom-topic {topic} carries no odom -> base_link pose")
            self._odom_cache[topic] = odo
        return self._odom_cache[topic]

    @property
    def ground_truth(self) -> Trajectory | None:
        if self._gt_cache is None:
            self._gt_cache = (self._read_ground_truth(),)
        return self._gt_cache[0]

    def _read_ground_truth(self) -> Trajectory | None:
        if self._gt_topic is None:
            return None
        stamps, poses, frame = [], [], "world"
        for _, _, msg in self._messages_of(self._gt_topic, []):
            stamp, frame, T = m.parse_pose(msg)
            stamps.append(stamp)
            poses.append(T)
        if not stamps:
            return None
        order = np.argsort(stamps, kind="stable")
        child = self._probe()[0][0].frame_id if self._channels else "camera_optical_frame"
        return Trajectory(np.asarray(stamps)[order], np.asarray(poses)[order], frame_id=frame,
                          child_frame_id=child)

    def summary(self) -> LogSummary:
        """Scan the log and describe it; right after a complete ``frames()`` pass (all
        frames, read to the end) the facts recorded by that pass are used instead."""
        if self._facts is not None:
            f = self._facts
            stats = self.stats = {"paired": f.stats["paired"], "unpaired_color": f.stats["unpaired_color"],
                                  "unpaired_depth": f.stats["unpaired_depth"], "corrupt": list(f.errors)}
            fractions, first, last, stop_at = f.fractions, f.first, f.last, f.stop_at
            return self._describe(stats, fractions, first, last, stop_at)
        stats = self.stats = _empty_stats()
        every = self._sample_every()
        fractions = []
        first = last = None
        index = 0
        stop_at: list = []
        for ev in self._pair_events(stats, stop_at):
            if isinstance(ev, Unpaired):
                stats["unpaired_color" if ev.side == COLOR else "unpaired_depth"] += 1
                continue
            stats["paired"] += 1
            first = ev.color_stamp if first is None else first
            last = ev.color_stamp
            if index % every == 0:
                try:
                    fractions.append(depth_valid_fraction(self._decode_depth(ev.depth)))
                except DecodeError as exc:
                    stats["corrupt"].append((ev.color_stamp, str(exc)))
            index += 1
        return self._describe(stats, fractions, first, last, stop_at)

    def _describe(self, stats: dict, fractions: list, first, last, stop_at: list) -> LogSummary:
        (cimg, (h, w)), (dimg, _) = self._probe()
        s = LogSummary(
            path=str(self.path), format=self.format,
            color_topic=self.color_topic, depth_topic=self.depth_topic, info_topic=self.info_topic,
            color_encoding=cimg.encoding_name, depth_encoding=dimg.encoding_name, width=w, height=h,
            frames=stats["paired"], color_messages=self._count(self.color_topic),
            depth_messages=self._count(self.depth_topic), unpaired_color=stats["unpaired_color"],
            unpaired_depth=stats["unpaired_depth"], corrupt=len(stats["corrupt"]),
            first_stamp=first, last_stamp=last, mount=self.mount,
            depth_valid_fraction=float(np.mean(fractions)) if fractions else None,
            depth_frames_sampled=len(fractions))
        try:
            s.intrinsics, s.intrinsics_source = self._intrinsics_and_source()
        except InputError as exc:
            s.notes.append(str(exc))
        try:
            odo = self.wheel_odometry()
            s.wheel_odometry = odo.describe() if odo is not None else None
        except InputError as exc:
            s.notes.append(str(exc))
        gt = self.ground_truth
        s.ground_truth_poses = len(gt) if gt is not None else 0
        if stop_at:
            s.truncated = stop_at[0].where(self.size)
        if s.depth_all_invalid:
            s.notes.append(f"depth is invalid (0, NaN or inf) in every sampled frame of {self.depth_topic}")
        return s

    @property
    def format(self) -> str:
        """``"MCAP (ROS 2, cdr)"`` or ``"MCAP (Foxglove, protobuf)"`` from the colour channel."""
        enc = next(ch.message_encoding for ch in self._channels.values() if ch.topic == self.color_topic)
        kind = {"cdr": "ROS 2", "protobuf": "Foxglove", "ros1": "ROS 1"}.get(enc, self.profile or "unknown profile")
        return f"MCAP ({kind}, {enc})"

    def _count(self, topic: str) -> int:
        return sum(self._counts.get(cid, 0) for cid in self._channel_ids({topic}))


def _chain(edges: dict, start: str, goal: str) -> np.ndarray | None:
    """``T_start_goal`` composed along the transform tree (breadth-first), or None."""
    if start == goal:
        return np.eye(4)
    seen = {start}
    frontier = [(start, np.eye(4))]
    while frontier:
        nxt = []
        for frame, T in frontier:
            for child, T_fc in edges.get(frame, ()):
                if child in seen:
                    continue
                T_child = T @ T_fc
                if child == goal:
                    return T_child
                seen.add(child)
                nxt.append((child, T_child))
        frontier = nxt
    return None
