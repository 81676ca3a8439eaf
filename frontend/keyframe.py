"""Steps measured against a keyframe, not only the previous frame.

A step's translation comes from depth differences of the same corners in two views, and
the depth noise of a Kinect at 3-5 m (1-3 cm per reading) does not shrink with the step.
At 30 Hz and 0.2 m/s a step is 7 mm: frame to frame, each step's forward error was 6.5 mm
rms on a low-texture tuning hall (seed 3702), and 600 such independent errors walk the
end point 16 cm away (2 % of its path) although each step is unbiased. Measured against
a keyframe K, the motion ``K -> i`` has about the same error whatever the baseline, and
the step ``i-1 -> i`` is the difference of two such motions: consecutive errors cancel and
the chain errs only by the motion at each keyframe change.

:class:`KeyframeTracker` keeps K's corners (levelled), follows them through the
tracker's frame-to-frame matches, and holds the motion ``K -> i-1`` that the steps so far
chained to. The front-end estimates each step as before (which estimator, its yaw, veto,
gates: :class:`planar_vo.frontend.odometry.PlanarOdometry`), then re-measures the motion
``K -> i`` with the same estimator on K's corners; the re-measured motion must agree with
``(K -> i-1) * step`` within its gate, and the step becomes ``(K -> i-1)^-1 (K -> i)``.
K is renewed (the current frame becomes it) when too few of its corners are still
tracked, when the baseline grows past a limit, or when a step was not measured from
points (a partial or bridged step, or a re-measurement that disagreed).

Motions are levelled: ``(yaw, t)`` with ``X_2 = R_y(yaw) X_1 + t``, ``t`` (3,) metres
(``t[1] = 0``), as everywhere in the front-end.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core import geometry


def rot_y(yaw: float) -> np.ndarray:
    """(3, 3) ``R_y(yaw)``: the levelled rotation of a planar motion."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def compose(a: tuple[float, np.ndarray], b: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
    """Motion ``1 -> 3`` of ``a`` (``1 -> 2``) followed by ``b`` (``2 -> 3``):
    ``X_3 = R_b (R_a X_1 + t_a) + t_b``."""
    return float(geometry.wrap_angle(a[0] + b[0])), rot_y(b[0]) @ np.asarray(a[1], float) + np.asarray(b[1], float)


