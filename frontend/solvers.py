"""Minimal solvers for planar motion between two levelled views, and ground-truth problems.

Convention (pinned in :mod:`planar_vo.core.geometry`)
------------------------------------------------
Levelled camera frame ``lev``: x right, y down along gravity, z forward. A planar motion
maps view-1 points to view-2 points::

    X2 = R X1 + t,   R = R_y(yaw) = [[cos, 0, sin], [0, 1, 0], [-sin, 0, cos]],   t[1] = 0,

with ``yaw`` the robot's REP 103 yaw increment (turning left is positive). Normalised
image coordinates are ``x = X / Z``, ``y = Y / Z``. The essential matrix of the motion is
``E = [t]x R`` (``x2^T E x1 = 0``).

Direction-plus-point (paper Sec. 2.1, eq. 1-2)
----------------------------------------------
The yaw comes from the local Manhattan frame seen in both views (eq. 1). A fixed world
direction ``v`` is seen as ``v2 = R v1``; with headings ``h = atan2(-v_x, v_z)`` (REP 103
sense: left of forward is positive) this gives ``yaw = h1 - h2`` modulo the Manhattan
ambiguity of 90 degrees, resolved against a prior. One 3-D correspondence then gives the
translation ``t = P2 - R P1`` -- the paper's eq. 2 writes ``R^T`` because its ``R_ij``
maps the other way.

2-point homography (paper Sec. 2.2, eq. 3-17), re-derived
--------------------------------------------------------
Two non vertically aligned points define a *virtual vertical plane* ``n^T X1 = d`` with
``n = (n_x, 0, n_z)``, ``|n| = 1``, ``d > 0`` when the points are in front of camera 1.
For points ON that plane ``X2 = R X1 + t (n^T X1) / d``, so with *our* sign

    H = R + (t / d) n^T = [[h1, 0, h2], [0, 1, 0], [h3, 0, h4]]   (eq. 5-7 with t -> -t)

and, because ``Y2 = Y1``, ``p2 ~ H p1`` holds with the scale ``sigma = Z2 / Z1 = y1 / y2``
fixed by the middle row. Eq. 10 is then two 2x2 systems sharing one matrix:
``h3 x1 + h4 = y1 / y2`` and ``h1 x1 + h2 = x2 y1 / y2`` (per point). ``det(H - R) = 0``
on the x-z block gives eq. 13, ``(h1 + h4) cos + (h2 - h3) sin = 1 + h1 h4 - h2 h3``: two
yaw roots (eq. 14). ``H - R = tau n^T`` (``tau = t / d``) is rank one at either root; we
take ``n`` from its larger row and ``tau = (H - R) n``, which avoids eq. 15/17's division
by ``n_x`` / ``n_z`` (zero for forward motion facing a wall-like plane). Sign: eq. 17 has
the sign of the paper's ``H = R - t n^T / d``; with our ``H = R + t n^T / d`` the
translation is ``t = +d (h1 - cos, 0, h4 - cos) / (n_x, n_z)`` (proved against simulation
in ``tests/test_solvers.py``). ``(n, t)`` and ``(-n, -t)`` give the same ``H``; both are
returned, chirality decides in the estimator.

Caveat (a): the homography is exact only for points on the virtual plane through the
*sampled pair*; any other point lies on a different vertical plane. Hypotheses are
therefore scored and refined with the epipolar (Sampson) error of ``E = [t]x R``, never
with ``H`` (see :mod:`planar_vo.frontend.estimators`).

Degenerate inputs (points on one vertical line, on the horizon ``y = 0``, non-finite,
too few) give no solution; zero translation gives one solution per yaw flagged
``pure_rotation`` with ``t = 0``. Solvers never raise on such data and never return NaN.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.geometry import rot_y, wrap_angle

__all__ = [
    "PlanarMotion",
    "heading_of_direction",
    "manhattan_yaw_candidates",
    "yaw_from_manhattan_headings",
    "relpose_planar_dirpoint_1pt",
    "relpose_upright_planar_homography_2pt",
    "homography_2pt_batch",
    "essential_from_planar",
]

#: Below this |x1a - x1b|, |y2| or |t/d| the pair is degenerate (normalised units).
_EPS = 1e-12


@dataclass
class PlanarMotion:
    """A planar motion ``X2 = R_y(yaw) X1 + t`` between levelled views.

    ``yaw``: radians, wrapped to [-pi, pi). ``t``: (3,) float64 with ``t[1] = 0``; unit length
    when only the direction is observable (2-point solver), metric (metres) otherwise.
    ``n``: (3,) unit normal of the virtual vertical plane in view 1 (2-point solver only),
    ``t_over_d``: ``|t| / d`` of that plane. ``pure_rotation``: the solver saw no
    translation (``t`` is then zero).
    """

    yaw: float
    t: np.ndarray
    n: np.ndarray | None = None
    t_over_d: float | None = None
    pure_rotation: bool = False

    @property
    def R(self) -> np.ndarray:
        """(3, 3) ``R_y(yaw)``."""
        return rot_y(self.yaw)

    @property
    def E(self) -> np.ndarray:
        """(3, 3) essential matrix ``[t]x R``."""
        return essential_from_planar(self.yaw, self.t)


def essential_from_planar(yaw: float, t) -> np.ndarray:
    """(3, 3) ``E = [t]x R_y(yaw)`` so that ``x2^T E x1 = 0`` for ``X2 = R X1 + t``."""
    t = np.asarray(t, dtype=float)
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ rot_y(yaw)


# --------------------------------------------------------------- direction-plus-point

def heading_of_direction(v) -> float:
    """Heading (rad) of a horizontal direction ``v`` (3,) given in a levelled frame.

    REP 103 sense: 0 along +z (forward), positive to the left (-x). A world direction seen
    as ``v1`` in view 1 is ``R v1`` in view 2, so its heading drops by the motion's yaw.
    """
    v = np.asarray(v, dtype=float)
    return math.atan2(-v[0], v[2])


def manhattan_yaw_candidates(heading1: float, heading2: float) -> np.ndarray:
    """(4,) yaw candidates in [-pi, pi), sorted, from Manhattan headings seen in views 1 and 2.

    ``yaw = heading1 - heading2 + k pi/2`` (paper eq. 1 in our convention): a Manhattan frame
    fixes the heading only modulo 90 degrees.
    """
    base = float(wrap_angle(heading1 - heading2))
    return np.sort(wrap_angle(base + np.arange(4) * (np.pi / 2.0)))


def yaw_from_manhattan_headings(heading1: float, heading2: float, prior_yaw: float = 0.0) -> float:
    """Yaw (rad) from the two views' Manhattan headings, the candidate closest to ``prior_yaw``.

    ``prior_yaw`` is the expected motion (e.g. the previous step's yaw, or 0 for slow robots);
    the result is correct when the true yaw is within 45 degrees of it.
    """
    c = manhattan_yaw_candidates(heading1, heading2)
    return float(c[np.argmin(np.abs(wrap_angle(c - prior_yaw)))])


def relpose_planar_dirpoint_1pt(yaw: float, P1, P2) -> list[PlanarMotion]:
    """Direction-plus-point minimal solver (paper eq. 2): metric ``t`` from one 3-D match.

    ``yaw``: radians (from :func:`yaw_from_manhattan_headings`); ``P1``, ``P2``: (3,) the same
    point in levelled view 1 and 2 (metres). Returns ``[PlanarMotion(yaw, t)]`` with
    ``t = P2 - R P1`` and its y component (zero under planar motion) dropped, or ``[]`` for
    non-finite input.
    """
    P1 = np.asarray(P1, dtype=float).reshape(-1)
    P2 = np.asarray(P2, dtype=float).reshape(-1)
    if P1.shape != (3,) or P2.shape != (3,) or not (np.isfinite(P1).all() and np.isfinite(P2).all()
                                                   and math.isfinite(yaw)):
        return []
    t = P2 - rot_y(yaw) @ P1
    t[1] = 0.0
    return [PlanarMotion(float(wrap_angle(yaw)), t)]


# ------------------------------------------------------------------ 2-point homography

def homography_2pt_batch(x1a, x1b, x2a, x2b):
    """Vectorised 2-point planar homography solver over K samples.

    Inputs: (K, 2) float64 normalised coordinates of the sampled pair (a, b) in view 1
    (``x1a``, ``x1b``) and view 2 (``x2a``, ``x2b``).

    Returns ``(yaw, t, n, t_over_d, ok)``: ``yaw`` (K, 2) both roots of eq. 13-14; ``t``
    (K, 2, 3) unit translation directions with the sign for which the sampled points lie in
    front of camera 1 (``n . p1 > 0``, i.e. ``d > 0``; negate ``t`` and ``n`` for the other
    sign); ``n`` (K, 2, 3) unit plane normals in view 1; ``t_over_d`` (K, 2) ``|t| / d``
    (0 for pure rotation); ``ok`` (K,) False for degenerate or non-finite samples. Rows
    with ``ok`` False hold zeros, never NaN.
    """
    xa = x1a[:, 0]
    yaw, h1, h2, h3, h4, ok = _homography_yaws(x1a, x1b, x2a, x2b)
    c, s = np.cos(yaw), np.sin(yaw)
    z = lambda v: np.where(ok, v, 0.0)[:, None]  # noqa: E731 - keep NaN out of the algebra
    # M = H - R on the x-z block = tau n^T (rank one at a root of eq. 13)
    m00, m01 = z(h1) - c, z(h2) - s
    m10, m11 = z(h3) + s, z(h4) - c
    row0 = np.hypot(m00, m01)
    row1 = np.hypot(m10, m11)
    use0 = row0 >= row1
    nx = np.where(use0, m00, m10)
    nz = np.where(use0, m01, m11)
    nn = np.maximum(np.hypot(nx, nz), 1e-300)
    nx, nz = nx / nn, nz / nn
    # sign: the sampled point a in front of camera 1 => d = Z1 (n . p1) > 0
    flip = np.where(nx * xa[:, None] + nz < 0.0, -1.0, 1.0)
    nx, nz = nx * flip, nz * flip
    tau_x = m00 * nx + m01 * nz
    tau_z = m10 * nx + m11 * nz
    tn = np.hypot(tau_x, tau_z)
    moving = tn > 1e-9
    safe = np.where(moving, tn, 1.0)
    t = np.zeros(yaw.shape + (3,))
    t[..., 0] = np.where(moving, tau_x / safe, 0.0)
    t[..., 2] = np.where(moving, tau_z / safe, 0.0)
    n = np.zeros(yaw.shape + (3,))
    n[..., 0], n[..., 2] = nx, nz
    t = np.where(ok[:, None, None], t, 0.0)
    n = np.where(ok[:, None, None], n, 0.0)
    return wrap_angle(yaw), t, n, np.where(ok[:, None], tn, 0.0), ok


def _homography_yaws(x1a, x1b, x2a, x2b):
    """Both yaw roots (K, 2) of eq. 13-14 (zeros where degenerate), the homography entries
    ``h1..h4`` (K,) and ``ok`` (K,) of :func:`homography_2pt_batch`."""
    xa, ya = x1a[:, 0], x1a[:, 1]
    xb, yb = x1b[:, 0], x1b[:, 1]
    ua, va = x2a[:, 0], x2a[:, 1]
    ub, vb = x2b[:, 0], x2b[:, 1]
    dx = xa - xb
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ok = (np.abs(dx) > _EPS) & (np.abs(va) > _EPS) & (np.abs(vb) > _EPS)
        ok &= np.isfinite(dx) & np.isfinite(ya) & np.isfinite(yb) & np.isfinite(ua) & np.isfinite(ub)
        # eq. 10 divided through by y2: per point h3 x1 + h4 = w, h1 x1 + h2 = x2 w, w = Z2/Z1
        wa, wb = ya / va, yb / vb
        h3 = (wa - wb) / dx
        h4 = wa - h3 * xa
        h1 = (ua * wa - ub * wb) / dx
        h2 = ua * wa - h1 * xa
        # eq. 13: A cos + B sin = C  ->  yaw = phi +- acos(C / r)
        A = h1 + h4
        B = h2 - h3
        C = 1.0 + h1 * h4 - h2 * h3
        r = np.hypot(A, B)
        ok &= np.isfinite(r) & np.isfinite(C) & (r > _EPS)
        phi = np.arctan2(B, A)
        # |C / r| > 1 only through noise (double root for small t/d): clamp to the closest yaw
        delta = np.arccos(np.clip(np.where(ok, C / np.where(ok, r, 1.0), 1.0), -1.0, 1.0))
    yaw = np.stack([phi + delta, phi - delta], axis=1)
    return np.where(ok[:, None], yaw, 0.0), h1, h2, h3, h4, ok


def relpose_upright_planar_homography_2pt(x1, x2) -> list[PlanarMotion]:
    """2-point planar-homography minimal solver (paper Sec. 2.2), every solution.

    ``x1``, ``x2``: (2, 2) float64 normalised coordinates of two points in levelled view 1
    and 2. Returns up to four :class:`PlanarMotion` -- two yaw roots, each with ``(n, t)``
    and ``(-n, -t)`` (``t`` unit); the first of each pair has ``d > 0`` (sampled points in
    front of camera 1). Zero translation yields one ``pure_rotation`` solution per yaw.
    ``[]`` for degenerate or non-finite input.
    """
    x1 = np.asarray(x1, dtype=float)
    x2 = np.asarray(x2, dtype=float)
    if x1.shape != (2, 2) or x2.shape != (2, 2):
        return []
    yaw, t, n, tod, ok = homography_2pt_batch(x1[None, 0], x1[None, 1], x2[None, 0], x2[None, 1])
    if not ok[0]:
        return []
    out: list[PlanarMotion] = []
    for k in range(2):
        if k == 1 and abs(float(wrap_angle(yaw[0, 1] - yaw[0, 0]))) < 1e-12:
            break  # double root
        if tod[0, k] <= 1e-9:
            out.append(PlanarMotion(float(yaw[0, k]), np.zeros(3), None, 0.0, pure_rotation=True))
            continue
        for sgn in (1.0, -1.0):
            out.append(PlanarMotion(float(yaw[0, k]), sgn * t[0, k], sgn * n[0, k], float(tod[0, k])))
    return out
