"""The translation along one direction from the depth images alone (partial steps).

A partial step knows its yaw (the Manhattan frame) and the translation along the normals
of the walls seen in both frames; along a corridor's axis nothing in a textureless log
fixes it, and the constant-velocity guess takes over. But the depth images still see
what stands off the walls -- boxes, door frames, the end wall, a corner -- and those
move in the image when the robot moves along the axis. :func:`align_along` finds the
distance ``s`` along a levelled direction ``u`` that makes the previous frame's depth,
moved by the step, agree with this frame's depth: a one-dimensional search (the other
degrees of freedom are fixed by the walls and the Manhattan yaw), robust to depth edges
and to what entered or left the view.

Frames: levelled camera ``lev`` (y down, yaw about y), ``X_lev2 = R_y(yaw) X_lev1 + t``
with ``t = (t_x, 0, t_z)``; ``X_lev = R_lev_cam X_cam``; camera optical (x right, y down,
z forward).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from planar_vo.core import geometry
from planar_vo.core.types import CameraIntrinsics


@dataclass(frozen=True)
class DepthAlignOptions:
    """``stride``: pixel step of the sampled points of the previous frame; ``edge_m``: a
    sample this far from a grid neighbour is on a depth edge. A point whose surface normal
    is nearly perpendicular to ``u`` (``|n . u| < min_cos``) carries no information on
    ``s`` and is left out. Depth noise
    ``sigma_const + sigma_quad Z^2`` (m); residuals are truncated at ``truncate`` sigmas.
    ``inflate``: the fitted variance is multiplied by this (neighbouring samples' errors
    are correlated, and the model error is not in the curvature), then
    ``min_sigma_m`` is added in quadrature. ``min_points``: informative samples needed.
    ``basin_m``: half-width of the parabola's grid, ``wide_basin_m`` the one tried when
    that grid shows no bowl (0: none); ``min_contrast``: the parabola must rise over its
    grid this many times the RMS it leaves unexplained. ``yaw_smooth_px``: the window of
    :func:`smooth_depth` applied to this frame's depth before the yaw search (1: none).
    """

    stride: int = 0  # 0: the image width / 160 (6 px at Kinect v2 qhd, 4 at VGA)
    edge_m: float = 0.05
    min_cos: float = 0.5
    sigma_const: float = 0.002
    sigma_quad: float = 0.002
    truncate: float = 3.0
    inflate: float = 2.0
    min_sigma_m: float = 0.0005
    min_points: int = 100
    basin_m: float = 0.015
    wide_basin_m: float = 0.04
    yaw_smooth_px: int = 5
    min_contrast: float = 10.0
    max_sigma_m: float = 0.01
    min_depth: float = 0.3
    max_depth: float = 4.0


@dataclass(frozen=True)
class DepthAlignment:
    """``s`` (m) along ``u`` from ``t0`` and its variance (m^2); ``n_points`` samples used."""

    s: float
    var: float
    n_points: int


def sample_points(depth: np.ndarray, K: CameraIntrinsics, R_lev_cam: np.ndarray, opt: DepthAlignOptions
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Levelled points ``(N, 3)`` float64 of every ``opt.stride``-th pixel with valid depth
    whose 5 x 5 median depth lies in ``(opt.min_depth, opt.max_depth)``, and their
    levelled unit surface normals ``(N, 3)`` (central differences on that grid,
    towards the camera); points on a depth edge (a neighbour more than
    ``opt.edge_m`` away) or without all four neighbours are left out."""
    step = opt.stride or max(2, round(depth.shape[1] / 160))
    v, u = np.mgrid[0:depth.shape[0]:step, 0:depth.shape[1]:step]
    z = depth[v, u].astype(np.float64)
    # Which points are in range is decided on the 5 x 5 median, not the pixel's own
    # depth: a cut on a noisy depth keeps, of a surface near it, the pixels whose noise
    # put them nearer, and the points taken from it are biased near (of a wall 3.95 m
    # ahead, 4.8 mm with a 4 m cut; 0.1 mm on the median), so a step towards it comes out
    # short (tests/test_depthalign.py: 5 cm towards that wall, 5.0 mm short; 0.6 mm long).
    zm = cv2.medianBlur(np.asarray(depth, np.float32), 5)[v, u]
    ok = np.isfinite(z) & (zm > opt.min_depth) & (zm < opt.max_depth)
    z = np.where(ok, z, np.nan)
    G = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z], axis=-1) @ R_lev_cam.T
    dx = G[1:-1, 2:] - G[1:-1, :-2]
    dy = G[2:, 1:-1] - G[:-2, 1:-1]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1)
    P = G[1:-1, 1:-1]
    good = (np.isfinite(norm) & (norm > 0) & (np.linalg.norm(dx, axis=-1) < 2 * opt.edge_m)
            & (np.linalg.norm(dy, axis=-1) < 2 * opt.edge_m))
    n = n[good] / norm[good][:, None]
    P = P[good]
    n *= -np.sign((n * P).sum(1))[:, None]  # towards the camera
    return P, n


