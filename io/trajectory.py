"""Trajectory files, evo style: paired ``read_*`` / ``write_*`` per format, atomic writes.

* TUM text: one pose per line, ``timestamp tx ty tz qx qy qz qw``; ``#`` comments.
* Foxglove MCAP: for each trajectory ``N``, a ``foxglove.PoseInFrame`` per pose on
  ``/planar_vo/N/pose`` and ``foxglove.PosesInFrame`` paths on ``/planar_vo/N/path``;
  optional transforms as ``foxglove.FrameTransforms`` on ``/tf``.
"""
from __future__ import annotations

import math
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from planar_vo.core.errors import InputError
from planar_vo.core.geometry import matrix_from_pose7, pose7_from_matrix
from planar_vo.io import messages as m
from planar_vo.io import rosmsg
from planar_vo.io.atomic import atomic_path, write_text_atomic
from planar_vo.core.types import Trajectory

POSES_METADATA = "planar_vo.trajectories"
_TOPIC = re.compile(r"^/planar_vo/(?P<name>.+)/(?P<kind>pose|odom|path)$")


def associate_stamps(stamps_a: np.ndarray, stamps_b: np.ndarray, max_dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(ia, ib)`` matching each stamp of ``a`` to the nearest of ``b`` within ``max_dt`` s.

    Each ``b`` stamp is used at most once (the closest ``a`` wins); both arrays sorted ascending.
    """
    a = np.asarray(stamps_a, dtype=float)
    b = np.asarray(stamps_b, dtype=float)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    j = np.clip(np.searchsorted(b, a), 1, len(b) - 1) if len(b) > 1 else np.zeros(len(a), int)
    if len(b) > 1:
        left_better = np.abs(a - b[j - 1]) <= np.abs(a - b[j])
        j = np.where(left_better, j - 1, j)
    dt = np.abs(a - b[j])
    ok = dt <= max_dt
    ia, ib, dt = np.nonzero(ok)[0], j[ok], dt[ok]
    # keep the closest a for every b
    order = np.lexsort((dt, ib))
    ia, ib = ia[order], ib[order]
    first = np.ones(len(ib), bool)
    first[1:] = ib[1:] != ib[:-1]
    ia, ib = ia[first], ib[first]
    o = np.argsort(ia)
    return ia[o], ib[o]


# ------------------------------------------------------------------------------ TUM

def read_tum_trajectory(path) -> Trajectory:
    """Read a TUM trajectory file; a malformed line raises InputError naming ``file:line``."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: trajectory file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read trajectory file ({exc})") from None
    stamps, poses = [], []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        try:
            values = [float(v) for v in fields]
        except ValueError:
            values = []
        if len(values) != 8 or not all(math.isfinite(v) for v in values):
            raise InputError(f"{p}:{lineno}: expected 8 finite numbers 'timestamp tx ty tz qx qy qz qw', "
                             f"got {line[:80]!r}")
        if math.hypot(*values[4:8]) < 1e-9:
            raise InputError(f"{p}:{lineno}: zero quaternion")
        stamps.append(values[0])
        poses.append(matrix_from_pose7(values[1:]))
    return Trajectory(np.asarray(stamps, dtype=np.float64), np.asarray(poses).reshape(-1, 4, 4))


def write_tum_trajectory(path, traj: Trajectory, *, header: str | None = None) -> None:
    """Write ``traj`` as TUM text (full float precision), atomically."""
    _check_traj(traj, "write_tum_trajectory")
    lines = [f"# {line}" for line in (header or "").splitlines()]
    lines.append("# timestamp tx ty tz qx qy qz qw")
    for stamp, T in zip(traj.stamps, traj.poses):
        lines.append(" ".join(repr(float(v)) for v in (stamp, *pose7_from_matrix(T))))
    write_text_atomic(path, "\n".join(lines) + "\n")


