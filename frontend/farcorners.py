"""Depths of the corners the sensor does not read, triangulated from the measured motion.

In an open hall most corners lie beyond the depth sensor's range (pillars, doors and boxes
5-10 m away, a 4.5 m Kinect), so the 2-point method finds the step's yaw and direction but
no scale, and with no wall in view the step's translation is the constant-velocity guess.
Where the base also stops and drives on inside such a stretch, the guess is wrong for the
whole stretch: on a low-texture hall with speed dips (hall_s7700 of
``docs/bench/probe_speed_dips_lowtex.py``) it held a near-stop's 3 mm a step for 55 steps
while the base drove 55 mm a step again, and the run ended 16 % of its path off.

Those corners were tracked, though, while the steps before were measured. Each corner
keeps the ray it had where it was first seen (its anchor) and is triangulated along it
from its image positions and the measured motion since (the inverse depth of the view
with the least variance, a variance that does not depend on the estimate itself: one
that did kept the estimates that came out too near). A frame whose step no estimator
measured is then resected against the corners whose depth is known to ``MAX_REL_SIGMA``:
the motion from the anchor frame A (yaw, t_x, t_z) from their rays alone, each residual's
variance holding its image noise and its depth's uncertainty, the walls' yaw as a prior
when there is one. The step is the difference of the motions A -> i-1 and A -> i, as for
keyframes (frontend/keyframe.py): the depths' errors, common to both, only scale it.

A is the frame the corners' motions are counted from; it moves on (the corners keep their
anchors and depths) when fewer than half of its corners are still tracked. A motion that
came from a resection is the depths' own, so no corner is triangulated through it: after
one, or after a step that was neither measured nor resected, the tracked corners are
anchored again where they are, their depths carried over. Motions are levelled, as in
the whole front-end: ``X_2 = R_y(yaw) X_1 + t`` with ``t`` (3,) metres, ``t[1] = 0``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.frontend.keyframe import between, compose

#: A resection needs this many corners with depth agreeing with it, and half of those tried.
MIN_POINTS = 8
#: Corners take part in a resection once their inverse depth is known to this fraction:
#: their errors scale every step resected against them alike (the same corners, frame
#: after frame), and a cut on the estimate's own precision also prefers the estimates that
#: came out too near. On the tuning halls (seeds 3700-3707) 0.3 and 0.2 were alike; 0.1
#: left too few corners to resect a restart (hall_s7700), no cut let a 20-50 % uncertain
#: start shorten the resected steps.
MAX_REL_SIGMA = 0.3
#: Gauss-Newton iterations per solve, and the robust rounds (inliers re-selected).
_ITERATIONS = 6
_ROUNDS = 3
#: chi-square (2 dof, 99 %) of a corner's image residual in its own sigmas.
_GATE_CHI2 = 9.21
#: A point closer than this (levelled z, m) in the resected frame is behind the camera.
_MIN_Z = 0.05


@dataclass
class FarOptions:
    """``pixel_sigma``: a corner's image noise (normalised coordinates, px / focal);
    ``walk``: its tracking drift per sqrt(frame) since A (normalised coordinates; the
    keyframes' ``keyframe_track_px`` walk); ``min_fraction``: A is renewed below this
    share of its corners still tracked; ``depth_sigma``: the sensor's ``(const, quad)``
    noise model, sigma_Z = const + quad Z^2 (m)."""

    pixel_sigma: float
    walk: float
    min_fraction: float = 0.5
    depth_sigma: tuple[float, float] = (0.0, 0.003)


def _project(b: np.ndarray, rho: np.ndarray, yaw: float, t: np.ndarray):
    """Images ``(K, 2)`` of A's rays ``b`` (K, 2) at inverse depths ``rho`` (K,) seen after
    the motion ``(yaw, t)``, and ``N`` (K, 3) = rho * the point in the new frame
    (``N = R b + rho t``, finite for points at infinity, rho = 0)."""
    c, s = math.cos(yaw), math.sin(yaw)
    N = np.empty((len(b), 3))
    N[:, 0] = c * b[:, 0] + s + rho * t[0]
    N[:, 1] = b[:, 1] + rho * t[1]
    N[:, 2] = -s * b[:, 0] + c + rho * t[2]
    return N[:, :2] / N[:, 2:3], N


def _jacobians(b: np.ndarray, rho: np.ndarray, yaw: float, t: np.ndarray, N: np.ndarray):
    """``(J (K, 2, 3), D (K, 2))``: derivatives of the images over ``(yaw, t_x, t_z)`` and
    over each corner's inverse depth."""
    c, s = math.cos(yaw), math.sin(yaw)
    iz = 1.0 / N[:, 2]
    px, py = N[:, 0] * iz, N[:, 1] * iz
    dN = np.zeros((len(b), 3, 3))  # d N / d (yaw, t_x, t_z), columns
    dN[:, 0, 0] = -s * b[:, 0] + c
    dN[:, 2, 0] = -c * b[:, 0] - s
    dN[:, 0, 1] = rho
    dN[:, 2, 2] = rho
    J = np.empty((len(b), 2, 3))
    J[:, 0, :] = (dN[:, 0, :] - px[:, None] * dN[:, 2, :]) * iz[:, None]
    J[:, 1, :] = (dN[:, 1, :] - py[:, None] * dN[:, 2, :]) * iz[:, None]
    D = np.stack([(t[0] - px * t[2]) * iz, (t[1] - py * t[2]) * iz], axis=1)
    return J, D


@dataclass
class Resection:
    """A solved :func:`resect`: ``motion`` ``(yaw, t)``; ``cov`` (3, 3) over ``(yaw, t_x,
    t_z)`` (image noise and the depths' errors); ``inliers`` (K,) bool; at the solution,
    over the inliers: ``J`` (L, 2, 3) the images' derivatives over the motion, ``D`` (L, 2)
    over each corner's inverse depth, ``var`` (L, 2) the residuals' variances, and ``chi2``
    the residuals' squares in those variances, summed (``2 L - 3`` degrees of freedom)."""

    motion: tuple[float, np.ndarray]
    cov: np.ndarray
    inliers: np.ndarray
    J: np.ndarray
    D: np.ndarray
    var: np.ndarray
    chi2: float = float("nan")


def resect(b: np.ndarray, rho: np.ndarray, var_rho: np.ndarray, x: np.ndarray, init: tuple[float, np.ndarray],
           sigma: float, min_points: int = MIN_POINTS, yaw_prior: tuple[float, float] | None = None
           ) -> Resection | None:
    """The planar motion ``(yaw, t)`` from a frame A to a frame whose images ``x`` (K, 2)
    (levelled normalised) show A's rays ``b`` (K, 2) of inverse depths ``rho`` (K,) with
    variances ``var_rho`` (K,): robust Gauss-Newton from ``init``, each residual weighted
    by ``sigma^2`` (the image noise) plus its depth's uncertainty mapped into the image.
    ``yaw_prior``: ``(yaw, variance)`` of the yaw measured otherwise (walls): far corners
    tell a sideways translation from a yaw poorly. None with fewer than ``min_points``
    corners agreeing, or fewer than half of them."""
    if len(b) < min_points:
        return None
    yaw, t = float(init[0]), np.array(init[1], dtype=float)
    inl = np.ones(len(b), bool)
    for r in range(_ROUNDS + 1):
        for _ in range(_ITERATIONS):
            p, N = _project(b, rho, yaw, t)
            use = inl & (N[:, 2] > _MIN_Z * np.maximum(rho, 1e-9))
            if int(use.sum()) < min_points:
                return None
            J, D = _jacobians(b, rho, yaw, t, N)
            var = sigma ** 2 + D * D * var_rho[:, None]  # (K, 2)
            w = 1.0 / var
            if r == 0:
                # first a Cauchy-weighted solve over every corner, so that the wrong tracks
                # (a corner jumping to another) do not drag the start the gate then judges by
                chi2 = (((p - x) ** 2) * w).sum(1)
                w = w / (1.0 + chi2 / _GATE_CHI2)[:, None]
            Ju, w = J[use], w[use]
            H = np.einsum("kai,ka,kaj->ij", Ju, w, Ju)
            g = np.einsum("kai,ka,ka->i", Ju, w, (p - x)[use])
            if yaw_prior is not None:
                H[0, 0] += 1.0 / yaw_prior[1]
                g[0] += (yaw - yaw_prior[0]) / yaw_prior[1]
            try:
                d = np.linalg.solve(H, -g)
            except np.linalg.LinAlgError:
                return None
            yaw, t[0], t[2] = yaw + float(d[0]), t[0] + float(d[1]), t[2] + float(d[2])
            if float(np.abs(d).max()) < 1e-10:
                break
        p, N = _project(b, rho, yaw, t)
        J, D = _jacobians(b, rho, yaw, t, N)
        var = sigma ** 2 + D * D * var_rho[:, None]
        new = ((((p - x) ** 2) / var).sum(1) < _GATE_CHI2) & (N[:, 2] > _MIN_Z * np.maximum(rho, 1e-9))
        if np.array_equal(new, inl):
            break
        inl = new
    n = int(inl.sum())
    if n < min_points or n < 0.5 * len(b):
        return None
    H = np.einsum("kai,ka,kaj->ij", J[inl], 1.0 / var[inl], J[inl])
    if yaw_prior is not None:
        H[0, 0] += 1.0 / yaw_prior[1]
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0)):
        return None
    return Resection((yaw, t), cov, inl, J[inl], D[inl], var[inl], float((((p - x)[inl] ** 2) / var[inl]).sum()))


