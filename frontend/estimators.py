"""Robust planar-motion estimation: 2-point RANSAC (+ metric scale) and direction-plus-point.

Convention: levelled frames (x right, y down, z forward), ``X2 = R_y(yaw) X1 + t`` with
``t[1] = 0`` -- see :mod:`planar_vo.frontend.solvers`. Estimators are pure (arrays in,
``(motion, info)`` out), seeded through their options, and never raise on degenerate
data: they return ``motion = None`` (or a flagged motion) with ``info.status`` saying why.
Malformed input (wrong shape, non-finite image coordinates) raises ``ValueError``.

Scoring. The 2-point homography is exact only for the sampled pair (its virtual vertical
plane), so every hypothesis is scored against all points with the Sampson error of
``E = [t]x R`` (MSAC, truncated quadratic), with a chirality test (points in front of both
cameras) deciding the sign of ``t``; refinement minimises the same Sampson error.
With ``t = (tx, 0, tz)`` and ``R = R_y(yaw)`` the essential matrix is
``[[0, a, 0], [b, 0, c], [0, d, 0]]``, ``a = -tz``, ``b = tz cos + tx sin``,
``c = tz sin - tx cos``, ``d = tx``, hence (per point, normalised coordinates)

    r = x2^T E x1 = a x2 y1 + b x1 y2 + c y2 + d y1
    g = (a y1)^2 + (b x1 + c)^2 + (b y2)^2 + (a x2 + d)^2,    sampson^2 = r^2 / g,

and the depths triangulated in the horizontal plane have the signs of ``-(a x2 + d) / D``
(view 1) and ``(b x1 + c) / D`` (view 2), ``D = cos (x1 - x2) + sin (1 + x1 x2)``.

Levelling error. The levelled frames come from a mount calibration (or a floor fit) that
is never exact. A levelling error ``T = R_x(pitch) R_z(roll)`` shared by both views (a
miscalibrated mount) leaves the motion planar but tilts its plane: the images obey
``E' = T [t]x R_y T^T``, not ``[t]x R_y``. The misfit is worst for sideways motion under a
roll error -- the epipolar lines are horizontal and the error moves points vertically,
across them: translation ``T t`` gains a vertical part ``|t| roll`` and a yaw ``theta``
turns about an axis tilted by ``roll``, a vertical shift of ``~ theta roll`` (4.6 px at
15 deg yaw, 1 deg roll, f = 1000 px), both out of reach of any planar ``E``. Then no planar
model has inliers at a 1.5 px threshold, the consensus set shrinks to a structured
subset (e.g. the far floor) and its planar fit is off by many degrees. So after the
planar refinement the estimator also fits ``(yaw, t, pitch, roll)`` to the same images
(Sampson error of ``E'``, a weak Gaussian prior on the two tilt angles, inliers
re-selected at 4, 2, then 1 x the threshold as in LO-RANSAC so it can leave a subset-bound
start) and keeps it only when its MSAC score beats the planar one by more than a BIC
penalty for two parameters: with a well-levelled camera the planar result is returned
unchanged. The reported ``yaw``, ``t`` are those of the corrected (truly levelled) frame,
the correction is in ``info.extra["levelling_error"]``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.errors import ConfigError
from planar_vo.frontend.solvers import PlanarMotion, homography_2pt_batch
from planar_vo.core.geometry import rot_x, rot_z, wrap_angle

__all__ = [
    "TwoPointOptions",
    "MetricTwoPointOptions",
    "DirPointOptions",
    "EstimateInfo",
    "estimate_planar_motion_2pt",
    "estimate_planar_motion_2pt_metric",
    "estimate_planar_motion_dpp",
    "count_depth_inliers",
    "score_depth_matches",
    "PlanarTwoPointEstimator",
    "ransac",
    "levelling_tilt",
    "sampson_errors",
]

# info.status values
OK = "ok"
PURE_ROTATION = "pure_rotation"      # yaw fine, translation direction unobservable
TOO_FEW_POINTS = "too_few_points"
NO_MODEL = "no_model"                # no hypothesis with enough support
NO_DEPTH = "no_depth"                # metric estimator: no inlier with valid depth


def _check_options(opt) -> None:
    """Range checks shared by the options dataclasses (one-line ConfigError naming the field)."""
    name = type(opt).__name__
    if not 0.0 < opt.confidence < 1.0:
        raise ConfigError(f"{name}.confidence must be in (0, 1), got {opt.confidence}")
    for f in ("max_error_px", "focal_px", "pixel_sigma", "chi2", "depth_chi2", "levelling_sigma_deg"):
        v = getattr(opt, f, None)
        if v is not None and not v > 0:
            raise ConfigError(f"{name}.{f} must be > 0, got {v}")
    if getattr(opt, "max_error", None) is not None and not opt.max_error > 0:
        raise ConfigError(f"{name}.max_error must be > 0 (or None), got {opt.max_error}")
    for f in ("max_iterations", "batch_size"):
        v = getattr(opt, f, None)
        if v is not None and v < 1:
            raise ConfigError(f"{name}.{f} must be >= 1, got {v}")


@dataclass
class TwoPointOptions:
    """Options of :func:`estimate_planar_motion_2pt`.

    The Sampson threshold is ``max_error`` (normalised image units) if given, else
    ``max_error_px / focal_px``. ``focal_px`` defaults to a Kinect-like 525 px: set it from
    the camera intrinsics. RANSAC stops once ``confidence`` is reached (adaptive,
    between ``min_iterations`` and ``max_iterations`` samples, drawn ``batch_size`` at a
    time and solved together). ``seed`` seeds the sampler. ``refine_levelling``: also try
    a model with a levelling error shared by both views (prior standard deviation
    ``levelling_sigma_deg`` per tilt angle) and keep it when the data ask for it (see the
    module docstring); needs ``refine``.
    """

    max_error_px: float = 1.0
    focal_px: float = 525.0
    max_error: float | None = None
    confidence: float = 0.999
    min_iterations: int = 16
    max_iterations: int = 2000
    batch_size: int = 32
    min_inliers: int = 6
    refine: bool = True
    max_refine_iterations: int = 15
    refine_levelling: bool = True
    levelling_sigma_deg: float = 2.0
    seed: int = 0

    def __post_init__(self):
        _check_options(self)

    def threshold(self) -> float:
        """Sampson threshold in normalised image units."""
        return float(self.max_error) if self.max_error is not None else self.max_error_px / self.focal_px


@dataclass
class MetricTwoPointOptions(TwoPointOptions):
    """Options of :func:`estimate_planar_motion_2pt_metric`.

    Depth noise model (per view): ``sigma(Z) = depth_sigma_const + depth_sigma_quad * Z^2``
    metres (structured-light / stereo sensors); image noise ``pixel_sigma`` pixels at
    ``focal_px``. A 3-D match supports the scale when its horizontal residual is within
    ``depth_chi2`` (chi-square, 2 dof) of that model. ``refine_levelling`` is off by default
    here (the front-end's odometry keeps its planar behaviour); when on and the levelling-error
    model wins, images and depths are corrected alike before the metric refinement.
    """

    refine_levelling: bool = False
    depth_sigma_const: float = 0.002
    depth_sigma_quad: float = 0.002
    pixel_sigma: float = 0.5
    depth_chi2: float = 9.21
    #: Wheeled bases do not slide sideways: with ``mount_se2`` (the planar mount, pose of the
    #: levelled camera in base_link, :func:`planar_vo.core.geometry.mount_se2`) and
    #: ``lateral_slip`` > 0 the refinement also asks the base_link step to follow its own
    #: heading, ``y - x tan(theta / 2) = 0`` (the chord of a constant-curvature arc), at
    #: ``lateral_floor_m + lateral_slip * |t|`` metres. It pins the far-feature ambiguity
    #: between yaw and sideways translation (:func:`estimate_planar_motion_2pt_metric`).
    mount_se2: tuple[float, float, float] | None = None
    lateral_slip: float = 0.0
    lateral_floor_m: float = 0.001
    #: With the wheeled prior: a step the images take for a pure rotation is fitted on the
    #: chord of its heading change itself (:func:`_wheeled_refine`; the slip enters the
    #: covariance only) -- for one frame interval (a motion over several frames, whose
    #: heading weaved, is no single arc). False: a pure rotation goes without the prior.
    #: Fits whose direction the images see take it as a soft row either way.
    follow_heading: bool = False

    def __post_init__(self):
        super().__post_init__()
        if not (self.lateral_slip >= 0 and self.lateral_floor_m > 0):
            raise ConfigError(f"MetricTwoPointOptions.lateral_slip must be >= 0 and lateral_floor_m > 0, "
                              f"got {self.lateral_slip}, {self.lateral_floor_m}")


@dataclass
class DirPointOptions:
    """Options of :func:`estimate_planar_motion_dpp` (1-point RANSAC on ``t``, yaw known).

    Inlier test: horizontal 3-D residual ``|P2 - R P1 - t|`` (x, z) against the depth
    noise model ``sigma(Z) = depth_sigma_const + depth_sigma_quad * Z^2`` of both views plus
    the lateral image noise ``pixel_sigma / focal_px * Z``, chi-square ``chi2`` (2 dof).
    """

    depth_sigma_const: float = 0.002
    depth_sigma_quad: float = 0.002
    pixel_sigma: float = 0.5
    focal_px: float = 525.0
    chi2: float = 9.21
    confidence: float = 0.999
    max_iterations: int = 200
    min_inliers: int = 3
    seed: int = 0
    #: Narrow the refit's gate to the scatter the RANSAC inliers show along z when it is at
    #: most half the modelled variance (:func:`_scatter_gate`); False: the model's variances alone.
    scatter_gate: bool = True

    def __post_init__(self):
        _check_options(self)


@dataclass
class EstimateInfo:
    """What an estimator reports besides the motion.

    ``inliers``: (N,) bool. ``status``: ``"ok"``, ``"pure_rotation"`` (translation not
    observable; the motion's yaw is still valid), ``"too_few_points"``, ``"no_model"``,
    ``"no_depth"``. ``iterations``: RANSAC samples drawn. ``cost``: final sum of squared
    residuals over the inliers (Sampson, normalised units^2, for the 2-point estimator;
    whitened for the others). ``covariance``: (3, 3) over (yaw, t_x, t_z) where provided.
    ``refine_iterations``: Gauss-Newton/LM steps taken. ``scale_inliers``: (N,) bool, 3-D
    matches that fixed the metric scale (metric estimator). ``extra``:
    ``"rotation_only_median_error"`` (2-point estimators; normalised units) and, when the
    levelling-error model won, ``"levelling_error"`` ``(pitch, roll)`` radians, the
    estimated shared levelling error ``T = R_x(pitch) R_z(roll)`` with ``x_seen ~ T X``.
    """

    inliers: np.ndarray
    status: str = OK
    iterations: int = 0
    cost: float = float("nan")
    num_inliers: int = 0
    refine_iterations: int = 0
    covariance: np.ndarray | None = None
    scale_inliers: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.status in (OK, PURE_ROTATION)


# ----------------------------------------------------------------------------- input

def _as_points(name: str, a, dim: int, allow_nan: bool = False) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {arr.shape}")
    if not allow_nan and not np.isfinite(arr).all():
        bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        raise ValueError(f"{name} {arr.shape} has non-finite rows {bad[:5].tolist()}"
                         f"{'...' if len(bad) > 5 else ''}")
    return arr


def _check_same(n1: str, a: np.ndarray, n2: str, b: np.ndarray) -> None:
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"{n1} {a.shape} and {n2} {b.shape} must have the same number of rows")


def _ransac_needed(confidence: float, inlier_ratio: float, sample_size: int) -> float:
    w = inlier_ratio ** sample_size
    if w <= 0.0:
        return math.inf
    if w >= 1.0:
        return 0.0
    return math.log(1.0 - confidence) / math.log1p(-w)


# ------------------------------------------------------------------- Sampson geometry

def _coeffs(c, s, tx, tz):
    """Essential-matrix entries (a, b, c, d) of ``[t]x R_y`` (see module docstring)."""
    return -tz, tz * c + tx * s, tz * s - tx * c, tx


def sampson_errors(yaw: float, t, x1, x2) -> np.ndarray:
    """(N,) Sampson errors (normalised units) of matches ``x1``, ``x2`` (N, 2) under ``E = [t]x R_y(yaw)``."""
    t = np.asarray(t, dtype=float)
    a, b, cc, d = _coeffs(math.cos(yaw), math.sin(yaw), t[0], t[2])
    X1, Y1, X2, Y2 = x1[:, 0], x1[:, 1], x2[:, 0], x2[:, 1]
    r = a * X2 * Y1 + b * X1 * Y2 + cc * Y2 + d * Y1
    g = (a * Y1) ** 2 + (b * X1 + cc) ** 2 + (b * Y2) ** 2 + (a * X2 + d) ** 2
    return np.abs(r) / np.sqrt(np.maximum(g, 1e-300))


class _Matches:
    """Per-point features shared by scoring and refinement (computed once)."""

    def __init__(self, x1: np.ndarray, x2: np.ndarray):
        self.X1, self.Y1 = x1[:, 0].copy(), x1[:, 1].copy()
        self.X2, self.Y2 = x2[:, 0].copy(), x2[:, 1].copy()
        # r = [a, b, c, d] . F ; D = [cos, sin] . G
        self.F = np.stack([self.X2 * self.Y1, self.X1 * self.Y2, self.Y2, self.Y1])
        self.G = np.stack([self.X1 - self.X2, 1.0 + self.X1 * self.X2])
        self.Y1sq, self.Y2sq = self.Y1 ** 2, self.Y2 ** 2

    def subset(self, mask: np.ndarray) -> "_Matches":
        m = _Matches.__new__(_Matches)
        for k in ("X1", "Y1", "X2", "Y2", "Y1sq", "Y2sq"):
            setattr(m, k, getattr(self, k)[mask])
        m.F, m.G = self.F[:, mask], self.G[:, mask]
        return m


def _score(m: _Matches, c, s, tx, tz, thr2: float, parallax_tol: float):
    """Score H hypotheses (arrays (H,)) against all N matches in one array expression.

    Returns ``(score (H,), sign (H,) +-1, ok (H, N) inlier mask for the chosen sign)``.
    MSAC: sum of min(e^2, thr^2), points failing chirality counted at thr^2.
    """
    a, b, cc, d = _coeffs(c, s, tx, tz)
    r = np.stack([a, b, cc, d], axis=1) @ m.F                       # (H, N)
    u = b[:, None] * m.X1 + cc[:, None]                              # (E x1)_2, ~ Z2 sign * D
    v = a[:, None] * m.X2 + d[:, None]                               # (E^T x2)_2, ~ -Z1 sign * D
    g = (a * a)[:, None] * m.Y1sq + (b * b)[:, None] * m.Y2sq + u * u + v * v
    e2 = r * r / np.maximum(g, 1e-300)
    fp, fn = _front_masks(m, c, s, u, v, parallax_tol)
    return _msac(e2, fp, fn, thr2)


def _front_masks(m: _Matches, c, s, u, v, parallax_tol: float):
    """Chirality (H, N) masks: the point is in front of both cameras for ``+t`` / for ``-t``
    (``u``, ``v`` as in :func:`_score`); points with too little parallax pass both."""
    D = np.stack([c, s], axis=1) @ m.G
    uD, vD = u * D, v * D
    low = np.abs(D) < parallax_tol
    return ((uD > 0) & (vD < 0)) | low, ((uD < 0) & (vD > 0)) | low


def _msac(e2, front_pos, front_neg, thr2: float):
    """MSAC score (H,), sign of ``t`` (H,) and inlier mask (H, N) from squared errors (H, N)."""
    inl = e2 < thr2
    front_pos, front_neg = inl & front_pos, inl & front_neg
    sign = np.where(front_pos.sum(-1) >= front_neg.sum(-1), 1.0, -1.0)
    ok = np.where((sign > 0)[..., None], front_pos, front_neg)
    return np.where(ok, e2, thr2).sum(-1), sign, ok


def _sampson(m: _Matches, c: float, s: float, tx: float, tz: float, derivs=None):
    """Sampson residuals (M,) of the planar essential matrix with ``cos/sin yaw = c, s`` and
    translation ``(tx, 0, tz)``, and their Jacobian (M, K): ``derivs(a, b, c', d)`` gives the
    derivatives ``(da, db, dc', dd)`` of the coefficients (see ``_coeffs``) per parameter."""
    a, b, cc, d = _coeffs(c, s, tx, tz)
    r = a * m.F[0] + b * m.F[1] + cc * m.F[2] + d * m.F[3]
    u = b * m.X1 + cc
    v = a * m.X2 + d
    g = a * a * m.Y1sq + b * b * m.Y2sq + u * u + v * v
    sg = np.sqrt(np.maximum(g, 1e-300))
    e = r / sg
    if derivs is None:
        return e, None
    cols = derivs(a, b, cc, d)
    J = np.empty((len(e), len(cols)))
    for k, (da, db, dc, dd) in enumerate(cols):
        dr = da * m.F[0] + db * m.F[1] + dc * m.F[2] + dd * m.F[3]
        dg = 2.0 * (a * da * m.Y1sq + u * (m.X1 * db + dc) + b * db * m.Y2sq + v * (m.X2 * da + dd))
        J[:, k] = (dr - 0.5 * e * dg / sg) / sg
    return e, J


def _sampson_residuals_2(m: _Matches, theta: float, alpha: float, jac: bool):
    """Sampson residuals (M,) and Jacobian (M, 2) w.r.t. (yaw, alpha), t = (sin a, 0, cos a)."""
    # d/dtheta: (da, db, dc, dd) = (0, -c', b, 0);  d/dalpha: (d, c', -b, -a)
    derivs = (lambda a, b, cc, d: ((0.0, -cc, b, 0.0), (d, cc, -b, -a))) if jac else None
    return _sampson(m, math.cos(theta), math.sin(theta), math.sin(alpha), math.cos(alpha), derivs)


def _levenberg_marquardt(fun, p0: np.ndarray, max_iter: int):
    """Small dense LM: ``fun(p, jac) -> (residuals, J)``. Returns (p, cost, iterations, J)."""
    p = np.array(p0, dtype=float)
    e, J = fun(p, True)
    cost = float(e @ e)
    lam = 1e-4
    it = 0
    for it in range(1, max_iter + 1):
        A = J.T @ J
        gvec = J.T @ e
        improved = False
        for _ in range(8):
            try:
                step = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), gvec)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            pn = p + step
            en, Jn = fun(pn, True)
            cn = float(en @ en)
            if cn <= cost:
                improved = True
                rel = (cost - cn) / max(cost, 1e-300)
                p, e, J, cost = pn, en, Jn, cn
                lam = max(lam * 0.1, 1e-12)
                break
            lam *= 10.0
        if not improved or rel < 1e-12 or np.abs(step).max() < 1e-12:
            break
    return p, cost, it, J


# ------------------------------------------------------------- shared levelling error

def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


_EX, _EZ = _skew((1.0, 0.0, 0.0)), _skew((0.0, 0.0, 1.0))


def levelling_tilt(pitch: float, roll: float) -> np.ndarray:
    """(3, 3) levelling error ``T = R_x(pitch) R_z(roll)``: a point ``X`` of the true levelled
    frame is seen at ``T X`` (the convention of :func:`~planar_vo.frontend.solvers.make_planar_problem`)."""
    return rot_x(pitch) @ rot_z(roll)


def _tilted_essential(p: np.ndarray):
    """``E' = T [t]x R_y(yaw) T^T`` (3, 3) and ``dE'/dp`` (4, 3, 3), ``p = (yaw, alpha, pitch, roll)``,
    ``t = (sin alpha, 0, cos alpha)``."""
    th, al, pitch, roll = (float(v) for v in p)
    c, s = math.cos(th), math.sin(th)
    Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    dRy = np.array([[-s, 0.0, c], [0.0, 0.0, 0.0], [-c, 0.0, -s]])
    tx = _skew((math.sin(al), 0.0, math.cos(al)))
    E0 = tx @ Ry
    Rx, Rz = rot_x(pitch), rot_z(roll)
    T = Rx @ Rz
    dTp, dTr = _EX @ T, Rx @ _EZ @ Rz
    E0Tt, TE0 = E0 @ T.T, T @ E0
    D = np.stack([T @ (tx @ dRy) @ T.T,
                  T @ (_skew((math.cos(al), 0.0, -math.sin(al))) @ Ry) @ T.T,
                  dTp @ E0Tt + TE0 @ dTp.T,
                  dTr @ E0Tt + TE0 @ dTr.T])
    return TE0 @ T.T, D


def _sampson_tilted(x1h: np.ndarray, x2h: np.ndarray, p: np.ndarray, w_prior: float, jac: bool):
    """Sampson residuals of ``E'`` (M,) on homogeneous points ``x1h``, ``x2h`` (3, M), then the
    prior's two residuals ``w_prior * (pitch, roll)``; Jacobian (M + 2, 4) over ``p``."""
    E, D = _tilted_essential(p)
    l1, l2 = E @ x1h, E.T @ x2h
    r = np.einsum("in,in->n", x2h, l1)
    sg = np.sqrt(np.maximum(l1[0] ** 2 + l1[1] ** 2 + l2[0] ** 2 + l2[1] ** 2, 1e-300))
    e = np.concatenate([r / sg, w_prior * np.asarray(p[2:4], dtype=float)])
    if not jac:
        return e, None
    m = x1h.shape[1]
    dl1 = D @ x1h                                                     # (4, 3, M)
    dl2 = np.transpose(D, (0, 2, 1)) @ x2h
    dr = np.einsum("in,kin->kn", x2h, dl1)
    dg = 2.0 * (l1[0] * dl1[:, 0] + l1[1] * dl1[:, 1] + l2[0] * dl2[:, 0] + l2[1] * dl2[:, 1])
    J = np.zeros((m + 2, 4))
    J[:m] = ((dr - 0.5 * e[:m] * dg / sg) / sg).T
    J[m, 2] = J[m + 1, 3] = w_prior
    return e, J


def _untilt(x: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(N, 2) normalised coordinates seen through the levelling error ``T`` mapped to the true
    levelled frame (``x ~ T^T x_seen``)."""
    xh = np.column_stack([x, np.ones(len(x))]) @ T                  # rows: (T^T x)^T
    return xh[:, :2] / xh[:, 2:3]


def _tilted_errors(x1, x2, x1h, x2h, p, parallax_tol: float):
    """Squared Sampson errors (N,) of ``E'`` in the images as seen, and the chirality masks
    (N,) for ``+t`` / ``-t`` in the corrected frame, of one levelling-error hypothesis ``p``."""
    E, _ = _tilted_essential(p)
    l1, l2 = E @ x1h, E.T @ x2h
    r = np.einsum("in,in->n", x2h, l1)
    e2 = r * r / np.maximum(l1[0] ** 2 + l1[1] ** 2 + l2[0] ** 2 + l2[1] ** 2, 1e-300)
    T = levelling_tilt(p[2], p[3])
    X1, X2 = _untilt(x1, T)[:, 0], _untilt(x2, T)[:, 0]
    c, s = math.cos(p[0]), math.sin(p[0])
    a, b, cc, d = _coeffs(c, s, math.sin(p[1]), math.cos(p[1]))
    D = c * (X1 - X2) + s * (1.0 + X1 * X2)                          # as in _front_masks
    uD, vD = (b * X1 + cc) * D, (a * X2 + d) * D
    low = np.abs(D) < parallax_tol
    return e2, ((uD > 0) & (vD < 0)) | low, ((uD < 0) & (vD > 0)) | low


#: LO-RANSAC style schedule of the levelling refinement: inlier threshold multipliers.
_LEVELLING_SCHEDULE = (4.0, 2.0, 1.0, 1.0, 1.0)


def _refine_levelling(x1, x2, theta: float, alpha: float, thr: float, planar_score: float,
                      opt: TwoPointOptions):
    """Fit ``(yaw, alpha, pitch, roll)`` from a planar start; see the module docstring.

    Stops as soon as a round does not beat ``planar_score`` (MSAC at ``thr``): a level
    camera costs one round. Returns ``(p (4,), msac score, inliers (N,) bool, LM iterations)``.
    """
    x1h = np.vstack([x1.T, np.ones(len(x1))])
    x2h = np.vstack([x2.T, np.ones(len(x2))])
    thr2, par_tol = thr * thr, 2.0 * thr
    # prior sd in normalised image units: the threshold is ~3 sigma of the image noise
    w_prior = (thr / 3.0) / math.radians(opt.levelling_sigma_deg)
    p = np.array([theta, alpha, 0.0, 0.0])
    e2, fp, fn = _tilted_errors(x1, x2, x1h, x2h, p, par_tol)   # fp, fn always match p
    prev, its_total = None, 0
    for k in _LEVELLING_SCHEDULE:
        _, sign, sel = _msac(e2, fp, fn, k * k * thr2)
        if sign < 0:
            p[1] += math.pi
            fp, fn = fn, fp
        if sel.sum() < max(opt.min_inliers, 4) or (k == 1.0 and np.array_equal(sel, prev)):
            break
        prev = sel
        a1, a2 = x1h[:, sel], x2h[:, sel]
        fun = lambda q, jac: _sampson_tilted(a1, a2, q, w_prior, jac)  # noqa: E731
        p, _cost, its, _J = _levenberg_marquardt(fun, p, opt.max_refine_iterations)
        its_total += its
        e2, fp, fn = _tilted_errors(x1, x2, x1h, x2h, p, par_tol)
        if _msac(e2, fp, fn, thr2)[0] >= planar_score:
            break
    score, sign, inl = _msac(e2, fp, fn, thr2)
    if sign < 0:
        p[1] += math.pi
    return p, float(score), inl, its_total


# ------------------------------------------------------------------- 2-point RANSAC core

def _homography_hypotheses(x1: np.ndarray, x2: np.ndarray, idx: np.ndarray):
    """Default minimal solver for the RANSAC: (K, 2) sample indices -> yaw (H,), t (H, 3)."""
    i, j = idx[:, 0], idx[:, 1]
    # a point keeps its side of the horizon (Y2 = Y1, Z > 0): cheap pre-filter
    keep = (x1[i, 1] * x2[i, 1] > 0.0) & (x1[j, 1] * x2[j, 1] > 0.0)
    i, j = i[keep], j[keep]
    yaw, t, _n, _tod, ok = homography_2pt_batch(x1[i], x1[j], x2[i], x2[j])
    return yaw[ok].reshape(-1), t[ok].reshape(-1, 3)


class PlanarTwoPointEstimator:
    """The 2-point planar RANSAC problem, shaped like PoseLib's estimators: ``sample_size``,
    :meth:`generate` (minimal solver), :meth:`score` (MSAC on the Sampson error with a
    chirality test) and :meth:`refine` (Sampson least squares, then the levelling-error
    model); :func:`ransac` drives any of them.

    ``x1``, ``x2``: (N, 2) float64 levelled normalised coordinates. A variant (another
    minimal solver, e.g. PoseLib's upright-planar ones in ``planar-vo bench solvers``) is a
    subclass overriding :meth:`generate` and ``sample_size``; scoring and refinement stay
    the same, so the variants compare on equal terms.
    """

    sample_size = 2

    def __init__(self, x1: np.ndarray, x2: np.ndarray, opt: TwoPointOptions):
        self.x1, self.x2, self.opt = x1, x2, opt
        self.n = x1.shape[0]
        self.thr = opt.threshold()
        self.thr2 = self.thr * self.thr
        self.parallax_tol = 2.0 * self.thr
        self.matches = _Matches(x1, x2)

    def sample(self, rng: np.random.Generator, k: int) -> np.ndarray:
        """(k, sample_size) indices of distinct points."""
        n = self.n
        if self.sample_size == 2:
            i = rng.integers(0, n, k)
            return np.stack([i, (i + rng.integers(1, n, k)) % n], axis=1)
        return np.argsort(rng.random((k, n)), axis=1)[:, :self.sample_size]

    def generate(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hypotheses of samples ``idx``: yaw (H,) rad and unit t (H, 3), either sign."""
        return _homography_hypotheses(self.x1, self.x2, idx)

    def score(self, yaw: np.ndarray, t: np.ndarray):
        """``(score (H,), sign of t (H,), inlier masks (H, N))`` of hypotheses."""
        return _score(self.matches, np.cos(yaw), np.sin(yaw), t[:, 0], t[:, 2], self.thr2, self.parallax_tol)

    def _score_one(self, theta: float, alpha: float):
        """:meth:`score` of one model ``(theta, alpha)`` (yaw, heading of t)."""
        return _score(self.matches, np.array([math.cos(theta)]), np.array([math.sin(theta)]),
                      np.array([math.sin(alpha)]), np.array([math.cos(alpha)]), self.thr2, self.parallax_tol)

    def refine(self, theta: float, alpha: float, inl: np.ndarray):
        """Sampson refinement of ``(theta, alpha)`` (yaw, translation heading) over inliers
        re-selected while they change; then the levelling-error model when it pays.
        Returns ``(theta, alpha, inliers, tilt (pitch, roll) or None, iterations)``."""
        opt, m = self.opt, self.matches
        iterations = 0
        rounds = 3  # refine, re-select inliers, refine again while they change
        for rnd in range(rounds):
            sub = m.subset(inl)
            fun = lambda p, jac: _sampson_residuals_2(sub, p[0], p[1], jac)  # noqa: E731
            p, _cost, its, _J = _levenberg_marquardt(fun, np.array([theta, alpha]), opt.max_refine_iterations)
            iterations += its
            theta, alpha = float(p[0]), float(p[1])
            if rnd == rounds - 1:
                break  # the reported inliers are the ones the fit used
            _sc, sign, okm = self._score_one(theta, alpha)
            if sign[0] < 0:
                alpha += math.pi
            new = okm[0]
            if np.array_equal(new, inl) or new.sum() < max(opt.min_inliers, 2):
                break
            inl = new
        tilt = None
        if opt.refine_levelling:
            theta, alpha, inl, tilt, its = self._refine_levelling(theta, alpha, inl)
            iterations += its
        return theta, alpha, inl, tilt, iterations

    def _refine_levelling(self, theta: float, alpha: float, inl: np.ndarray):
        planar_score = float(self._score_one(theta, alpha)[0][0])
        p, lev_score, lev_inl, its = _refine_levelling(self.x1, self.x2, theta, alpha, self.thr, planar_score,
                                                       self.opt)
        # BIC penalty of the two tilt angles, image noise sigma ~ thr / 3
        if (lev_score + 2.0 * math.log(self.n) * self.thr2 / 9.0 < planar_score
                and lev_inl.sum() >= max(self.opt.min_inliers, 2)):
            return float(p[0]), float(p[1]), lev_inl, (float(p[2]), float(p[3])), its
        return theta, alpha, inl, None, its


def ransac(est: PlanarTwoPointEstimator, opt: TwoPointOptions):
    """Adaptive RANSAC over ``est``: batches of samples until the confidence is reached.
    Returns ``(yaw, (tx, tz), inlier mask (N,) or None, samples drawn)`` of the best hypothesis."""
    rng = np.random.default_rng(opt.seed)
    n = est.n
    best_score, best_yaw, best_t = math.inf, 0.0, (0.0, 1.0)  # t as (tx, tz)
    best_ok = None
    drawn = 0
    needed = max(opt.min_iterations, 1)
    while drawn < min(needed, opt.max_iterations):
        k = max(int(min(opt.batch_size, opt.max_iterations - drawn, max(needed - drawn, 1))), 1)
        idx = est.sample(rng, k)
        drawn += k
        yaw, t = est.generate(idx)
        if len(yaw) == 0:
            continue
        score, sign, okm = est.score(yaw, t)
        best = int(np.argmin(score))
        if score[best] < best_score:
            best_score, best_yaw = float(score[best]), float(yaw[best])
            best_t = (float(sign[best] * t[best, 0]), float(sign[best] * t[best, 2]))
            best_ok = okm[best]
            needed = max(_ransac_needed(opt.confidence, best_ok.sum() / n, est.sample_size), opt.min_iterations)
    return best_yaw, best_t, best_ok, drawn


def _ransac_2pt(x1: np.ndarray, x2: np.ndarray, opt: TwoPointOptions, estimator=PlanarTwoPointEstimator):
    """RANSAC + refinement with ``estimator`` (a :class:`PlanarTwoPointEstimator` class).
    Returns ``(yaw, t_dir (3,), info)``; yaw None when no model was found."""
    est = estimator(x1, x2, opt)
    info = EstimateInfo(inliers=np.zeros(est.n, dtype=bool))
    if est.n < est.sample_size:
        info.status = TOO_FEW_POINTS
        return None, None, info
    best_yaw, best_t, best_ok, info.iterations = ransac(est, opt)
    if best_ok is None or best_ok.sum() < max(opt.min_inliers, 2):
        info.status = NO_MODEL
        return None, None, info
    theta, alpha, inl = best_yaw, math.atan2(best_t[0], best_t[1]), best_ok
    refine_iters, tilt = 0, None  # tilt: (pitch, roll) of the levelling-error model when it wins
    if opt.refine:
        theta, alpha, inl, tilt, refine_iters = est.refine(theta, alpha, inl)
    t_dir = np.array([math.sin(alpha), 0.0, math.cos(alpha)])
    theta = float(wrap_angle(theta))
    _fill_info(info, x1, x2, inl, theta, alpha, t_dir, tilt, est.thr)
    info.refine_iterations = refine_iters
    return theta, t_dir, info


def _fill_info(info: EstimateInfo, x1, x2, inl, theta: float, alpha: float, t_dir, tilt, thr: float) -> None:
    """Inliers, cost and the pure-rotation test of the final model."""
    if tilt is None:
        e = sampson_errors(theta, t_dir, x1[inl], x2[inl])
        u1, u2 = x1[inl], x2[inl]
    else:
        info.extra["levelling_error"] = tilt
        e, _ = _sampson_tilted(np.vstack([x1[inl].T, np.ones(inl.sum())]),
                               np.vstack([x2[inl].T, np.ones(inl.sum())]),
                               np.array([theta, alpha, *tilt]), 0.0, False)
        e = e[:-2]
        T = levelling_tilt(*tilt)
        u1, u2 = _untilt(x1[inl], T), _untilt(x2[inl], T)
    info.inliers = inl
    info.num_inliers = int(inl.sum())
    info.cost = float(e @ e)
    # pure rotation: x2 ~ R x1 explains the inliers (in the corrected frame), so t is unobservable
    with np.errstate(divide="ignore", invalid="ignore"):
        rx, ry = _rotation_residuals(theta, u1, u2)
        rot_err = np.nan_to_num(np.hypot(rx, ry), nan=np.inf)
    info.extra["rotation_only_median_error"] = float(np.median(rot_err))
    if np.median(rot_err) < thr:
        info.status = PURE_ROTATION


def estimate_planar_motion_2pt(x1, x2, options: TwoPointOptions | None = None,
                               estimator: type[PlanarTwoPointEstimator] = PlanarTwoPointEstimator):
    """Planar motion from 2-D matches: 2-point RANSAC + Sampson refinement (paper Sec. 2.2, 3.1).

    ``x1``, ``x2``: (N, 2) float64 normalised coordinates of the same points in the levelled
    frames of view 1 and 2 (points anywhere, not only on the ground).
    Returns ``(motion, info)``: ``motion`` a :class:`PlanarMotion` with ``yaw`` (rad) and unit
    ``t`` (3,), ``t[1] = 0``, such that ``X2 = R_y(yaw) X1 + s t`` for some ``s > 0``, or
    ``None`` when ``info.status`` is ``"too_few_points"`` / ``"no_model"``; ``info`` an
    :class:`EstimateInfo` (``inliers`` (N,) bool, ``iterations``, ``cost``, ``status``).
    With ``status == "pure_rotation"`` the yaw is valid and ``t`` is not observable.
    ``estimator``: the RANSAC problem (a subclass for another minimal solver).
    """
    opt = options or TwoPointOptions()
    x1 = _as_points("x1", x1, 2)
    x2 = _as_points("x2", x2, 2)
    _check_same("x1", x1, "x2", x2)
    theta, t_dir, info = _ransac_2pt(x1, x2, opt, estimator)
    if theta is None:
        return None, info
    return PlanarMotion(theta, t_dir, pure_rotation=info.status == PURE_ROTATION), info


# ------------------------------------------------------------------ metric 2-point path

def _depth_sigma(Z: np.ndarray, const: float, quad: float) -> np.ndarray:
    return const + quad * Z * Z


def _metric_residuals(m: _Matches, w_img: float, Q1: np.ndarray, Q2: np.ndarray, inv_sig: np.ndarray,
                      p: np.ndarray, jac: bool):
    """Whitened residuals of (yaw, tx, tz): Sampson (M,) / sigma_img, then 3-D x and z (K,) each."""
    theta, tx, tz = p
    c, s = math.cos(theta), math.sin(theta)
    tn = math.hypot(tx, tz)
    parts, jparts = [], []
    if tn > 1e-12 and len(m.X1):
        # d/dtheta (0, -c', b, 0); d/dtx (0, s, -c, 1); d/dtz (-1, c, s, 0)
        derivs = (lambda a, b, cc, d: ((0.0, -cc, b, 0.0), (0.0, s, -c, 1.0), (-1.0, c, s, 0.0))) if jac else None
        e, J = _sampson(m, c, s, tx, tz, derivs)
        parts.append(e * w_img)
        if jac:
            jparts.append(J * w_img)
    # 3-D: (P2 - R P1 - t)_{x,z} / sigma
    rx = c * Q1[:, 0] + s * Q1[:, 2]
    rz = -s * Q1[:, 0] + c * Q1[:, 2]
    ex = (Q2[:, 0] - rx - tx) * inv_sig
    ez = (Q2[:, 2] - rz - tz) * inv_sig
    parts += [ex, ez]
    if jac:
        Jx = np.zeros((len(ex), 3))
        Jz = np.zeros((len(ez), 3))
        Jx[:, 0] = -rz * inv_sig
        Jx[:, 1] = -inv_sig
        Jz[:, 0] = rx * inv_sig
        Jz[:, 2] = -inv_sig
        jparts += [Jx, Jz]
    e = np.concatenate(parts)
    return e, (np.vstack(jparts) if jac else None)


def _base_lateral(p: np.ndarray, m_base_lev: np.ndarray) -> float:
    """Sideways motion (m) of the base_link step of the levelled motion ``p = (yaw, t_x,
    t_z)`` off the chord of its heading change: ``y - x tan(theta / 2)`` (zero for a wheeled
    base on a constant-curvature arc)."""
    x, y = _lev_step_to_base(p, m_base_lev)
    return y - x * math.tan(0.5 * float(p[0]))


def _arc_motion(q: np.ndarray, m_base_lev: np.ndarray) -> np.ndarray:
    """The levelled motion ``(yaw, t_x, t_z)`` (3,) of a base_link step that follows its
    heading: ``q = (yaw, rho)``, ``rho`` metres along the chord of the heading change (a
    constant-curvature arc; negative backwards). Inverse of the mapping in
    :func:`_base_lateral`: ``b = R_m p + (I - R_th) m`` solved for the levelled step ``p``."""
    th, rho = float(q[0]), float(q[1])
    c, s = math.cos(th), math.sin(th)
    mx, my, mpsi = float(m_base_lev[0]), float(m_base_lev[1]), float(m_base_lev[2])
    qx = rho * math.cos(0.5 * th) - (1.0 - c) * mx - s * my
    qy = rho * math.sin(0.5 * th) + s * mx - (1.0 - c) * my
    cm, sm = math.cos(mpsi), math.sin(mpsi)
    px, py = cm * qx + sm * qy, -sm * qx + cm * qy
    return np.array([th, -s * px + c * py, -c * px - s * py])


def _arc_jacobian(q: np.ndarray, m_base_lev: np.ndarray) -> np.ndarray:
    """(3, 2) derivative of :func:`_arc_motion` by ``q = (yaw, rho)`` (central differences)."""
    h, G = 1e-7, np.empty((3, 2))
    for k in range(2):
        d = np.zeros(2)
        d[k] = h
        G[:, k] = (_arc_motion(q + d, m_base_lev) - _arc_motion(q - d, m_base_lev)) / (2 * h)
    return G


def _chord_length(p: np.ndarray, m_base_lev: np.ndarray) -> float:
    """The length (m) along the chord of its heading change of the base_link step of the
    levelled motion ``p = (yaw, t_x, t_z)``: :func:`_arc_motion`'s ``rho``."""
    x, y = _lev_step_to_base(p, m_base_lev)
    return float(x * math.cos(0.5 * p[0]) + y * math.sin(0.5 * p[0]))


def _wheeled_refine(fun, p0: np.ndarray, m_base_lev: np.ndarray, max_iter: int) -> tuple[np.ndarray, int]:
    """``(p (3,), iterations)``: ``fun`` (:func:`_metric_residuals` of ``p = (yaw, t_x,
    t_z)``) minimised over the steps that follow their heading (:func:`_arc_motion`), from
    ``p0``'s yaw and its length along the chord."""
    def g(q, jac):
        e, J = fun(_arc_motion(q, m_base_lev), jac)
        return e, (J @ _arc_jacobian(q, m_base_lev) if jac else None)
    q, _, its, _ = _levenberg_marquardt(g, np.array([p0[0], _chord_length(p0, m_base_lev)]), max_iter)
    return _arc_motion(q, m_base_lev), its


def _wheeled_image_yaw(m: _Matches, w_img: float, p: np.ndarray, m_base_lev: np.ndarray, max_iter: int) -> float:
    """The yaw (rad) the image matches ``m`` alone give a step that follows its heading,
    at the length of the fitted ``p = (yaw, t_x, t_z)`` (which enters only through the
    camera's lever arm): what a few depths may have bent the joint fit away from."""
    rho = _chord_length(p, m_base_lev)
    none = np.zeros((0, 3))

    def g(q, jac):
        arc = np.array([q[0], rho])
        e, J = _metric_residuals(m, w_img, none, none, np.zeros(0), _arc_motion(arc, m_base_lev), jac)
        return e, (J @ _arc_jacobian(arc, m_base_lev)[:, :1] if jac else None)
    q, _, _, _ = _levenberg_marquardt(g, np.array([p[0]]), max_iter)
    return float(q[0])


def _lev_step_to_base(p: np.ndarray, m_base_lev: np.ndarray) -> tuple[float, float]:
    """The base_link step ``(x, y)`` (m) of the levelled motion ``p = (yaw, t_x, t_z)``."""
    # closed form of lev_step_to_base_step(levelled_motion_to_pose(...)): the levelled step
    # (-(s tx + c tz), c tx - s tz, th) conjugated by the mount, R_m p + (I - R_th) m (called
    # ~100 times per refinement by _base_lateral, so no arrays)
    th, tx, tz = float(p[0]), float(p[1]), float(p[2])
    c, s = math.cos(th), math.sin(th)
    px, py = -(s * tx + c * tz), c * tx - s * tz
    mx, my, mpsi = float(m_base_lev[0]), float(m_base_lev[1]), float(m_base_lev[2])
    cm, sm = math.cos(mpsi), math.sin(mpsi)
    return cm * px - sm * py + (1.0 - c) * mx + s * my, sm * px + cm * py - s * mx + (1.0 - c) * my


def _with_lateral_prior(fun, m_base_lev: np.ndarray, sigma: float):
    """``fun`` (:func:`_metric_residuals`) with one more row: :func:`_base_lateral` / sigma."""
    def g(p, jac):
        e, J = fun(p, jac)
        e = np.append(e, _base_lateral(p, m_base_lev) / sigma)
        if jac:
            h, row = 1e-7, np.empty(3)
            for k in range(3):
                d = np.zeros(3)
                d[k] = h
                row[k] = (_base_lateral(p + d, m_base_lev) - _base_lateral(p - d, m_base_lev)) / (2 * h * sigma)
            J = np.vstack([J, row])
        return e, J
    return g


def _metric_covariance(J: np.ndarray, e: np.ndarray, n_depth: int, n_prior: int, p: np.ndarray) -> np.ndarray:
    """Covariance (3, 3) of the metric 2-point fit ``p`` from its Jacobian ``J`` and
    whitened residuals ``e``: image rows, then ``2 n_depth`` depth rows, then ``n_prior``."""
    n_img = len(e) - 2 * n_depth - n_prior
    return _blocked_covariance(_image_rows_at_scale(J, n_img, n_depth, p), e, n_img, 3, n_prior)


def _image_rows_at_scale(J: np.ndarray, n_img: int, n_depth: int, p: np.ndarray) -> np.ndarray:
    """``J`` (rows, 3) with its first ``n_img`` (Sampson) rows' translation columns taken
    at the length the depths allow, ``|t| + sigma_r``, not at the estimate's ``|t|``.

    The Sampson rows are scale-free: they see the direction of ``t``, and in metres their
    derivative is that direction's divided by ``|t|``. Where the images barely see the
    translation the fit can end near ``t = 0`` in any direction, and the covariance then
    claimed the direction to a fraction of a millimetre in metres; with the wheeled base's
    sideways prior it pinned the length too (a tuning hall's 11 mm steps measured as 1 mm
    at a stated 0.5 mm forward sigma). ``sigma_r``: the length's sigma from the ``n_depth``
    points' depth rows (the ``2 n_depth`` rows after the image rows) alone."""
    tn = math.hypot(p[1], p[2])
    if n_img == 0 or n_depth == 0 or tn <= 0:
        return J
    Jd = J[n_img:n_img + 2 * n_depth, 1:]
    d = np.array([p[1], p[2]]) / tn
    try:
        sigma_r = math.sqrt(max(float(d @ np.linalg.solve(Jd.T @ Jd, d)), 0.0))
    except np.linalg.LinAlgError:
        return J
    J = J.copy()
    J[:n_img, 1:] *= tn / (tn + sigma_r)
    return J


def _blocked_covariance(J: np.ndarray, e: np.ndarray, n_img: int, dof_params: int, n_prior: int = 0) -> np.ndarray:
    """``(sum_b J_b^T J_b / f_b)^-1`` over the image rows (the first ``n_img``; none when
    the fit has no Sampson terms) and the depth rows, whitened residuals ``e``. The image
    rows keep the whole fit's reduced chi-square (the yaw they fix is calibrated so); the
    depth rows take their own, never below 1. One factor for both let the many image
    residuals, smaller than their model, shrink the depth noise model the scale rests on:
    the metric steps' forward errors were 1.9x their stated sigma on the tuning seeds. As
    in the direction-plus-point covariance, a few agreeing depths never claim more than
    their noise model gives. (Flooring the image rows too widened the yaw sigma the
    weak-scale check reads and let 5-6-depth steps 5-7 cm off through on a tuning hall;
    their own factor alone made pure-rotation yaws on a textureless hall 8 sigma off.)"""
    m = len(e) - n_prior
    f_all = float(e[:m] @ e[:m]) / (m - dof_params) if m > dof_params else 1.0
    A = np.zeros((J.shape[1], J.shape[1]))
    for rows, depth in ((slice(0, n_img), False), (slice(n_img, m), True)):
        Jb, eb = J[rows], e[rows]
        if len(eb) == 0:
            continue
        f = max(float(eb @ eb) / max(len(eb) - dof_params, 1), 1.0) if depth else f_all
        A += Jb.T @ Jb / max(f, 1e-12)
    # prior rows (last n_prior) state their own sigma
    A += J[m:].T @ J[m:]
    try:
        return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(A)


def estimate_planar_motion_2pt_metric(x1, x2, P1, P2, options: MetricTwoPointOptions | None = None):
    """Metric planar motion: 2-point RANSAC for yaw and direction, scale from depth, joint refinement.

    ``x1``, ``x2``: (N, 2) float64 normalised levelled coordinates (finite). ``P1``, ``P2``:
    (N, 3) float64 levelled 3-D points (metres) of the same matches, NaN (or Z <= 0) where
    depth is invalid. Returns ``(motion, info)``: ``motion.t`` metric (metres), ``X2 = R X1 +
    t``; ``info.inliers`` (N,) bool (epipolar inliers), ``info.scale_inliers`` (N,) bool,
    ``info.covariance`` (3, 3) over (yaw, t_x, t_z) from the whitened inlier residuals.
    ``motion`` is None when the 2-point stage fails or no inlier has valid depth. With
    ``options.refine_levelling`` and a shared levelling error found, the scale and the joint
    refinement work in the corrected frame (images and 3-D points rotated by ``T^T``). A fit
    that the sideways prior (``options.lateral_slip``) pins near ``t = 0``
    (:func:`_collapsed`) is refitted as a pure rotation (:func:`_rotation_then_depths`):
    ``info.status`` says ``"pure_rotation"`` and ``info.extra["direction_collapsed_m"]`` the
    length it started at.
    """
    opt = options or MetricTwoPointOptions()
    x1 = _as_points("x1", x1, 2)
    x2 = _as_points("x2", x2, 2)
    P1 = _as_points("P1", P1, 3, allow_nan=True)
    P2 = _as_points("P2", P2, 3, allow_nan=True)
    _check_same("x1", x1, "x2", x2)
    _check_same("x1", x1, "P1", P1)
    _check_same("x1", x1, "P2", P2)
    theta, t_dir, info = _ransac_2pt(x1, x2, opt)
    if theta is None:
        return None, info
    if "levelling_error" in info.extra:
        # the levelling-error model won: fix scale and refine in the corrected frame
        T = levelling_tilt(*info.extra["levelling_error"])
        x1, x2, P1, P2 = _untilt(x1, T), _untilt(x2, T), P1 @ T, P2 @ T
    # the yaw of the image matches alone, before the depths join the fit (a caller can
    # check that a few depths did not bend it)
    info.extra["epipolar_yaw"] = float(theta)
    fit = _metric_fit(theta, t_dir, info, x1, x2, P1, P2, opt)
    on_heading = opt.follow_heading and info.status == PURE_ROTATION  # fitted by _wheeled_refine
    if fit is not None and fit[2] and (info.status == OK or on_heading) and _collapsed(fit[0], fit[1], on_heading):
        # The images' direction and the wheeled base's heading disagree, and the fit met
        # them at t ~ 0, pinned there by both (on a held-out hall 17 mm steps measured as
        # 0 +- 1.5 mm, 2-point status ok between pure rotations): a pure rotation the
        # direction test let through, its yaw bent by the sideways direction. Fitted on the
        # heading, a step near t = 0 moves the camera sideways by the lever arm alone, along
        # the epipolar lines of the rotation, which then no longer see the yaw (8 mm steps
        # of a 30 Hz tuning hall so fitted at ~1 mm erred 0.15-0.18 deg).
        info.extra["direction_collapsed_m"] = float(math.hypot(fit[1][0], fit[1][2]))
        return _rotation_then_depths(theta, info, x1, x2, P1, P2, opt)
    if fit is None:
        info.status = NO_DEPTH
        return None, info
    p = fit[0]
    motion = PlanarMotion(float(wrap_angle(p[0])), np.array([p[1], 0.0, p[2]]),
                          pure_rotation=info.status == PURE_ROTATION)
    return motion, info


def _rotation_then_depths(theta: float, info: EstimateInfo, x1, x2, P1, P2, opt: MetricTwoPointOptions):
    """A pure rotation's motion: the yaw that maps the epipolar inliers by rotation alone
    (:func:`_rotation_only_yaw`, from ``theta``), then the translation the depths give at
    that yaw (eq. 2, :func:`estimate_planar_motion_dpp`, the yaw's sigma propagated).
    ``(motion, info)`` with ``info.status`` ``"pure_rotation"``, or ``(None, info)`` with
    ``"no_depth"`` when too few depths agree."""
    inl = info.inliers
    yaw, sigma = _rotation_only_yaw(x1[inl], x2[inl], theta, opt.pixel_sigma / opt.focal_px)
    info.extra["epipolar_yaw"] = yaw  # the images' own yaw under the rotation model
    dopt = DirPointOptions(depth_sigma_const=opt.depth_sigma_const, depth_sigma_quad=opt.depth_sigma_quad,
                           pixel_sigma=opt.pixel_sigma, focal_px=opt.focal_px, chi2=opt.depth_chi2, seed=opt.seed)
    motion, dinfo = estimate_planar_motion_dpp(P1[inl], P2[inl], yaw, dopt, yaw_sigma=sigma)
    if motion is None:
        info.status = NO_DEPTH
        return None, info
    info.status = PURE_ROTATION
    info.covariance = dinfo.covariance
    info.scale_inliers = np.zeros_like(inl)
    info.scale_inliers[np.flatnonzero(inl)[dinfo.inliers]] = True
    return PlanarMotion(float(wrap_angle(motion.yaw)), motion.t, pure_rotation=True), info


def _rotation_residuals(theta: float, u1: np.ndarray, u2: np.ndarray, jac: bool = False):
    """Residuals ``(r_x, r_y)`` (M,) each of the rotation model ``u2 ~ R_y(theta) u1``
    (normalised levelled points (M, 2)), and with ``jac`` their derivatives by ``theta``."""
    c, s = math.cos(theta), math.sin(theta)
    X1, Y1 = u1[:, 0], u1[:, 1]
    zr = -s * X1 + c
    rx, ry = (c * X1 + s) / zr - u2[:, 0], Y1 / zr - u2[:, 1]
    if not jac:
        return rx, ry
    dz = -c * X1 - s
    return rx, ry, (zr * zr - (c * X1 + s) * dz) / (zr * zr), -Y1 * dz / (zr * zr)


def _rotation_only_yaw(u1: np.ndarray, u2: np.ndarray, theta: float, sigma_img: float) -> tuple[float, float]:
    """``(yaw, sigma)`` (rad) of ``u2 ~ R_y(yaw) u1`` (normalised levelled points (M, 2)) by
    Gauss-Newton from ``theta``: the rotation model of the pure-rotation test. ``sigma``
    from the residuals' reduced chi-square, at least ``sigma_img`` (normalised units) per
    residual. A forward step's parallax is radial and leaves this yaw unbiased; the
    2-point yaw of a fit that read it as a sideways translation was 0.2-0.3 deg off on a
    held-out hall, this one 0.01-0.03 deg."""
    for _ in range(10):
        rx, ry, jx, jy = _rotation_residuals(theta, u1, u2, jac=True)
        r, J = np.concatenate([rx, ry]), np.concatenate([jx, jy])
        step = -float(J @ r) / float(J @ J)
        theta += step
        if abs(step) < 1e-12:
            break
    s2 = max(float(r @ r) / max(len(r) - 1, 1), sigma_img * sigma_img)
    return float(theta), math.sqrt(s2 / float(J @ J))


def _metric_fit(theta: float, t_dir, info: EstimateInfo, x1, x2, P1, P2, opt: MetricTwoPointOptions):
    """Scale from depth and the joint refinement of :func:`estimate_planar_motion_2pt_metric`:
    ``(p (3,) = (yaw, t_x, t_z), t0 (3,) the depths' start, prior used)``, or None when no
    inlier's depth agrees. Fills ``info``'s refinement fields, covariance and scale inliers."""
    scale = _metric_scale(theta, t_dir, info, P1, P2, opt)
    if scale is None:
        return None
    t0, Q1, Q2, inv_sig, scale_inl = scale
    w_img = 1.0 / (opt.pixel_sigma / opt.focal_px)
    inl = info.inliers
    # Sampson terms stay well defined for small non-zero t (they are scale invariant)
    sub = _Matches(x1[inl], x2[inl])
    fun = lambda p, jac: _metric_residuals(sub, w_img, Q1, Q2, inv_sig, p, jac)  # noqa: E731
    p, its, fun, n_prior = _refine_metric(fun, np.array([theta, t0[0], t0[2]]), t0, info, sub, w_img, opt)
    e, J = fun(p, True)
    info.refine_iterations += its
    info.cost = float(e @ e)
    info.covariance = _metric_covariance(J, e, len(Q1), n_prior, p)
    info.scale_inliers = scale_inl
    return p, t0, n_prior > 0


def _refine_metric(fun, p0: np.ndarray, t0: np.ndarray, info: EstimateInfo, sub: _Matches, w_img: float,
                   opt: MetricTwoPointOptions):
    """The joint refinement of :func:`_metric_fit` from ``p0 = (yaw, t_x, t_z)``: ``(p (3,),
    iterations, the residual function with the wheeled prior's row if any, rows of prior)``."""
    if opt.lateral_slip <= 0 or opt.mount_se2 is None or not (opt.follow_heading or info.status == OK):
        p, _, its, _ = _levenberg_marquardt(fun, p0, opt.max_refine_iterations)
        return p, its, fun, 0
    # Far features at one depth leave a valley in which yaw and sideways translation trade
    # off (dt_x = -Z dyaw): image rows and depth rows alike. A wheeled base's step follows
    # its heading, which picks the valley's true end (without it, on a low-texture tuning
    # hall: yaw errors of 0.28-0.55 deg, the translation 28-63 deg off the heading).
    m = np.asarray(opt.mount_se2, dtype=float)
    if opt.follow_heading and info.status == PURE_ROTATION:
        # A pure rotation over one frame interval: fitted on the heading itself
        # (:func:`_wheeled_refine`), the slip in the covariance only. A soft prior let its
        # scale-free image rows shrink the step (22 of 23 mm lost on a tuning hall), so pure
        # rotations went without one, and where their images took a forward step's radial
        # parallax for a rotation (corners on one side) the yaw erred by +0.05 deg a step
        # for 60 steps of a held-out hall (seed 8203; on the heading 0.01). Fits whose
        # direction the images see keep the soft row below (fitted on the heading too, the
        # tuning halls drifted further: hall_s3700 0.10 -> 0.53 %, hall_s3704 0.74 -> 1.29 %).
        p, its = _wheeled_refine(fun, p0, m, opt.max_refine_iterations)
        # the images' own yaw under the same model, for the callers' bend test
        info.extra["epipolar_yaw"] = _wheeled_image_yaw(sub, w_img, p, m, opt.max_refine_iterations)
        sigma = opt.lateral_floor_m + opt.lateral_slip * math.hypot(p[1], p[2])
        info.extra["lateral_prior_m"] = sigma
        return p, its, _with_lateral_prior(fun, m, sigma), 1
    # the images see the direction: a soft row
    sigma = opt.lateral_floor_m + opt.lateral_slip * math.hypot(t0[0], t0[2])
    info.extra["lateral_prior_m"] = sigma
    fun = _with_lateral_prior(fun, m, sigma)
    p, _, its, _ = _levenberg_marquardt(fun, p0, opt.max_refine_iterations)
    return p, its, fun, 1


#: A fit with the sideways prior whose translation ends below this fraction of the depths'
#: start has met the prior at t ~ 0 (:func:`_collapsed`).
_COLLAPSE_RATIO = 0.25


def _collapsed(p: np.ndarray, t0: np.ndarray, on_heading: bool) -> bool:
    """True when the refined translation ``p[1:]`` is below ``_COLLAPSE_RATIO`` of the length
    the depths started it at (``t0`` (3,)): the scale-free image rows pin the direction, the
    sideways prior the heading, and when the two disagree only ``t = 0`` satisfies both.
    Fitted on the heading (``on_heading``), also when the camera moves more sideways than
    forward: a turn on the spot, whose lever-arm motion runs along the rotation's epipolar
    lines, where the image rows no longer see the yaw."""
    sideways = on_heading and abs(p[2]) < abs(p[1])
    return sideways or math.hypot(p[1], p[2]) < _COLLAPSE_RATIO * math.hypot(t0[0], t0[2])


def _metric_scale(theta: float, t_dir, info: EstimateInfo, P1, P2, opt: MetricTwoPointOptions):
    """The metric translation ``t0`` (3,) from the depths of the epipolar inliers, with the
    points that agree on it: ``(t0, Q1, Q2, 1 / sigma, scale inlier mask (N,))``, or None
    when no inlier has a valid depth or none agrees."""
    inl = info.inliers
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(P1).all(1) & np.isfinite(P2).all(1) & (P1[:, 2] > 0) & (P2[:, 2] > 0)
    dep = inl & valid
    if not dep.any():
        return None
    c, s = math.cos(theta), math.sin(theta)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    Q1, Q2 = P1[dep], P2[dep]
    sig = np.sqrt(_depth_sigma(Q1[:, 2], opt.depth_sigma_const, opt.depth_sigma_quad) ** 2
                  + _depth_sigma(Q2[:, 2], opt.depth_sigma_const, opt.depth_sigma_quad) ** 2
                  + (opt.pixel_sigma / opt.focal_px) ** 2 * (Q1[:, 2] ** 2 + Q2[:, 2] ** 2))
    diff = Q2 - Q1 @ R.T
    if info.status == PURE_ROTATION:
        # direction unobservable: robust (median) metric t from depth alone
        t0 = np.array([np.median(diff[:, 0]), 0.0, np.median(diff[:, 2])])
    else:
        t0 = np.median(diff @ t_dir) * t_dir
    res = np.hypot(diff[:, 0] - t0[0], diff[:, 2] - t0[2]) / sig
    keep = res * res < opt.depth_chi2
    if not keep.any():
        return None
    scale_inl = np.zeros_like(inl)
    scale_inl[np.flatnonzero(dep)[keep]] = True
    return t0, Q1[keep], Q2[keep], 1.0 / sig[keep], scale_inl


# ------------------------------------------------------------------ direction-plus-point

def estimate_planar_motion_dpp(P1, P2, yaw: float, options: DirPointOptions | None = None,
                               yaw_sigma: float = math.radians(1.0), depth_scale=None):
    """Direction-plus-point estimation (paper Sec. 2.1): yaw known, 1-point RANSAC on ``t``.

    ``P1``, ``P2``: (N, 3) float64 levelled 3-D points (metres) of matched features in views 1
    and 2 (rows with NaN or Z <= 0 are ignored); ``yaw``: radians, from the Manhattan
    alignment (:func:`~planar_vo.frontend.solvers.yaw_from_manhattan_headings`);
    ``yaw_sigma``: its standard deviation (rad). ``depth_scale``: ``(s1 (N,), s2 (N,))`` factors on each view's modelled
    depth variance (a depth refined by a plane, :mod:`planar_vo.frontend.pointplanes`), or None.
    Returns ``(motion, info)``: ``motion.t`` metric with ``X2 = R_y(yaw) X1 + t``; ``t`` is the
    noise-weighted least-squares mean of ``P2 - R P1`` (x, z) over the inliers.
    ``info.covariance`` (3, 3) over (yaw, t_x, t_z): ``yaw_sigma^2``, the inlier scatter of
    ``t`` (reduced chi-square scaled) and the first-order effect of the yaw error on ``t``.
    """
    opt = options or DirPointOptions()
    P1 = _as_points("P1", P1, 3, allow_nan=True)
    P2 = _as_points("P2", P2, 3, allow_nan=True)
    _check_same("P1", P1, "P2", P2)
    if not math.isfinite(yaw):
        raise ValueError(f"yaw must be finite, got {yaw}")
    N = P1.shape[0]
    info = EstimateInfo(inliers=np.zeros(N, dtype=bool))
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(P1).all(1) & np.isfinite(P2).all(1) & (P1[:, 2] > 0) & (P2[:, 2] > 0)
    idx = np.flatnonzero(valid)
    if len(idx) < max(opt.min_inliers, 1):
        info.status = TOO_FEW_POINTS
        return None, info
    s1, s2 = (np.ones(N), np.ones(N)) if depth_scale is None else map(np.asarray, depth_scale)
    rx, rz, dx, dz, vx, vz = _dpp_candidates(P1[idx], P2[idx], yaw, opt, (s1[idx], s2[idx]))
    best_ok, info.iterations = _dpp_ransac(dx, dz, vx, vz, opt)
    if best_ok is None or best_ok.sum() < opt.min_inliers:
        info.status = NO_MODEL
        return None, info
    tx, tz, inl = _dpp_refit(dx, dz, vx, vz, best_ok, opt)
    info.num_inliers, info.cost, info.covariance = _dpp_covariance(rx, rz, dx, dz, vx, vz, inl, tx, tz, yaw_sigma)
    mask = np.zeros(N, dtype=bool)
    mask[idx[inl]] = True
    info.inliers = mask
    return PlanarMotion(float(wrap_angle(yaw)), np.array([tx, 0.0, tz])), info


def count_depth_inliers(P1, P2, motion: PlanarMotion, options: DirPointOptions | None = None,
                        depth_scale=None) -> int:
    """How many 3-D matches a planar motion explains: the direction-plus-point inlier test
    (``|P2 - R P1 - t|`` (x, z) against the depth and image noise model, ``options.chi2``)
    applied to a given ``motion`` (``X2 = R_y(yaw) X1 + t``).

    ``P1``, ``P2``: (N, 3) float64 levelled points (metres; rows with NaN or Z <= 0 are
    ignored); ``depth_scale``: ``(s1 (N,), s2 (N,))`` or None, as for
    :func:`estimate_planar_motion_dpp`. Scores competing hypotheses on the same data.
    """
    return score_depth_matches(P1, P2, motion, options, depth_scale)[0]


def score_depth_matches(P1, P2, motion: PlanarMotion, options: DirPointOptions | None = None,
                        depth_scale=None) -> tuple[int, float]:
    """``(inliers, cost)`` of a planar motion on the 3-D matches: the inlier count of
    :func:`count_depth_inliers` and the truncated chi-square sum (each match's whitened
    squared residual, capped at ``options.chi2``; MSAC). Arguments as there. The cost
    still ranks two motions whose counts tie (a yaw a degree apart moves points 2 m ahead
    by 3.5 cm, which can stay inside the gate: 3 of the 18 one-degree jumps of
    ``tests/test_drift_free_yaw.py`` tied on the count)."""
    opt = options or DirPointOptions()
    P1 = _as_points("P1", P1, 3, allow_nan=True)
    P2 = _as_points("P2", P2, 3, allow_nan=True)
    _check_same("P1", P1, "P2", P2)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(P1).all(1) & np.isfinite(P2).all(1) & (P1[:, 2] > 0) & (P2[:, 2] > 0)
    if not valid.any():
        return 0, 0.0
    N = P1.shape[0]
    s1, s2 = (np.ones(N), np.ones(N)) if depth_scale is None else map(np.asarray, depth_scale)
    _, _, dx, dz, vx, vz = _dpp_candidates(P1[valid], P2[valid], float(motion.yaw), opt, (s1[valid], s2[valid]))
    t = np.asarray(motion.t, float)
    r2 = (dx - t[0]) ** 2 / vx + (dz - t[2]) ** 2 / vz
    return int((r2 < opt.chi2).sum()), float(np.minimum(r2, opt.chi2).sum())


def _dpp_candidates(Q1: np.ndarray, Q2: np.ndarray, yaw: float, opt: DirPointOptions,
                    depth_scale: tuple[np.ndarray, np.ndarray]):
    """Per-match translation candidates ``d = P2 - R P1`` (x, z) and their variances:
    ``(rx, rz, dx, dz, vx, vz)``, each (M,), ``(rx, rz)`` the rotated view-1 points; each
    view's modelled depth variance is scaled by ``depth_scale`` ``(s1, s2)``."""
    c, s = math.cos(yaw), math.sin(yaw)
    rx = c * Q1[:, 0] + s * Q1[:, 2]
    rz = -s * Q1[:, 0] + c * Q1[:, 2]
    dx, dz = Q2[:, 0] - rx, Q2[:, 2] - rz          # per-match t candidates (eq. 2, our sign)
    # Per axis: a point X = x Z (x normalised) has var(Z) = sigma_Z^2 along the ray and
    # var(X) = (sigma_px / f)^2 Z^2 + x^2 sigma_Z^2 across it, so depth noise lands on t_z
    # and barely on t_x (one isotropic variance overstated t_x and understated t_z).
    vz1 = _depth_sigma(Q1[:, 2], opt.depth_sigma_const, opt.depth_sigma_quad) ** 2 * depth_scale[0]
    vz2 = _depth_sigma(Q2[:, 2], opt.depth_sigma_const, opt.depth_sigma_quad) ** 2 * depth_scale[1]
    pix = (opt.pixel_sigma / opt.focal_px) ** 2
    vx = pix * (Q1[:, 2] ** 2 + Q2[:, 2] ** 2) + (Q1[:, 0] / Q1[:, 2]) ** 2 * vz1 + (Q2[:, 0] / Q2[:, 2]) ** 2 * vz2
    vz = vz1 + vz2 + pix * (Q1[:, 0] ** 2 + Q2[:, 0] ** 2)
    return rx, rz, dx, dz, vx, vz


def _dpp_ransac(dx, dz, vx, vz, opt: DirPointOptions):
    """1-point RANSAC on the candidates: ``(inlier mask of the best hypothesis or None, drawn)``.

    Each hypothesis ``t_k = d_k`` is uncertain too: the residual is tested against
    ``var_i + var_k``. Small sets: every match is a hypothesis; large ones: adaptive
    random batches.
    """
    rng = np.random.default_rng(opt.seed)
    M = len(dx)
    best_score, best_ok, drawn = math.inf, None, 0
    needed = 1.0
    while drawn < min(max(needed, 1.0), opt.max_iterations, M):
        hyp = np.arange(M) if M <= 64 else rng.integers(0, M, 64)
        drawn += len(hyp)
        d2 = ((dx[None, :] - dx[hyp, None]) ** 2 / (vx[None, :] + vx[hyp, None])
              + (dz[None, :] - dz[hyp, None]) ** 2 / (vz[None, :] + vz[hyp, None]))
        ok = d2 < opt.chi2
        score = np.where(ok, d2, opt.chi2).sum(1)
        k = int(np.argmin(score))
        if score[k] < best_score:
            best_score, best_ok = float(score[k]), ok[k]
            needed = _ransac_needed(opt.confidence, best_ok.sum() / M, 1)
    return best_ok, drawn


def _dpp_refit(dx, dz, vx, vz, inl, opt: DirPointOptions):
    """Weighted means of the inliers' candidates, inliers re-selected against them:
    ``(tx, tz, inliers)``. With ``opt.scatter_gate`` the gate is first narrowed to the
    scatter the RANSAC inliers show about their weighted medians (:func:`_scatter_gate`)."""
    gz = 1.0
    if opt.scatter_gate:
        gz, inl = _scatter_gate(dx, dz, vx, vz, inl, opt)
    for _ in range(3):
        wx, wz = 1.0 / vx[inl], 1.0 / vz[inl]
        tx = float((wx * dx[inl]).sum() / wx.sum())
        tz = float((wz * dz[inl]).sum() / wz.sum())
        new = (dx - tx) ** 2 / vx + (dz - tz) ** 2 / (gz * vz) < opt.chi2
        if new.sum() < opt.min_inliers or np.array_equal(new, inl):
            break
        inl = new
    return tx, tz, inl


def _scatter_gate(dx, dz, vx, vz, inl, opt: DirPointOptions):
    """``(gz, inliers)``: the factor ``gz`` on the candidates' modelled depth variances
    ``vz`` that the inliers ``inl`` show along z -- the squared MAD of their normalised
    residuals about their weighted median, pooled with the model at :data:`DPP_MODEL_DOF` as
    :func:`_pooled_scale` does -- and the candidates within ``opt.chi2`` of the medians at
    those variances (``inl`` when fewer than ``opt.min_inliers`` are). Where ``gz`` exceeds
    :data:`_SCATTER_GATE_MAX` nothing changes: ``(1, inl)``.

    The modelled depth noise grows with Z^2, and the sensor often reads far points far better
    than it says. A near point then outweighs several far ones, and a corner that slid with the
    camera passes the gate at the model's variances. On an unseen low-texture L (lturn_s9700),
    five points 3.5-3.9 m away agreed on -29 mm to within 2 mm, at stated sigmas of 16-20 mm.
    One floor point at 1.9 m read -0.3 mm, 3 of its 9.5 mm sigmas from the weighted mean, and
    took 26 % of the weight: the step came out 21.7 mm. A median is not pulled by it (-27.5 mm),
    and at the variances narrowed to the scatter about it (a factor 0.35 here) that point is
    4.8 sigmas out, beyond the 3 of the gate. Across the track (x) the variance is the pixel
    noise's, not the depth's, and stays as modelled.
    """
    n = int(inl.sum())
    cx = _weighted_median(dx[inl], 1.0 / vx[inl])
    cz = _weighted_median(dz[inl], 1.0 / vz[inl])
    r = (dz[inl] - cz) / np.sqrt(vz[inl])
    gz = _pooled_scale(n * (1.4826 * float(np.median(np.abs(r)))) ** 2, n)
    if gz > _SCATTER_GATE_MAX:
        return 1.0, inl
    new = (dx - cx) ** 2 / vx + (dz - cz) ** 2 / (gz * vz) < opt.chi2
    return gz, (new if new.sum() >= opt.min_inliers else inl)


#: :func:`_scatter_gate` narrows the gate only when the inliers scatter along z by at most
#: this share of the modelled variance. Where they scatter about as modelled, a median
#: centre and a gate a little narrower only pick another subset of the same noise: on a
#: held-out low-texture hall (tests/test_estimators.py, frame 227 of the two-point
#: collapse) a factor of 0.72 put the step 21 mm sideways (4.6 of its sigmas).
_SCATTER_GATE_MAX = 0.5


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value (float) at which the cumulative ``weights`` (K,) of the sorted ``values``
    (K,) first reach half their total."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return float(values[order][int(np.searchsorted(cum, 0.5 * cum[-1]))])


#: Degrees of freedom the depth noise model counts for when the inliers' own scatter
#: scales the direction-plus-point covariance (:func:`_pooled_scale`).
DPP_MODEL_DOF = 4.0


def _pooled_scale(chi2: float, dof: int) -> float:
    """Variance factor from an inlier chi-square with ``dof`` degrees of freedom, pooled
    with the noise model (factor 1) at :data:`DPP_MODEL_DOF`. With a factor never below 1
    the direction-plus-point forward sigmas were twice their errors on the tuning seeds
    3500-3507 (normalised RMS 0.45): hundreds of plane-refined depths scatter less than
    the per-pixel model says."""
    return (chi2 + DPP_MODEL_DOF) / (max(dof, 0) + DPP_MODEL_DOF)


def _dpp_covariance(rx, rz, dx, dz, vx, vz, inl, tx: float, tz: float, yaw_sigma: float):
    """``(inliers, chi-square, covariance (3, 3) over (yaw, t_x, t_z))`` of the estimate."""
    wx, wz = 1.0 / vx[inl], 1.0 / vz[inl]
    n_in = int(inl.sum())
    # reduced chi-square per axis, pooled with the noise model's 1 at DPP_MODEL_DOF degrees
    # of freedom: a few agreeing matches cannot claim more precision than the model gives,
    # many whose scatter is smaller than the model state that scatter
    fx = _pooled_scale(float((wx * (dx[inl] - tx) ** 2).sum()), n_in - 1)
    fz = _pooled_scale(float((wz * (dz[inl] - tz) ** 2).sum()), n_in - 1)
    chi2 = float((wx * (dx[inl] - tx) ** 2).sum() + (wz * (dz[inl] - tz) ** 2).sum())
    # t = mean(P2 - R P1): dt/dyaw = -mean(dR/dyaw P1) = (-rz, +rx) weighted
    gx = -float((wx * rz[inl]).sum() / wx.sum())
    gz = float((wz * rx[inl]).sum() / wz.sum())
    g = np.array([1.0, gx, gz])
    cov = yaw_sigma ** 2 * np.outer(g, g)
    cov[1, 1] += fx / wx.sum()
    cov[2, 2] += fz / wz.sum()
    return n_in, chi2, cov