def _check_traj(traj, where: str) -> None:
    if not isinstance(traj, Trajectory):
        raise TypeError(f"{where}: expected a Trajectory, got {type(traj).__name__}")
    if not np.all(np.isfinite(traj.poses)) or not np.all(np.isfinite(traj.stamps)):
        raise ValueError(f"{where}: trajectory has non-finite stamps or poses")


# ---------------------------------------------------------------------- poses MCAP

#: ``write_poses_mcap`` formats: Foxglove protobuf schemas, or ROS 2 messages (CDR) in a
#: rosbag2-style MCAP file, which Foxglove, rosbags and evo (``evo_traj bag2 FILE``) read.
POSES_FORMATS = ("foxglove", "ros2")


def poses_format_for(log_format: str) -> str:
    """``auto`` poses format for a log's ``format``: ``ros2`` for ROS logs (ROS 1 or 2 MCAP,
    bags, rosbag2 folders), ``foxglove`` for the rest (Foxglove MCAP, TUM folders)."""
    return "ros2" if "ROS" in log_format or "rosbag" in log_format else "foxglove"


def write_poses_mcap(path, trajectories: dict[str, Trajectory], *, transforms=None, lines=None,
                     path_period: float = 1.0, path_max_poses: int = 256, format: str = "foxglove") -> None:
    """Write trajectories for Foxglove and ROS tools, atomically.

    ``trajectories``: name -> :class:`Trajectory` (names become topic segments).
    ``transforms``: optional list of ``(stamp, parent, child, T (4, 4))`` written on ``/tf``
    (one message per distinct stamp). ``lines``: optional ``(stamp, name, frame_id, segments
    (M, 2, 3))`` drawn as one line list on ``/planar_vo/NAME`` (e.g. the loop closures between
    the two poses they join): ``foxglove.SceneUpdate`` or ``visualization_msgs/MarkerArray``. ``format``:

    * ``foxglove``: ``foxglove.PoseInFrame`` per pose on ``/planar_vo/N/pose``,
      ``foxglove.PosesInFrame`` paths on ``/planar_vo/N/path``, ``foxglove.FrameTransforms``.
    * ``ros2``: ``nav_msgs/msg/Odometry`` per pose on ``/planar_vo/N/odom`` (``child_frame_id``
      is the trajectory's), ``nav_msgs/msg/Path`` on ``/planar_vo/N/path``,
      ``tf2_msgs/msg/TFMessage``, as ``ros2 bag record -s mcap`` writes them, so that
      ``evo_traj bag2 poses.mcap /planar_vo/smoothed/odom`` (rosbags) reads it as it is.

    The path grows: every ``path_period`` seconds of the trajectory a message with the
    path so far, thinned evenly to at most ``path_max_poses`` poses (so the file grows
    linearly, not quadratically, with the length), and one last message with every pose.
    """
    if format not in POSES_FORMATS:
        raise ValueError(f"poses format {format!r} is not one of {POSES_FORMATS}")
    for name, traj in trajectories.items():
        if not re.fullmatch(r"[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*", name):
            raise ValueError(f"trajectory name {name!r}: use letters, digits, '_', '-' (and '/')")
        _check_traj(traj, f"write_poses_mcap[{name}]")
    events = _pose_events(trajectories, transforms, path_period, path_max_poses, format == "ros2")
    if lines is not None:
        events.append(_lines_event(*lines, format == "ros2"))
        events.sort(key=lambda e: (e[0], e[1]))
    if format == "ros2":
        _write_poses_ros2(Path(path), events)
        return
    from mcap_protobuf.writer import Writer
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        w = Writer(f)
        w.add_metadata(POSES_METADATA, {name: traj.child_frame_id for name, traj in trajectories.items()})
        for s, _, topic, _, build in events:
            t = m.stamp_to_ns(s)
            w.write_message(topic, build(), log_time=t, publish_time=t)
        w.finish()