def informative(normals: np.ndarray, u: np.ndarray, opt: DepthAlignOptions) -> np.ndarray:
    """Mask ``(N,)`` of the points whose surface a motion along levelled ``u`` (2,) (x, z)
    does not slide along (``|n . u| >= opt.min_cos``): side walls, floor, ceiling and box
    fronts seen along a corridor say nothing about the distance along it."""
    return np.abs(normals[:, 0] * u[0] + normals[:, 2] * u[1]) >= opt.min_cos


def smooth_depth(depth: np.ndarray, size: int, edge_m: float) -> np.ndarray:
    """``depth`` (H, W) float32 metres (0 = none) averaged over ``size`` x ``size`` pixels
    wherever that window is all valid and spans less than ``edge_m`` in depth; elsewhere
    (holes, depth edges) as it was. Each pixel's noise is drawn anew, so a point moving
    across pixels under the candidate motions sees a new draw at each and the cost jitters
    by it; :func:`align_yaw` averages that part away. (On a textureless test hall it was
    the smaller part: the bowls' contrast moved little, the rest of the jitter comes from
    points crossing depth edges, where the nearest pixel is used.)"""
    d = np.asarray(depth, dtype=np.float32)
    k = np.ones((size, size), np.uint8)
    valid = (d > 0).astype(np.float32)
    full = cv2.blur(valid, (size, size)) > 1.0 - 1e-6
    span = cv2.dilate(d, k) - cv2.erode(np.where(d > 0, d, np.float32(np.inf)).astype(np.float32), k)
    mean = cv2.blur(d, (size, size))
    return np.where(full & (span < edge_m), mean, d).astype(np.float32)


def informative_yaw(points: np.ndarray, normals: np.ndarray, opt: DepthAlignOptions) -> np.ndarray:
    """Mask ``(N,)`` of the levelled ``points`` (N, 3) whose surface a yaw (about levelled
    y) does not slide along: a yaw moves a point across its line of sight, ``(z, 0, -x)``,
    so the floor, the ceiling and surfaces facing the camera say little of it."""
    d = np.stack([points[:, 2], -points[:, 0]], axis=1)
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-9)[:, None]
    return np.abs(normals[:, 0] * d[:, 0] + normals[:, 2] * d[:, 1]) >= opt.min_cos


