"""Wheel odometry: the record a log yields, where it is found, and a synthetic error model.

* :class:`WheelOdometry` holds stamped SE(2) samples ``T_odom_base`` ``(x, y, theta)`` and
  interpolates them at any stamp (on SE(2): the relative pose of two neighbouring samples
  scaled in its tangent space), e.g. at the colour frames' stamps.
* :func:`choose_odometry_topic` picks the source among a log's topics (one rule for every
  container: ``nav_msgs/Odometry`` first, else a ``/tf`` topic carrying ``odom -> base_link``,
  else a Foxglove ``PoseInFrame`` topic named like odometry); :func:`odometry_from_messages`
  turns the decoded messages of that topic into a :class:`WheelOdometry`. A reader only
  lists its topics by kind (:func:`planar_vo.io.messages.schema_kind`) and decodes.
* :class:`WheelOdomModel` and :func:`simulate_wheel_odometry`: a differential-drive robot's
  odometry driven by a ground-truth base path, with scale error, wheelbase error, heading
  drift per metre and wheel noise (``planar-vo synth --wheel-odom``).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from planar_vo.core.errors import InputError
from planar_vo.core.geometry import wrap_angle
from planar_vo.io import messages as m

#: Frames a wheel odometry transform may name (REP 105), leading '/' ignored.
ODOM_FRAMES = ("odom",)
BASE_FRAMES = ("base_link", "base_footprint")
#: Where the odometry can come from, in the order tried.
SOURCE_KINDS = (m.ODOMETRY, m.TRANSFORMS, m.POSE)


# --------------------------------------------------------------------------- record

def _se2_log(d: np.ndarray) -> np.ndarray:
    """Tangent vectors (M, 3) of SE(2) poses ``d`` (M, 3) (x, y, theta)."""
    th = d[:, 2]
    small = np.abs(th) < 1e-9
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th ** 2 / 6.0, np.sin(safe) / safe)     # sin(t) / t
    b = np.where(small, th / 2.0, (1.0 - np.cos(safe)) / safe)        # (1 - cos t) / t
    det = a * a + b * b
    u = (a * d[:, 0] + b * d[:, 1]) / det
    v = (-b * d[:, 0] + a * d[:, 1]) / det
    return np.column_stack([u, v, th])


def _se2_exp(xi: np.ndarray) -> np.ndarray:
    th = xi[:, 2]
    small = np.abs(th) < 1e-9
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th ** 2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, th / 2.0, (1.0 - np.cos(safe)) / safe)
    return np.column_stack([a * xi[:, 0] - b * xi[:, 1], b * xi[:, 0] + a * xi[:, 1], th])


def se2_between_many(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a_i^-1 b_i`` for SE(2) poses (M, 3) each."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[:, 2] - a[:, 2])])


def se2_compose_many(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a_i b_i`` for SE(2) poses (M, 3) each."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([a[:, 0] + c * b[:, 0] - s * b[:, 1], a[:, 1] + s * b[:, 0] + c * b[:, 1],
                            wrap_angle(a[:, 2] + b[:, 2])])


@dataclass
class WheelOdometry:
    """Stamped wheel odometry: ``stamps`` (N,) float64 s, increasing; ``poses`` (N, 3)
    float64 SE(2) ``T_odom_base`` (x, y m; theta rad, REP 103); where it came from."""

    stamps: np.ndarray
    poses: np.ndarray
    topic: str = ""
    source: str = ""          # "nav_msgs/Odometry", "tf", "foxglove.PoseInFrame", ...
    frame_id: str = "odom"
    child_frame_id: str = "base_link"

    def __post_init__(self) -> None:
        self.stamps = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
        if len(self.stamps) != len(self.poses):
            raise ValueError(f"{len(self.stamps)} stamps but {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def rate_hz(self) -> float:
        span = self.stamps[-1] - self.stamps[0] if len(self) > 1 else 0.0
        return (len(self) - 1) / span if span > 0 else 0.0

    def at(self, stamps) -> np.ndarray:
        """``T_odom_base`` (M, 3) at ``stamps`` (M,), interpolated on SE(2) between the two
        neighbouring samples; NaN rows outside ``[stamps[0], stamps[-1]]``."""
        t = np.asarray(stamps, dtype=np.float64).reshape(-1)
        out = np.full((len(t), 3), np.nan)
        if len(self) == 0:
            return out
        inside = (t >= self.stamps[0]) & (t <= self.stamps[-1])
        if len(self) == 1:
            out[inside] = self.poses[0]
            return out
        ti = t[inside]
        j = np.clip(np.searchsorted(self.stamps, ti, side="right") - 1, 0, len(self) - 2)
        t0, t1 = self.stamps[j], self.stamps[j + 1]
        a = np.where(t1 > t0, (ti - t0) / np.where(t1 > t0, t1 - t0, 1.0), 0.0)
        p0, p1 = self.poses[j], self.poses[j + 1]
        out[inside] = se2_compose_many(p0, _se2_exp(_se2_log(se2_between_many(p0, p1)) * a[:, None]))
        return out

    def describe(self) -> str:
        """One line for ``planar-vo info``."""
        if not len(self):
            return f"{self.topic} ({self.source}): no samples"
        d = np.hypot(*np.diff(self.poses[:, :2], axis=0).T).sum() if len(self) > 1 else 0.0
        return (f"{self.topic} ({self.source}, {self.frame_id} -> {self.child_frame_id}): {len(self)} samples, "
                f"{self.rate_hz:.1f} Hz, {d:.2f} m")


def planar_pose(T: np.ndarray) -> np.ndarray:
    """SE(2) ``(x, y, yaw)`` of a (4, 4) pose in a z-up frame (height, pitch and roll dropped)."""
    T = np.asarray(T, dtype=np.float64)
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])


# ------------------------------------------------------------------------- dispatch

def _frame(name: str) -> str:
    return name.lstrip("/")


def _is_ground_truth(topic: str) -> bool:
    return "ground_truth" in topic or "groundtruth" in topic


def choose_odometry_topic(topics_by_kind: dict, override: str | None = None,
                          source: str = "log") -> tuple[str, str] | None:
    """``(topic, kind)`` of the wheel odometry among a log's topics, or None.

    ``topics_by_kind``: kind (``messages.ODOMETRY``, ``TRANSFORMS``, ``POSE``, ...) -> topics.
    Tried in order: ``nav_msgs/Odometry`` (``/odom`` first), the ``/tf`` topic, a pose topic
    with ``odom`` in its name. ``override`` (``--odom-topic``) must be one of those kinds.
    """
    if override is not None:
        for kind in SOURCE_KINDS:
            if override in topics_by_kind.get(kind, ()):
                return override, kind
        cands = sorted({t for k in SOURCE_KINDS for t in topics_by_kind.get(k, ())
                        if not t.endswith("tf_static") and not _is_ground_truth(t)})
        raise InputError(f"{source}: --odom-topic {override} is not an odometry, /tf or pose topic of the log "
                         f"(candidates: {', '.join(cands) or 'none'})")
    odo = sorted(set(topics_by_kind.get(m.ODOMETRY, ())))
    if odo:
        return ("/odom" if "/odom" in odo else odo[0]), m.ODOMETRY
    tf = sorted({t for t in topics_by_kind.get(m.TRANSFORMS, ()) if not t.endswith("tf_static")})
    if tf:
        return ("/tf" if "/tf" in tf else tf[0]), m.TRANSFORMS
    poses = sorted({t for t in topics_by_kind.get(m.POSE, ()) if "odom" in t.lower() and not _is_ground_truth(t)})
    if poses:
        return ("/odom" if "/odom" in poses else poses[0]), m.POSE
    return None


def odometry_samples(kind: str, msg) -> list[tuple[float, str, str, np.ndarray]]:
    """``[(stamp, parent, child, T (4, 4))]`` of wheel odometry in one decoded message."""
    if kind == m.ODOMETRY:
        return [m.parse_odometry(msg)]
    if kind == m.TRANSFORMS:
        return [s for s in m.parse_transforms(msg)
                if _frame(s[1]) in ODOM_FRAMES and _frame(s[2]) in BASE_FRAMES]
    if kind == m.POSE:
        stamp, frame, T = m.parse_pose(msg)
        return [(stamp, frame, "base_link", T)]
    return []


_SOURCE_NAMES = {m.ODOMETRY: "nav_msgs/Odometry", m.TRANSFORMS: "tf", m.POSE: "pose"}


def odometry_from_messages(topic: str, kind: str, messages, schema_name: str = "") -> WheelOdometry | None:
    """A :class:`WheelOdometry` from the decoded messages (iterable of ``(log_stamp, msg)``)
    of ``topic``; None when it carries no odometry sample (e.g. a ``/tf`` without
    ``odom -> base_link``). Header stamps are used (log time if unset); samples are
    sorted by stamp and duplicates dropped."""
    stamps, poses, frames = [], [], None
    for log_stamp, msg in messages:
        for stamp, parent, child, T in odometry_samples(kind, msg):
            stamps.append(stamp if stamp > 0 else log_stamp)
            poses.append(planar_pose(T))
            frames = frames or (_frame(parent) or "odom", _frame(child) or "base_link")
    if not stamps:
        return None
    st = np.asarray(stamps)
    order = np.argsort(st, kind="stable")
    st, P = st[order], np.asarray(poses)[order]
    keep = np.concatenate([[True], np.diff(st) > 0])
    name = schema_name or _SOURCE_NAMES.get(kind, kind)
    return WheelOdometry(st[keep], P[keep], topic=topic, source=name, frame_id=frames[0], child_frame_id=frames[1])


# -------------------------------------------------------------------- synthetic model

@dataclass
class WheelOdomModel:
    """Error model of a differential-drive robot's wheel odometry (all dimensionless unless said).

    The true base motion between two odometry samples is split into the wheels' travels
    ``d_l, d_r = ds -+ dtheta * B / 2`` (B the true wheelbase). Each encoder reads
    ``(1 + scale) d + N(0, (noise * sqrt|d|)^2)`` (wheel radius error, slip); the odometry
    integrates ``ds' = (d_l' + d_r') / 2`` and ``dtheta' = (d_r' - d_l') (1 + wheelbase) / B``
    (its wheelbase is ``B / (1 + wheelbase)``, so turns come out scaled) plus
    ``drift_deg_per_m`` degrees per metre travelled (an uneven load, a soft tyre).
    """

    scale: float = 0.02
    wheelbase: float = 0.03
    drift_deg_per_m: float = 0.5
    noise: float = 0.001         # m per sqrt(m) of wheel travel
    rate_hz: float = 50.0        # samples per second (at least the frame rate)
    wheelbase_m: float = 0.4     # true wheelbase B
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("scale", "wheelbase"):
            if not -0.5 < getattr(self, name) < 0.5:
                raise ValueError(f"wheel odometry {name} error must be within +-0.5, got {getattr(self, name)}")
        if not self.noise >= 0:
            raise ValueError(f"wheel odometry noise must be >= 0, got {self.noise}")
        if not self.rate_hz > 0 or not self.wheelbase_m > 0:
            raise ValueError(f"wheel odometry rate_hz and wheelbase_m must be > 0, got {self.rate_hz}, "
                             f"{self.wheelbase_m}")
        if not math.isfinite(self.drift_deg_per_m):
            raise ValueError(f"wheel odometry drift must be finite, got {self.drift_deg_per_m}")

    def metadata(self) -> dict[str, str]:
        """The parameters as an MCAP metadata record (strings)."""
        return {k: repr(v) for k, v in asdict(self).items()}


def simulate_wheel_odometry(poses_world_base: np.ndarray, model: WheelOdomModel) -> np.ndarray:
    """Odometry ``T_odom_base`` (M, 3) along a true base path ``poses_world_base`` (M, 3)
    sampled at the odometry's own instants; ``odom`` is the first true pose. Deterministic
    for ``model.seed``."""
    P = np.asarray(poses_world_base, dtype=np.float64).reshape(-1, 3)
    rel = se2_between_many(P[:-1], P[1:])
    dth = rel[:, 2]
    # arc length of each increment, taken as a circular arc (a wheeled base moves along its heading)
    ds = np.sign(rel[:, 0]) * np.hypot(rel[:, 0], rel[:, 1]) / np.sinc(dth / (2.0 * np.pi))
    B = model.wheelbase_m
    rng = np.random.default_rng([int(model.seed), 2031])
    wheels = np.column_stack([ds - 0.5 * B * dth, ds + 0.5 * B * dth])
    read = (1.0 + model.scale) * wheels + model.noise * np.sqrt(np.abs(wheels)) * rng.standard_normal(wheels.shape)
    ds_o = read.mean(axis=1)
    dth_o = (read[:, 1] - read[:, 0]) * (1.0 + model.wheelbase) / B \
        + math.radians(model.drift_deg_per_m) * np.abs(ds)
    theta = np.concatenate([[0.0], np.cumsum(dth_o)])
    mid = theta[:-1] + 0.5 * dth_o   # an arc's chord points along its midpoint heading
    chord = ds_o * np.sinc(dth_o / (2.0 * np.pi))
    x = np.concatenate([[0.0], np.cumsum(chord * np.cos(mid))])
    y = np.concatenate([[0.0], np.cumsum(chord * np.sin(mid))])
    return np.column_stack([x, y, wrap_angle(theta)])
