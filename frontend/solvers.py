"""Minimal solvers for planar motion between two levelled views, and ground-truth problems.

Convention (pinned in :mod:`planar_vo.geometry`)
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
from dataclasses import dataclass, field

import numpy as np

from planar_vo.geometry import rot_y, rot_x, rot_z, wrap_angle

__all__ = [
    "PlanarMotion",
    "PlanarProblem",
    "heading_of_direction",
    "manhattan_yaw_candidates",
    "yaw_from_manhattan_headings",
    "relpose_planar_dirpoint_1pt",
    "relpose_upright_planar_homography_2pt",
    "homography_2pt_batch",
    "essential_from_planar",
    "make_planar_problem",
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
    yaw = np.where(ok[:, None], yaw, 0.0)
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


# ------------------------------------------------------------ ground-truth generators

@dataclass
class PlanarProblem:
    """A simulated two-view planar-motion problem with ground truth.

    ``x1``, ``x2``: (N, 2) float64 normalised coordinates as the estimator sees them (after
    levelling with the simulated tilt error, with image noise and outliers). ``P1``, ``P2``:
    (N, 3) float64 levelled 3-D points as the depth sensor sees them (tilt error and depth
    noise included; NaN where depth is missing). ``yaw`` (rad) and ``t`` (3,) metres: the
    true motion ``X2 = R_y(yaw) X1 + t``; ``t_dir`` its unit direction. ``inliers``: (N,)
    bool, False for injected outliers. ``tilt1``, ``tilt2``: (3, 3) the levelling errors
    applied to view 1 / 2 (``X_seen = tilt @ X_true``). ``X1``: (N, 3) true view-1 points.
    ``focal``: pixels. ``wall_heading1/2``: heading of a world wall normal in each view.
    """

    x1: np.ndarray
    x2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    yaw: float
    t: np.ndarray
    inliers: np.ndarray
    X1: np.ndarray
    tilt1: np.ndarray = field(default_factory=lambda: np.eye(3))
    tilt2: np.ndarray = field(default_factory=lambda: np.eye(3))
    focal: float = 1000.0
    wall_heading1: float = 0.0
    wall_heading2: float = 0.0

    @property
    def t_dir(self) -> np.ndarray:
        return self.t / np.linalg.norm(self.t)

    @property
    def R(self) -> np.ndarray:
        return rot_y(self.yaw)


def _tilt(pitch: float, roll: float) -> np.ndarray:
    """Levelling error in ``lev``: pitch about x (right), roll about z (forward)."""
    return rot_x(pitch) @ rot_z(roll)


def make_planar_problem(
    rng: np.random.Generator,
    n: int = 500,
    motion: str = "forward",
    yaw_range_deg: float = 15.0,
    noise_px: float = 0.0,
    focal: float = 1000.0,
    fov_deg: float = 50.0,
    scene_depth: float = 1.0,
    baseline: float = 0.15,
    ground_fraction: float = 0.5,
    camera_height: float = 0.2,
    tilt_error: tuple[float, float] = (0.0, 0.0),
    tilt_mode: str = "shared",
    outlier_ratio: float = 0.0,
    depth_noise: float = 0.0,
    yaw: float | None = None,
) -> PlanarProblem:
    """Simulate the paper's synthetic scene (Sec. 3.1) and a planar motion through it.

    ``n`` points visible in both views, ``ground_fraction`` of them on the floor
    ``camera_height`` below the camera, the rest above it, depths uniform in
    ``scene_depth * [0.5, 1.5]`` (mean ``scene_depth``), inside a ``fov_deg`` square field of
    view. View 2's centre moves by ``baseline * scene_depth`` along view 1's z
    (``"forward"``) or x (``"sideways"``) axis and turns by a yaw uniform in
    ``+-yaw_range_deg`` (or ``yaw`` radians if given). ``noise_px``: Gaussian image noise
    (pixels, at ``focal``). ``tilt_error``: (pitch, roll) standard deviations (rad) of the
    levelling error, drawn once for both views (``"shared"``: a miscalibrated mount) or per
    view (``"independent"``). ``outlier_ratio``: that fraction of view-2 observations
    replaced by random image points. ``depth_noise``: relative depth noise (sigma = this * Z^2
    / scene_depth) added to ``P1``/``P2`` along the viewing rays.
    """
    if motion not in ("forward", "sideways"):
        raise ValueError(f"motion must be 'forward' or 'sideways', got {motion!r}")
    if tilt_mode not in ("shared", "independent"):
        raise ValueError(f"tilt_mode must be 'shared' or 'independent', got {tilt_mode!r}")
    half = math.tan(math.radians(fov_deg) / 2.0)
    if yaw is None:
        yaw = math.radians(rng.uniform(-yaw_range_deg, yaw_range_deg))
    R = rot_y(yaw)
    b = baseline * scene_depth
    c2 = np.array([0.0, 0.0, b]) if motion == "forward" else np.array([b, 0.0, 0.0])
    t = -R @ c2  # camera-2 centre at c2 in view 1: X2 = R (X1 - c2)
    h = camera_height * scene_depth
    zlo, zhi = 0.5 * scene_depth, 1.5 * scene_depth

    n_ground = int(round(ground_fraction * n))
    pts: list[np.ndarray] = []
    for count, ground in ((n_ground, True), (n - n_ground, False)):
        got = 0
        while got < count:
            m = 4 * (count - got) + 16
            Z = rng.uniform(zlo, zhi, m)
            X = rng.uniform(-half, half, m) * Z
            Y = np.full(m, h) if ground else rng.uniform(-half, half, m) * Z
            P = np.stack([X, Y, Z], axis=1)
            Q = P @ R.T + t
            keep = (np.abs(Y / Z) <= half) & (Q[:, 2] > 0.1 * scene_depth)
            keep &= (np.abs(Q[:, 0] / np.maximum(Q[:, 2], 1e-9)) <= half)
            keep &= np.abs(Q[:, 1] / np.maximum(Q[:, 2], 1e-9)) <= half
            if not ground:
                keep &= Y < h - 1e-3 * scene_depth  # strictly above the floor
            P = P[keep][: count - got]
            pts.append(P)
            got += len(P)
    X1 = np.concatenate(pts)
    X2 = X1 @ R.T + t

    sp, sr = tilt_error
    E1 = _tilt(rng.normal(0.0, sp) if sp > 0 else 0.0, rng.normal(0.0, sr) if sr > 0 else 0.0)
    if tilt_mode == "shared":
        E2 = E1
    else:
        E2 = _tilt(rng.normal(0.0, sp) if sp > 0 else 0.0, rng.normal(0.0, sr) if sr > 0 else 0.0)
    S1 = X1 @ E1.T
    S2 = X2 @ E2.T
    x1 = S1[:, :2] / S1[:, 2:3]
    x2 = S2[:, :2] / S2[:, 2:3]
    if noise_px > 0:
        x1 = x1 + rng.normal(0.0, noise_px / focal, x1.shape)
        x2 = x2 + rng.normal(0.0, noise_px / focal, x2.shape)

    inliers = np.ones(n, dtype=bool)
    n_out = int(round(outlier_ratio * n))
    if n_out:
        idx = rng.choice(n, n_out, replace=False)
        inliers[idx] = False
        x2[idx] = rng.uniform(-half, half, (n_out, 2))

    def sensed(S, x):
        Z = S[:, 2]
        if depth_noise > 0:
            Z = Z + rng.normal(0.0, 1.0, len(Z)) * depth_noise * Z ** 2 / scene_depth
        return np.column_stack([x * Z[:, None], Z])

    P1 = sensed(S1, x1)
    P2 = sensed(S2, x2)
    if n_out:
        P2[~inliers, 2] = rng.uniform(zlo, zhi, n_out)
        P2[~inliers, :2] = x2[~inliers] * P2[~inliers, 2:3]

    # a wall normal (world) at a random heading, seen from both views
    wall = rot_y(rng.uniform(-np.pi, np.pi)) @ np.array([0.0, 0.0, 1.0])
    return PlanarProblem(
        x1=x1, x2=x2, P1=P1, P2=P2, yaw=float(yaw), t=t, inliers=inliers, X1=X1,
        tilt1=E1, tilt2=E2, focal=focal,
        wall_heading1=heading_of_direction(wall), wall_heading2=heading_of_direction(R @ wall),
    )
