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
from planar_vo.io.atomic import atomic_path, write_text_atomic
from planar_vo.core.types import Trajectory

POSES_METADATA = "planar_vo.trajectories"
_TOPIC = re.compile(r"^/planar_vo/(?P<name>.+)/(?P<kind>pose|path)$")


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

def write_poses_mcap(path, trajectories: dict[str, Trajectory], *, transforms=None,
                     path_period: float = 1.0, path_max_poses: int = 256) -> None:
    """Write trajectories for Foxglove, atomically.

    ``trajectories``: name -> :class:`Trajectory` (names become topic segments).
    ``transforms``: optional list of ``(stamp, parent, child, T (4, 4))`` written as
    ``foxglove.FrameTransforms`` on ``/tf`` (one message per distinct stamp).
    The path on ``/planar_vo/N/path`` grows: every ``path_period`` seconds of the
    trajectory a ``PosesInFrame`` with the path so far, thinned evenly to at most
    ``path_max_poses`` poses (so the file grows linearly, not quadratically, with the
    length), and one last message with every pose.
    """
    from mcap_protobuf.writer import Writer

    for name, traj in trajectories.items():
        if not re.fullmatch(r"[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*", name):
            raise ValueError(f"trajectory name {name!r}: use letters, digits, '_', '-' (and '/')")
        _check_traj(traj, f"write_poses_mcap[{name}]")
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        w = Writer(f)
        w.add_metadata(POSES_METADATA, {name: traj.child_frame_id for name, traj in trajectories.items()})
        # Messages are written in log-time order across all topics.
        events = []  # (stamp, order, topic, builder)
        for name, traj in trajectories.items():
            order = np.argsort(traj.stamps, kind="stable")
            stamps, poses = traj.stamps[order], traj.poses[order]
            for i, (s, T) in enumerate(zip(stamps, poses)):
                events.append((s, 1, f"/planar_vo/{name}/pose",
                               lambda s=s, T=T, f=traj.frame_id: m.foxglove_pose_in_frame(s, f, T)))
            for i in _path_cuts(stamps, path_period):
                events.append((stamps[i], 2, f"/planar_vo/{name}/path",
                               lambda i=i, s=stamps, P=poses, f=traj.frame_id, last=(i == len(stamps) - 1):
                               m.foxglove_poses_in_frame(s[i], f, P[:i + 1] if last else
                                                         _thin(P[:i + 1], path_max_poses))))
        by_stamp = defaultdict(list)
        for s, parent, child, T in transforms or ():
            by_stamp[float(s)].append((float(s), parent, child, np.asarray(T, float)))
        for s, group in by_stamp.items():
            events.append((s, 0, "/tf", lambda g=group: m.foxglove_frame_transforms(g)))
        events.sort(key=lambda e: (e[0], e[1]))
        for s, _, topic, build in events:
            t = m.stamp_to_ns(s)
            w.write_message(topic, build(), log_time=t, publish_time=t)
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


def read_poses_mcap(path) -> dict[str, Trajectory]:
    """Read back the per-pose topics written by :func:`write_poses_mcap`."""
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
                if not match or match["kind"] != "pose":
                    continue
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