def _pose_events(trajectories, transforms, path_period: float, path_max_poses: int, ros2: bool) -> list:
    """``(stamp, order, topic, ROS 2 type, builder)`` for every message, in log-time order;
    builders give ROS 2 dicts (``ros2``) or Foxglove protobuf messages."""
    events = []
    for name, traj in trajectories.items():
        order = np.argsort(traj.stamps, kind="stable")
        stamps, poses, frame = traj.stamps[order], traj.poses[order], traj.frame_id
        for s, T in zip(stamps, poses):
            if ros2:
                events.append((s, 1, f"/planar_vo/{name}/odom", "nav_msgs/msg/Odometry",
                               lambda s=s, T=T, f=frame, c=traj.child_frame_id: m.ros2_odometry(s, f, c, T)))
            else:
                events.append((s, 1, f"/planar_vo/{name}/pose", None,
                               lambda s=s, T=T, f=frame: m.foxglove_pose_in_frame(s, f, T)))
        build_path = _Ros2Paths(poses, frame) if ros2 else (
            lambda s, idx, P=poses, f=frame: m.foxglove_poses_in_frame(s, f, P[idx]))
        for i in _path_cuts(stamps, path_period):
            idx = np.arange(i + 1) if i == len(stamps) - 1 else _thin(np.arange(i + 1), path_max_poses)
            events.append((stamps[i], 2, f"/planar_vo/{name}/path", "nav_msgs/msg/Path",
                           lambda s=stamps[i], idx=idx, b=build_path: b(s, idx)))
    by_stamp = defaultdict(list)
    for s, parent, child, T in transforms or ():
        by_stamp[float(s)].append((float(s), parent, child, np.asarray(T, float)))
    tf = m.ros2_tf_message if ros2 else m.foxglove_frame_transforms
    for s, group in by_stamp.items():
        events.append((s, 0, "/tf", "tf2_msgs/msg/TFMessage", lambda g=group: tf(g)))
    events.sort(key=lambda e: (e[0], e[1]))
    return events


class _Ros2Paths:
    """nav_msgs/Path messages of one trajectory's ``poses`` (N, 4, 4) in ``frame_id``, as
    ``rosbags`` objects (what :func:`planar_vo.io.messages.ros2_path` gives as a dict,
    serialised to the same bytes). The path grows: each pose is converted once and shared
    by every path message that holds it (the demo's two paths hold 9198 poses over their
    messages: built from dicts, writing its ``poses.mcap`` took 0.25-0.29 s of CPU, shared
    0.06-0.09 s)."""

    def __init__(self, poses: np.ndarray, frame_id: str):
        self._poses, self._frame, self._built = poses, frame_id, {}

    def _pose(self, store, i: int):
        if i not in self._built:
            t, q = m.xyz_quat(self._poses[i])
            self._built[i] = rosmsg.build(store, "geometry_msgs/msg/Pose", {"position": t, "orientation": q})
        return self._built[i]

    def __call__(self, stamp: float, idx: np.ndarray):
        store = rosmsg.typestore(rosmsg.CDR)
        header = rosmsg.build(store, "std_msgs/msg/Header", m.ros2_header(stamp, self._frame))
        stamped = store.types["geometry_msgs/msg/PoseStamped"]
        return store.types["nav_msgs/msg/Path"](
            header=header, poses=[stamped(header=header, pose=self._pose(store, int(i))) for i in idx])


def _lines_event(stamp: float, name: str, frame_id: str, segments, ros2: bool) -> tuple:
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 3)
    if ros2:
        return (stamp, 3, f"/planar_vo/{name}", "visualization_msgs/msg/MarkerArray",
                lambda: m.ros2_marker_lines(stamp, frame_id, seg, name))
    return (stamp, 3, f"/planar_vo/{name}", None, lambda: m.foxglove_scene_lines(stamp, frame_id, seg, name))