def _costs(P1: np.ndarray, depth2: np.ndarray, K: CameraIntrinsics, R_lev_cam2: np.ndarray, yaws: np.ndarray,
           ts: np.ndarray, opt: DepthAlignOptions) -> tuple[np.ndarray, int]:
    """Truncated squared normalised depth residuals of ``P1`` moved by each candidate step
    (``yaws`` (S,) rad, ``ts`` (S, 2) levelled x, z), normalised by the noise of the
    observed depth, summed over the points seen under every candidate, one sum per
    candidate, and that number of points."""
    yaws = np.asarray(yaws, dtype=float)
    if np.all(yaws == yaws[0]):
        Q = (P1 @ geometry.rot_y(float(yaws[0])).T)[None, :, :]  # rotated, not yet translated
    else:  # R_y(a) per candidate, written out: (S, N, 3)
        c, s_ = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
        x, y, z = P1[:, 0][None, :], P1[:, 1][None, :], P1[:, 2][None, :]
        Q = np.stack([c * x + s_ * z, np.broadcast_to(y, (len(yaws), len(P1))), c * z - s_ * x], axis=-1)
    shifts = np.zeros((len(yaws), 3))
    shifts[:, 0], shifts[:, 2] = ts[:, 0], ts[:, 1]
    X = (Q + shifts[:, None, :]) @ R_lev_cam2  # camera frame, (S, N, 3)
    z = X[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = K.fx * X[..., 0] / z + K.cx
        py = K.fy * X[..., 1] / z + K.cy
    h, w = depth2.shape
    inside = (z > opt.min_depth) & (px >= 0) & (px <= w - 1.001) & (py >= 0) & (py <= h - 1.001)
    px, py = np.where(inside, px, 0.0), np.where(inside, py, 0.0)
    x0, y0 = px.astype(np.int64), py.astype(np.int64)
    fx_, fy_ = px - x0, py - y0
    d00, d01 = depth2[y0, x0], depth2[y0, x0 + 1]
    d10, d11 = depth2[y0 + 1, x0], depth2[y0 + 1, x0 + 1]
    corners = np.stack([d00, d01, d10, d11])
    # across a depth edge the interpolated depth lies on neither surface: use the nearest
    spread = corners.max(0) - corners.min(0)
    bil = (d00 * (1 - fx_) * (1 - fy_) + d01 * fx_ * (1 - fy_) + d10 * (1 - fx_) * fy_ + d11 * fx_ * fy_)
    near = np.where(fy_ < 0.5, np.where(fx_ < 0.5, d00, d01), np.where(fx_ < 0.5, d10, d11))
    zobs = np.where(spread > 0.05, near, bil)
    # the same for this frame's depth: cut where noise cannot reach, 4 sigmas beyond the
    # range, so that no observation of a surface inside it is dropped for its noise
    far = opt.max_depth + 4.0 * (opt.sigma_const + opt.sigma_quad * opt.max_depth ** 2)
    valid = inside & (corners.min(0) > 0) & np.isfinite(zobs) & (zobs < far)
    # only points seen at every s: a point leaving the image (or falling into a hole) at
    # some s would make the cost prefer the motions that keep it in view
    keep = valid.all(0)
    z, zobs = z[:, keep], zobs[:, keep]
    # The noise is the observed depth's, so its sigma is taken there, the same under every
    # candidate. At the candidate's predicted depth z it would shrink as a candidate moves
    # the points closer, each point's noise (about one sigma squared) would weigh more on
    # the longer steps, and the minimum would move short: 1.0 / 1.5 mm for a 5 cm step
    # towards a wall 3 / 3.5 m ahead (mean of 20 noise draws; 0.1 mm at zobs,
    # tests/test_depthalign.py). At z, the depth-measured partial steps of four textureless
    # dev halls and two low-texture tuning halls came out 0.26-0.87 mm short a step (mean
    # per log, 8-80 mm steps); at zobs, 0.25 mm short to 0.18 mm long (a textureless L:
    # 0.01 short, 0.21 long).
    sig = opt.sigma_const + opt.sigma_quad * zobs * zobs
    r2 = ((zobs - z) / sig) ** 2
    return np.minimum(r2, opt.truncate ** 2).sum(1), int(keep.sum())


def align_along(P1: np.ndarray, depth2: np.ndarray, K: CameraIntrinsics, R_lev_cam2: np.ndarray, yaw: float,
                t0: np.ndarray, u: np.ndarray, half_range: float,
                opt: DepthAlignOptions | None = None, wide: bool = True) -> DepthAlignment | None:
    """The distance ``s`` (m) along levelled unit ``u`` (2,) (x, z) that best moves the
    previous frame's points ``P1`` (N, 3) (levelled, :func:`sample_points` masked by
    :func:`informative`) onto this frame's ``depth2`` (H, W) float32 metres (0 = none),
    with ``R_lev_cam2`` this frame's levelling, at the step's ``yaw`` (rad) and
    ``t = t0 + s u`` (``t0`` (2,) levelled x, z). ``|s| <= half_range``.

    A coarse grid over the range, then a parabola through a grid of +-``opt.basin_m``
    around its minimum (or, where that grid shows no bowl and ``wide``, of
    +-``opt.wide_basin_m``).
    The variance is ``2 / curvature`` of the summed truncated cost (its Fisher
    information) times ``opt.inflate``, plus the vertex's variance from the fit and
    ``opt.min_sigma_m^2``. None when fewer than ``opt.min_points`` points are seen at every
    ``s``, the minimum lies on the range's edge, the cost is not convex there, the parabola
    rises less than ``opt.min_contrast`` times its residual RMS, its vertex leaves the inner
    half of that grid, or the sigma exceeds ``opt.max_sigma_m``.
    """
    opt = opt or DepthAlignOptions()
    t0, u = np.asarray(t0, dtype=float), np.asarray(u, dtype=float)

    def cost(s: np.ndarray):
        return _costs(P1, depth2, K, R_lev_cam2, np.full(len(s), float(yaw)), t0 + s[:, None] * u, opt)
    return _search(cost, len(P1), half_range, (opt.basin_m, opt.wide_basin_m if wide else 0.0), opt.min_sigma_m,
                   opt.max_sigma_m, opt)


def align_yaw(P1: np.ndarray, depth2: np.ndarray, K: CameraIntrinsics, R_lev_cam2: np.ndarray, yaw0: float,
              t, half_range: float, opt: DepthAlignOptions | None = None) -> DepthAlignment | None:
    """The yaw change ``s`` (rad) from ``yaw0`` that best moves ``P1`` (N, 3) (levelled,
    :func:`sample_points` masked by :func:`informative_yaw`) onto ``depth2`` at the step
    ``X_lev2 = R_y(yaw0 + s) X_lev1 + t``; ``|s| <= half_range``. ``t``: (2,) levelled
    x, z, or a function of the candidate yaws (S,) giving (S, 2) (a translation that turns
    with the yaw).

    The search of :func:`align_along` about the yaw: a yaw change ``s`` moves a point at
    range ``r`` by ``r s``, so its windows and sigma bounds are ``align_along``'s divided
    by the points' median range (rad)."""
    opt = opt or DepthAlignOptions()
    if len(P1) == 0:
        return None
    if opt.yaw_smooth_px > 1:
        depth2 = smooth_depth(depth2, opt.yaw_smooth_px, opt.edge_m)
    r = float(np.median(np.hypot(P1[:, 0], P1[:, 2])))
    t_of = t if callable(t) else (lambda yaws, t=np.asarray(t, dtype=float): np.tile(t, (len(yaws), 1)))

    def cost(s: np.ndarray):
        yaws = float(yaw0) + s
        return _costs(P1, depth2, K, R_lev_cam2, yaws, t_of(yaws), opt)
    return _search(cost, len(P1), half_range, (opt.basin_m / r, opt.wide_basin_m / r), opt.min_sigma_m / r,
                   opt.max_sigma_m / r, opt)


def coarse_yaw_along(P1: np.ndarray, depth2: np.ndarray, K: CameraIntrinsics, R_lev_cam2: np.ndarray,
                     yaw0: float, t_of, u: np.ndarray, half_yaw: float, half_s: float,
                     opt: DepthAlignOptions | None = None, n_yaw: int = 13, n_s: int = 21,
                     max_points: int = 600) -> tuple[float, float] | None:
    """The grid cell ``(dyaw (rad), s (m))`` whose step ``X_lev2 = R_y(yaw0 + dyaw) X_lev1 +
    t_of(yaw0 + dyaw) + s u`` best moves ``P1`` (N, 3) onto ``depth2``, over ``n_yaw`` x
    ``n_s`` samples of ``+-half_yaw`` x ``+-half_s`` with about ``max_points`` of the
    points; None when too few points are seen at every cell. ``t_of``: candidate yaws
    (S,) -> levelled translations (S, 2); ``u`` (2,).

    A start for :func:`align_yaw` and :func:`align_along` when both the yaw and the
    distance along are guesses: each 1-D search needs the other coordinate within its
    basin (a yaw 0.8 deg off moves a point 3 m ahead 4 cm sideways, a distance 8 cm off
    moves the bowl of the yaw), and a robot starting from rest is guessed at zero."""
    opt = opt or DepthAlignOptions()
    if len(P1) < opt.min_points:
        return None
    # a cell is only a start: every k-th point is enough to find it, and the grid's
    # n_yaw x n_s candidates cost that many projections of each point
    k = max(1, len(P1) // max_points)
    P1 = P1[::k]
    dy = np.linspace(-half_yaw, half_yaw, n_yaw)
    ds = np.linspace(-half_s, half_s, n_s)
    Y, S = np.meshgrid(dy, ds, indexing="ij")
    yaws = float(yaw0) + Y.ravel()
    # t_of per distinct yaw only (a wheeled base's chord is a small solve per yaw); the
    # grid runs yaw-major, each yaw n_s times in a row
    ts = np.repeat(t_of(float(yaw0) + dy), n_s, axis=0) + S.ravel()[:, None] * np.asarray(u, dtype=float)[None, :]
    c, n = _costs(P1, depth2, K, R_lev_cam2, yaws, ts, opt)
    if n * k < opt.min_points:  # the sample stands for k times as many points
        return None
    i = int(np.argmin(c))
    return float(Y.ravel()[i]), float(S.ravel()[i])


def _search(cost, n_points: int, half_range: float, windows: tuple[float, float], min_sigma: float,
            max_sigma: float, opt: DepthAlignOptions) -> DepthAlignment | None:
    """The 1-D search of :func:`align_along` over ``cost(s (S,)) -> (costs (S,), points)``,
    in the units of ``half_range`` (its docstring gives the tests)."""
    if n_points < opt.min_points or not half_range > 0:
        return None
    grid = np.linspace(-half_range, half_range, 41)
    c, n = cost(grid)
    if n < opt.min_points:
        return None
    k = int(np.argmin(c))
    if k in (0, len(grid) - 1):
        return None
    # far surfaces make a wide bowl (their depth noise grows with Z^2): over the narrow
    # window it hardly rises above the noise. The wider window is tried only when the
    # narrow one finds no bowl, so every minimum the narrow one accepts stays as it was.
    for w in windows:
        if w > 0:
            a = _basin_vertex(cost, float(grid[k]), w, half_range, min_sigma, max_sigma, opt)
            if a is not None:
                return a
    return None


def _basin_vertex(cost, centre: float, w: float, half_range: float, min_sigma: float, max_sigma: float,
                  opt: DepthAlignOptions) -> DepthAlignment | None:
    """The parabola's vertex over ``centre +- w`` as :func:`align_along` states it, or None
    when that window shows no bowl (its tests, in its docstring)."""
    fine = np.linspace(centre - w, centre + w, 31)
    fc, n = cost(fine)
    coef, C = np.polyfit(fine - centre, fc, 2, cov="unscaled")
    a2, a1 = coef[0], coef[1]
    if not a2 > 0 or n < opt.min_points:
        return None
    # a bowl, not noise: what the parabola rises over the window must stand far above what
    # it leaves unexplained (a flat cost -- nothing faces u -- still fits some curvature).
    # On three synthetic textureless corridors the 23 minima below a contrast of 6 erred by
    # a median of 12-70 mm, the 82 above 10 by a median of 0.4-0.7 mm (worst 14.8); without the
    # test one such minimum (90 mm off, stated at 5 mm), copied into the guesses that
    # followed, took a textureless L from 4.7 to 15.6 % raw drift.
    resid = float(np.std(fc - np.polyval(coef, fine - centre)))
    if a2 * w * w < opt.min_contrast * resid:
        return None
    s = centre - a1 / (2 * a2)
    if abs(s - centre) > 0.5 * w or abs(s) > half_range:
        return None
    # cost = sum r^2 / sigma^2 ~ c0 + a2 (s - s*)^2 with a2 = sum (dr/ds)^2 / sigma^2, the
    # Fisher information of s: var = 1 / a2. A bumpy bowl also places its vertex only as
    # well as the parabola fits it: the vertex -a1 / (2 a2) propagated from the fit's
    # coefficient covariance (the residuals' variance times the unscaled one) is added.
    J = np.array([a1 / (2 * a2 * a2), -1.0 / (2 * a2), 0.0])
    var_fit = resid ** 2 * float(J @ C @ J)
    var = opt.inflate / a2 + var_fit + min_sigma ** 2
    if var > max_sigma ** 2:
        return None
    return DepthAlignment(float(s), float(var), n)