def between(a: tuple[float, np.ndarray], c: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
    """Motion ``2 -> 3`` given ``a`` (``1 -> 2``) and ``c`` (``1 -> 3``): the ``b`` with
    ``compose(a, b) == c``."""
    yaw = float(geometry.wrap_angle(c[0] - a[0]))
    return yaw, np.asarray(c[1], float) - rot_y(yaw) @ np.asarray(a[1], float)


def compose_covariance(a: tuple[float, np.ndarray], b: tuple[float, np.ndarray], cov_a: np.ndarray,
                       cov_b: np.ndarray) -> np.ndarray:
    """(3, 3) covariance over ``(yaw, t_x, t_z)`` of :func:`compose` ``(a, b)`` with
    independent errors of covariances ``cov_a``, ``cov_b`` (first order)."""
    c, s = math.cos(b[0]), math.sin(b[0])
    ta = np.asarray(a[1], float)
    Ja = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    Jb = np.array([[1.0, 0.0, 0.0], [-s * ta[0] + c * ta[2], 1.0, 0.0], [-c * ta[0] - s * ta[2], 0.0, 1.0]])
    return Ja @ cov_a @ Ja.T + Jb @ cov_b @ Jb.T


@dataclass
class Keyframe:
    """K: its corners and the motion from it to the latest frame.

    ``x_lev`` (N, 2), ``P_lev`` (N, 3): K's levelled corners (NaN rows without depth);
    ``planes``: K's walls and floor; ``owner`` (M,) int64: for each corner of the latest
    frame, the index of the K corner it was tracked from, -1 for corners found later;
    ``motion``: ``(yaw, t)`` from K to the latest frame, ``cov`` (3, 3) over
    ``(yaw, t_x, t_z)``; ``guess_cov``: the part of ``cov`` that guessed steps (partial,
    bridged) added since the last measured motion; ``walls``: a step since K took its yaw
    from walls; ``start``: corners of K still tracked
    one frame after K (the reference for renewal); ``age``: frames since K.
    """

    x_lev: np.ndarray
    P_lev: np.ndarray
    planes: list
    owner: np.ndarray
    motion: tuple[float, np.ndarray]
    cov: np.ndarray
    guess_cov: np.ndarray
    start: int = 0
    age: int = 0
    #: a step since K took its yaw from walls (eq. 1): the chained yaw is then better than
    #: a 2-point yaw measured from K, which is only re-measured on 2-point chains
    walls: bool = False
    #: ``(age, motion)`` of the motions from K measured so far (K itself first)
    measured: list = field(default_factory=list)
    #: K's depth (H, W) float32 metres and levelling (3, 3), for the depth alignment of
    #: weak-scale motions from K (set by the odometry), and its sampled points, once
    depth: np.ndarray | None = None
    R_lev_cam: np.ndarray | None = None
    align_points: tuple | None = None


class KeyframeTracker:
    """The keyframe of :class:`~planar_vo.frontend.odometry.PlanarOdometry` (module docstring).

    Per frame: :meth:`follow` with the tracker's matches, then (per estimate tried)
    :meth:`correspondences` and :meth:`predicted`, and last :meth:`commit` with the step
    taken. ``min_fraction``: K is renewed when fewer than this share of the corners it
    had one frame later are still tracked; ``max_baseline_m`` / ``max_yaw_deg``: ... or
    when the motion from K exceeds these.
    """

    def __init__(self, min_fraction: float = 0.5, max_baseline_m: float = 1.0, max_yaw_deg: float = 30.0):
        self.min_fraction = float(min_fraction)
        self.max_baseline_m = float(max_baseline_m)
        self.max_yaw = math.radians(max_yaw_deg)
        self.kf: Keyframe | None = None
        self._owner: np.ndarray | None = None  # this frame's owners, until commit

    def follow(self, matches: np.ndarray, n_features: int) -> int:
        """Carry K's corners to this frame through ``matches`` (M, 2) ``[i_prev, i_curr]``
        of the feature tracker; returns how many of K's corners are still tracked."""
        owner = np.full(n_features, -1, dtype=np.int64)
        if self.kf is not None and len(matches):
            owner[matches[:, 1]] = self.kf.owner[matches[:, 0]]
        self._owner = owner
        return int((owner >= 0).sum())

    def active(self) -> bool:
        """True when K is an earlier frame than the previous one (else the frame-to-frame
        step already is the keyframe-relative one)."""
        return self.kf is not None and self.kf.age >= 1 and self._owner is not None

    def correspondences(self, x_lev: np.ndarray, P_lev: np.ndarray):
        """``(x1, x2, P1, P2)``: K's corners and this frame's, matched through the tracks
        (rows with levelled coordinates finite in both)."""
        cur = np.flatnonzero(self._owner >= 0)
        k = self._owner[cur]
        x1, x2, P1, P2 = self.kf.x_lev[k], x_lev[cur], self.kf.P_lev[k], P_lev[cur]
        ok = np.isfinite(x1).all(1) & np.isfinite(x2).all(1)
        return x1[ok], x2[ok], P1[ok], P2[ok]

    def predicted(self, step: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
        """The motion K -> this frame the steps chain to with ``step`` (previous -> this)."""
        return compose(self.kf.motion, step)

    def step_from(self, motion_k: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
        """The step previous -> this frame of a motion K -> this frame."""
        return between(self.kf.motion, motion_k)

    def velocity(self, motion_k: tuple[float, np.ndarray], window: int) -> tuple[np.ndarray, int]:
        """``(v, n)``: levelled translation per frame (3,) over the last ``n`` frames, from
        the motion K -> this frame ``motion_k`` and the earliest motion from K measured at
        most ``window`` frames before: the difference of two motions from K (its noise
        that of two frames, whatever ``n``), not a sum of ``n`` steps."""
        age = self.kf.age + 1
        a, m = next(((a, m) for a, m in self.kf.measured if age - a <= window), self.kf.measured[-1])
        n = max(age - a, 1)
        return between(m, motion_k)[1] / n, n

    def commit(self, x_lev: np.ndarray, P_lev: np.ndarray, planes: list, measured=None, guessed=None,
               walls: bool = False, yaw_var: float | None = None) -> bool:
        """End the frame; returns True when this frame became K.

        ``measured``: ``(motion K -> this frame, (3, 3) cov)`` the step was taken from (its
        re-measurement, or the step itself when K is the previous frame); ``guessed``:
        ``(step, cov)`` of a step that points did not measure (partial, bridged): it is
        carried onto K's motion, so that the next measured step, re-measured against K,
        takes back what the guess got wrong. Neither: this frame becomes K (a measured step
        whose re-measurement failed). ``walls``: the step's yaw came from walls.
        ``yaw_var`` (rad^2): a guessed step whose yaw was measured from K (its yaw is the
        difference of two yaws from K): the motion's yaw is then that measurement, of this
        variance, no longer the sum of the guesses.
        """
        kf = self.kf
        tracked = int((self._owner >= 0).sum()) if self._owner is not None else 0
        renew = kf is None or (measured is None and guessed is None)
        if not renew:
            kf.age += 1
            kf.walls |= bool(walls)
            if kf.age == 1:
                kf.start = tracked
            if measured is not None:
                kf.motion = (float(measured[0][0]), np.asarray(measured[0][1], float))
                kf.cov, kf.guess_cov = np.asarray(measured[1], float), np.zeros((3, 3))
                kf.measured = (kf.measured + [(kf.age, kf.motion)])[-64:]
            else:
                b, cov_b = (float(guessed[0][0]), np.asarray(guessed[0][1], float)), np.asarray(guessed[1], float)
                kf.cov = compose_covariance(kf.motion, b, kf.cov, cov_b)
                kf.guess_cov = compose_covariance(kf.motion, b, kf.guess_cov, cov_b)
                kf.motion = compose(kf.motion, b)
                if yaw_var is not None:
                    for m in (kf.cov, kf.guess_cov):
                        m[0, :] = m[:, 0] = 0.0
                    kf.cov[0, 0] = float(yaw_var)
            kf.owner = self._owner
            renew = (tracked < self.min_fraction * max(kf.start, 1)
                     or math.hypot(kf.motion[1][0], kf.motion[1][2]) > self.max_baseline_m
                     or abs(kf.motion[0]) > self.max_yaw)
        if renew:
            self.kf = Keyframe(np.asarray(x_lev, float), np.asarray(P_lev, float), list(planes or []),
                               np.arange(len(x_lev), dtype=np.int64), (0.0, np.zeros(3)), np.zeros((3, 3)),
                               np.zeros((3, 3)), measured=[(0, (0.0, np.zeros(3)))])
        self._owner = None
        return renew