def triangulate(b: np.ndarray, x: np.ndarray, motion: tuple, sigma: np.ndarray | float):
    """Inverse depths ``(rho (K,), var (K,))`` along rays ``b`` (K, 2) seen at ``x`` (K, 2)
    after the motion ``(yaw, t)`` (one, or one per ray: ``yaw`` (K,), ``t`` (K, 3)), from
    the image noise ``sigma`` (normalised, both views together; scalar or (K,)): the least
    squares of the two image equations, each linear in rho
    (``x (R b + rho t)_z = (R b + rho t)_x``, the same for y)."""
    yaw, t = np.asarray(motion[0], float), np.asarray(motion[1], float)
    t = np.broadcast_to(t, (len(b), 3))
    c, s = np.cos(yaw), np.sin(yaw)
    Rb = np.stack([c * b[:, 0] + s, b[:, 1], -s * b[:, 0] + c], axis=1)
    a = np.stack([x[:, 0] * t[:, 2] - t[:, 0], x[:, 1] * t[:, 2] - t[:, 1]], axis=1)
    cc = np.stack([Rb[:, 0] - x[:, 0] * Rb[:, 2], Rb[:, 1] - x[:, 1] * Rb[:, 2]], axis=1)
    aa = (a * a).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = (a * cc).sum(1) / aa
        # an image error dx moves the equation by (R b + rho t)_z dx, taken at rho = 0: with
        # the estimate's own rho, the nearer a noisy estimate the smaller its variance, and
        # keeping the least-variance view kept estimates too near (resected steps too short)
        scale = np.abs(Rb[:, 2]) * sigma
        var = scale * scale / aa
    return rho, var