def _write_poses_ros2(path: Path, events: list) -> None:
    """ROS 2 messages (CDR, ``ros2msg`` schemas) in an MCAP of the ``ros2`` profile, the way
    ``ros2 bag record -s mcap`` writes one, atomically; zstd chunks as for the Foxglove format."""
    from mcap.writer import CompressionType, Writer

    store = rosmsg.typestore(rosmsg.CDR)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="planar-vo")
        channels: dict[str, int] = {}
        schemas: dict[str, int] = {}
        for s, _, topic, typename, build in events:
            if typename not in schemas:
                text = store.generate_msgdef(typename, ros_version=2)[0]
                schemas[typename] = w.register_schema(typename, "ros2msg", text.encode("utf-8"))
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "cdr", schemas[typename])
            t = m.stamp_to_ns(s)
            w.add_message(channels[topic], log_time=t, data=rosmsg.serialize(rosmsg.CDR, typename, build()),
                          publish_time=t)  # a dict, or a message already built (_Ros2Paths)
        w.finish()


def _path_cuts(stamps: np.ndarray, period: float) -> list[int]:
    """Indices after which a path message is published: every ``period`` s, and the end."""
    if len(stamps) == 0:
        return []
    cuts, next_t = [], stamps[0] + period
    for i, s in enumerate(stamps[:-1]):
        if s >= next_t:
            cuts.append(i)
            next_t = s + period
    cuts.append(len(stamps) - 1)
    return cuts


def _thin(poses: np.ndarray, max_poses: int) -> np.ndarray:
    if len(poses) <= max_poses:
        return poses
    idx = np.unique(np.linspace(0, len(poses) - 1, max_poses).round().astype(int))
    return poses[idx]


class _PoseOf:
    """An Odometry message seen as a PoseStamped (its pose without the covariance)."""

    def __init__(self, odometry):
        self.header, self.pose = odometry.header, odometry.pose.pose


def read_poses_mcap(path) -> dict[str, Trajectory]:
    """Read back the per-pose topics written by :func:`write_poses_mcap` (either format)."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: poses file not found")
    out: dict[str, tuple[list, list, str]] = {}
    children: dict[str, str] = {}
    try:
        with open(p, "rb") as f:
            reader = make_reader(f, decoder_factories=[ProtobufDecoders(), Ros2Decoders()])
            for meta in reader.iter_metadata():
                if meta.name == POSES_METADATA:
                    children.update(meta.metadata)
            for schema, channel, _, msg in reader.iter_decoded_messages():
                match = _TOPIC.match(channel.topic)
                if not match or match["kind"] == "path":
                    continue
                if match["kind"] == "odom":  # nav_msgs/Odometry: the child frame is in the message
                    children[match["name"]] = msg.child_frame_id
                    stamp, frame, T = m.parse_pose(_PoseOf(msg))
                else:
                    stamp, frame, T = m.parse_pose(msg)
                entry = out.setdefault(match["name"], ([], [], frame))
                entry[0].append(stamp)
                entry[1].append(T)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - any reader failure means a bad file
        raise InputError(f"{p}: not a readable poses MCAP ({type(exc).__name__}: {exc})") from None
    return {name: Trajectory(np.asarray(st), np.asarray(P).reshape(-1, 4, 4), frame_id=frame,
                             child_frame_id=children.get(name, "camera_optical_frame"))
            for name, (st, P, frame) in out.items()}


def read_lines_mcap(path, name: str) -> np.ndarray:
    """The last line list written by :func:`write_poses_mcap` on ``/planar_vo/NAME`` (either
    format) as (M, 2, 3) endpoints; (0, 2, 3) when the file has none."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: poses file not found")
    points: list = []
    try:
        with open(p, "rb") as f:
            reader = make_reader(f, decoder_factories=[ProtobufDecoders(), Ros2Decoders()])
            for _, _, _, msg in reader.iter_decoded_messages(topics=[f"/planar_vo/{name}"]):
                lines = msg.markers[0].points if hasattr(msg, "markers") else msg.entities[0].lines[0].points
                points = [(q.x, q.y, q.z) for q in lines]
    except Exception as exc:  # noqa: BLE001 - any reader failure means a bad file
        raise InputError(f"{p}: not a readable poses MCAP ({type(exc).__name__}: {exc})") from None
    return np.asarray(points, dtype=float).reshape(-1, 2, 3)