def compose_many(yaw_a: np.ndarray, t_a: np.ndarray, b: tuple[float, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~planar_vo.frontend.keyframe.compose` of K motions ``(yaw_a (K,), t_a (K, 3))``
    each followed by the one motion ``b``."""
    c, s = math.cos(b[0]), math.sin(b[0])
    t = np.empty_like(t_a)
    t[:, 0] = c * t_a[:, 0] + s * t_a[:, 2] + b[1][0]
    t[:, 1] = t_a[:, 1] + b[1][1]
    t[:, 2] = -s * t_a[:, 0] + c * t_a[:, 2] + b[1][2]
    return yaw_a + b[0], t


def _in_frame(b: np.ndarray, rho: np.ndarray, var: np.ndarray, yaw: np.ndarray, t: np.ndarray):
    """Rays, inverse depths and variances ``(b (K, 2), rho (K,), var (K,), front (K,) bool)``
    in a frame reached by the motions ``(yaw (K,), t (K, 3))`` from the corners' anchors,
    where they had rays ``b`` (K, 2), inverse depths ``rho`` and variances ``var``."""
    c, s = np.cos(yaw), np.sin(yaw)
    Nx = c * b[:, 0] + s + rho * t[:, 0]
    Ny = b[:, 1] + rho * t[:, 1]
    Rz = -s * b[:, 0] + c
    Nz = Rz + rho * t[:, 2]
    front = Nz > _MIN_Z * np.maximum(rho, 1e-9)
    Nz = np.where(front, Nz, 1.0)
    return np.column_stack([Nx / Nz, Ny / Nz]), rho / Nz, var * (Rz / (Nz * Nz)) ** 2, front


class FarCorners:
    """The far corners' depths and the motion from the anchor frame A to the latest frame.

    Each corner keeps the ray it had where it was first seen (its own anchor), the motion
    from there to A, and its inverse depth along that ray, so that a track outliving A is
    triangulated over its whole baseline. Per frame: :meth:`follow` with the tracker's
    matches; :meth:`step` when no estimator measured the step (a partial or bridged step);
    :meth:`commit` with what the step was.
    """

    def __init__(self, options: FarOptions):
        self.opt = options
        n = 0
        self._b = np.zeros((n, 2))       # (M, 2) A's corners' rays in their anchors
        self._ya = np.zeros(n)           # (M,) yaw of the motion anchor -> A
        self._ta = np.zeros((n, 3))      # (M, 3) its translation
        self._age_a = np.zeros(n)        # (M,) frames from the anchor to A
        self._rho = np.zeros(n)          # (M,) inverse depth along the ray (1/m), NaN unknown
        self._var = np.zeros(n)          # (M,) its variance
        self._tri = np.zeros(n, bool)    # (M,) the anchor -> A motion is the measured steps'
        self._owner: np.ndarray | None = None  # this frame's corners -> A's, -1 none
        self._start = 0                  # A's corners tracked one frame after A
        self._motion: tuple[float, np.ndarray] | None = None  # A -> latest frame
        self._cov = np.zeros((3, 3))
        self._age = 0
        self._resected: tuple | None = None  # this frame's resection (motion, cov)
        self.resection: Resection | None = None  # this frame's resection from A (:meth:`step`)
        self._after_resection = False        # the motion A -> latest frame is a resection
        self._independent = True             # no resection since A: the motion is the steps'

    @property
    def age(self) -> int:
        """Frames from A to the latest committed one (0: the latest frame is A)."""
        return self._age

    def follow(self, matches: np.ndarray, n_features: int, unread: np.ndarray | None = None) -> None:
        """Carry A's corners to this frame through ``matches`` (M, 2) ``[i_prev, i_curr]``.
        ``unread`` (N,) bool: this frame's corners with no depth reading around them (beyond
        the range, or a dropout wider than the depth window); only they are followed. A corner
        with readings around it but no usable depth lies on a depth edge, and its image does
        not follow one point: on a textureless corridor such corners resected a step 15 of
        its sigmas off (tests/test_drift_free_yaw.py)."""
        owner = np.full(n_features, -1, dtype=np.int64)
        if self._owner is not None and len(matches):
            owner[matches[:, 1]] = self._owner[matches[:, 0]]
        if unread is not None:
            owner[~unread] = -1
        self._owner = owner
        self._resected = None
        self.resection = None

    def _sigma(self, age) -> np.ndarray | float:
        """Image sigma (normalised) of a corner over ``age`` frames: both views' noise and
        the track's drift."""
        return np.sqrt(2.0 * self.opt.pixel_sigma ** 2 + age * self.opt.walk ** 2)

    def _usable(self, x_lev: np.ndarray):
        """``(cur, k, b, rho, var)``: this frame's corners (``cur``) tracked from A's (``k``)
        whose depth is known to ``MAX_REL_SIGMA``, as rays, inverse depths and variances in A."""
        cur = np.flatnonzero(self._owner >= 0)
        k = self._owner[cur]
        ok = np.isfinite(self._rho[k]) & np.isfinite(x_lev[cur]).all(1)
        cur, k = cur[ok], k[ok]
        b, rho, var, front = _in_frame(self._b[k], self._rho[k], self._var[k], self._ya[k], self._ta[k])
        ok = front & (np.sqrt(var) <= MAX_REL_SIGMA * rho)
        return cur[ok], k[ok], b[ok], rho[ok], var[ok]

    def step(self, x_lev: np.ndarray, guess: tuple[float, np.ndarray], yaw_var: float | None = None):
        """``(step (yaw, t), cov (3, 3), corners)`` of the step into this frame resected
        against A (``x_lev`` (N, 2) this frame's corners, ``guess`` the step's levelled
        guess, the solve's start), or None. ``yaw_var``: the guess's yaw was measured
        (walls, 2-point) with this variance (rad^2)."""
        if self._motion is None or self._owner is None:
            return None
        cur, k, b, rho, var = self._usable(x_lev)
        # the image error: both views' noise, and the track's drift since A (the anchor's
        # ray was carried into A by motions, its own drift is in its depth's variance)
        sigma = float(self._sigma(self._age + 1))
        init = compose(self._motion, guess)
        # the yaw A -> i-1 errs alike in both motions after a resection (the step's yaw is
        # what was measured); after measured steps it is the chain's
        shared = 0.0 if self._after_resection else float(self._cov[0, 0])
        prior = None if yaw_var is None else (init[0], yaw_var + shared)
        res = resect(b, rho, var, x_lev[cur], init, sigma, yaw_prior=prior)
        if res is None:
            return None
        stp = between(self._motion, res.motion)
        # How the motion from A moves with the images and the depths (the solve's weights).
        # A corner's image error in frame i is A's view's, its track's drift since A and
        # this frame's noise: after a resection of frame i-1 against the same corners the
        # first two are common to both motions and cancel in the step, which keeps two
        # frames' noise and one frame's drift; after measured steps, the step takes back
        # what the chain A -> i-1 got wrong (its covariance) and has all of this frame's.
        G = res.cov @ (res.J.reshape(-1, 3).T / res.var.reshape(-1))  # (3, 2L)
        cov_img = (G * sigma ** 2) @ G.T
        if self._after_resection:
            var_step = 2.0 * self.opt.pixel_sigma ** 2 + self.opt.walk ** 2
            cov_own = (G * var_step) @ G.T
        else:
            cov_own = cov_img + self._cov
        # the depths' errors are common to the motions A -> i-1 and A -> i: in the step they
        # count by its share of the motion from A (the images' derivatives over them scale with t)
        Gr = (G.reshape(3, -1, 2) * res.D[None]).sum(2)  # (3, L)
        share = float(np.linalg.norm(stp[1])) / max(float(np.linalg.norm(res.motion[1])), 1e-9)
        cov_depth = (Gr * var[res.inliers]) @ Gr.T * min(share, 1.0) ** 2
        self._resected = (res.motion, cov_img)
        self.resection = res
        return stp, cov_own + cov_depth, int(res.inliers.sum())

    def commit(self, x_lev: np.ndarray, P_lev: np.ndarray, step: tuple[float, np.ndarray] | None,
               cov: np.ndarray | None) -> None:
        """End the frame. ``step``: the levelled step into it when it was measured (with
        its (3, 3) ``cov``), None when it was only guessed; a resection of this frame
        (:meth:`step`) stands for either."""
        self._after_resection = self._resected is not None
        if self._resected is not None:
            self._motion, self._cov = self._resected[0], self._resected[1]
            # from now on the motion from A is the depths' own: a view through it would only
            # confirm them (their scale locked at its first estimate)
            self._independent = False
        elif step is not None and self._motion is not None:
            self._motion = compose(self._motion, step)
            self._cov = self._cov + cov
            if not self._independent:
                # measured again after resections: the corners start over from here, their
                # depths carried, so that the steps from now on triangulate them anew
                self._renew(x_lev, P_lev, guessed=False)
                return
        else:
            # nothing measured the step: the corners' depths carry over (a guess a few
            # centimetres off moves a corner 5 m away by a percent of its depth's sigma at
            # most), their anchors' motions do not
            self._renew(x_lev, P_lev, guessed=True)
            return
        self._age += 1
        if self._independent:
            self._triangulate(x_lev)
        tracked = int((self._owner >= 0).sum())
        if self._age == 1:
            self._start = tracked
        if tracked < self.opt.min_fraction * max(self._start, 1):
            self._renew(x_lev, P_lev, guessed=False)

    def _triangulate(self, x_lev: np.ndarray) -> None:
        """Inverse depths of A's corners tracked here along their anchors' rays, from the
        motion anchor -> A -> here, where the view gives less variance than they have."""
        cur = np.flatnonzero(self._owner >= 0)
        k = self._owner[cur]
        ok = self._tri[k] & np.isfinite(x_lev[cur]).all(1)
        cur, k = cur[ok], k[ok]
        if not len(k):
            return
        yaw, t = compose_many(self._ya[k], self._ta[k], self._motion)
        rho, var = triangulate(self._b[k], x_lev[cur], (yaw, t), self._sigma(self._age_a[k] + self._age))
        # the motion's own error scales every depth alike
        tn = float(np.linalg.norm(self._motion[1]))
        if tn > 0:
            s_rel2 = float(self._cov[1, 1] + self._cov[2, 2]) / (tn * tn)
            var = var + rho * rho * s_rel2
        better = np.isfinite(rho) & (rho > 0) & np.isfinite(var) & ~(var >= self._var[k])
        self._rho[k[better]] = rho[better]
        self._var[k[better]] = var[better]

    def _renew(self, x_lev: np.ndarray, P_lev: np.ndarray, guessed: bool) -> None:
        """This frame becomes A. Corners tracked from the old A whose anchors' motion to
        here is the measured steps' keep their anchors, rays and depths; after a
        ``guessed`` step or a resection, they are anchored here, their depths carried into
        this frame (to be triangulated again over the steps to come); new corners are
        anchored here with the sensor's depth if any."""
        n = len(x_lev)
        b = np.asarray(x_lev, dtype=float).copy()
        ya, ta, age_a = np.zeros(n), np.zeros((n, 3)), np.zeros(n)
        rho, var, tri = np.full(n, np.nan), np.full(n, np.inf), np.ones(n, bool)
        z = P_lev[:, 2]
        has = np.isfinite(z) & (z > 0)
        c0, c2 = self.opt.depth_sigma
        rho[has] = 1.0 / z[has]
        var[has] = ((c0 + c2 * z[has] ** 2) / z[has] ** 2) ** 2
        if self._owner is not None and self._motion is not None:
            cur = np.flatnonzero((self._owner >= 0) & ~has)
            k = self._owner[cur]
            yk, tk = compose_many(self._ya[k], self._ta[k], self._motion)
            keep = self._tri[k] & self._independent & (not guessed)
            c, kk = cur[keep], k[keep]
            b[c], rho[c], var[c] = self._b[kk], self._rho[kk], self._var[kk]
            ya[c], ta[c], age_a[c] = yk[keep], tk[keep], self._age_a[kk] + self._age
            c, kk = cur[~keep], k[~keep]
            bh, rh, vh, front = _in_frame(self._b[kk], self._rho[kk], self._var[kk], yk[~keep], tk[~keep])
            rho[c] = np.where(front, rh, np.nan)
            var[c] = np.where(front, vh, np.inf)
        self._b, self._ya, self._ta, self._age_a = b, ya, ta, age_a
        self._rho, self._var, self._tri = rho, var, tri
        self._owner = np.arange(n, dtype=np.int64)
        self._motion, self._cov = (0.0, np.zeros(3)), np.zeros((3, 3))
        self._age, self._start = 0, 0
        self._after_resection = False
        self._independent = True
