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
    ``basin_m``: half-width of the parabola's grid; ``min_contrast``: the parabola must
    rise over it this many times the RMS it leaves unexplained.
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
    and their levelled unit surface normals ``(N, 3)`` (central differences on that grid,
    towards the camera); points on a depth edge (a neighbour more than
    ``opt.edge_m`` away) or without all four neighbours are left out."""
    step = opt.stride or max(2, round(depth.shape[1] / 160))
    v, u = np.mgrid[0:depth.shape[0]:step, 0:depth.shape[1]:step]
    z = depth[v, u].astype(np.float64)
    ok = np.isfinite(z) & (z > opt.min_depth) & (z < opt.max_depth)
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


def _costs(P1: np.ndarray, depth2: np.ndarray, K: CameraIntrinsics, R_lev_cam2: np.ndarray, yaw: float,
           t0: np.ndarray, u: np.ndarray, s: np.ndarray, opt: DepthAlignOptions) -> tuple[np.ndarray, int]:
    """Truncated squared normalised depth residuals summed over the points seen at every
    ``s``, one sum per ``s``, and that number of points."""
    Q = P1 @ geometry.rot_y(yaw).T                       # rotated, not yet translated (N, 3)
    shifts = np.zeros((len(s), 3))
    shifts[:, 0] = t0[0] + s * u[0]
    shifts[:, 2] = t0[1] + s * u[1]
    X = (Q[None, :, :] + shifts[:, None, :]) @ R_lev_cam2  # camera frame, (S, N, 3)
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
    valid = inside & (corners.min(0) > 0) & np.isfinite(zobs) & (zobs < opt.max_depth)
    # only points seen at every s: a point leaving the image (or falling into a hole) at
    # some s would make the cost prefer the motions that keep it in view
    keep = valid.all(0)
    z, zobs = z[:, keep], zobs[:, keep]
    sig = opt.sigma_const + opt.sigma_quad * z * z
    r2 = ((zobs - z) / sig) ** 2
    return np.minimum(r2, opt.truncate ** 2).sum(1), int(keep.sum())


def align_along(P1: np.ndarray, depth2: np.ndarray, K: CameraIntrinsics, R_lev_cam2: np.ndarray, yaw: float,
                t0: np.ndarray, u: np.ndarray, half_range: float,
                opt: DepthAlignOptions | None = None) -> DepthAlignment | None:
    """The distance ``s`` (m) along levelled unit ``u`` (2,) (x, z) that best moves the
    previous frame's points ``P1`` (N, 3) (levelled, :func:`sample_points` masked by
    :func:`informative`) onto this frame's ``depth2`` (H, W) float32 metres (0 = none),
    with ``R_lev_cam2`` this frame's levelling, at the step's ``yaw`` (rad) and
    ``t = t0 + s u`` (``t0`` (2,) levelled x, z). ``|s| <= half_range``.

    A coarse grid over the range, then a parabola through a grid of +-``opt.basin_m``
    around its minimum. The variance is ``2 / curvature`` of the summed truncated cost (its
    Fisher information) times ``opt.inflate``, plus the vertex's variance from the fit and
    ``opt.min_sigma_m^2``. None when fewer than ``opt.min_points`` points are seen at every
    ``s``, the minimum lies on the range's edge, the cost is not convex there, the parabola
    rises less than ``opt.min_contrast`` times its residual RMS, its vertex leaves the inner
    half of that grid, or the sigma exceeds ``opt.max_sigma_m``.
    """
    opt = opt or DepthAlignOptions()
    if len(P1) < opt.min_points or not half_range > 0:
        return None
    grid = np.linspace(-half_range, half_range, 41)
    cost, n = _costs(P1, depth2, K, R_lev_cam2, yaw, t0, u, grid, opt)
    if n < opt.min_points:
        return None
    k = int(np.argmin(cost))
    if k in (0, len(grid) - 1):
        return None
    # The cost is a noisy bowl (each sample's depth noise is drawn again as its projection
    # moves across pixels): a parabola over the whole basin, not through the lowest samples
    w = opt.basin_m
    fine = np.linspace(grid[k] - w, grid[k] + w, 31)
    fc, n = _costs(P1, depth2, K, R_lev_cam2, yaw, t0, u, fine, opt)
    coef, C = np.polyfit(fine - grid[k], fc, 2, cov="unscaled")
    a2, a1 = coef[0], coef[1]
    if not a2 > 0 or n < opt.min_points:
        return None
    # a bowl, not noise: what the parabola rises over the window must stand far above what
    # it leaves unexplained (a flat cost -- nothing faces u -- still fits some curvature).
    # On three synthetic textureless corridors the 23 minima below a contrast of 6 erred by
    # a median of 12-70 mm, the 82 above 10 by a median of 0.4-0.7 mm (worst 14.8); without the
    # test one such minimum (90 mm off, stated at 5 mm), copied into the guesses that
    # followed, took a textureless L from 4.7 to 15.6 % raw drift.
    resid = float(np.std(fc - np.polyval(coef, fine - grid[k])))
    if a2 * w * w < opt.min_contrast * resid:
        return None
    s = grid[k] - a1 / (2 * a2)
    if abs(s - grid[k]) > 0.5 * w or abs(s) > half_range:
        return None
    # cost = sum r^2 / sigma^2 ~ c0 + a2 (s - s*)^2 with a2 = sum (dr/ds)^2 / sigma^2, the
    # Fisher information of s: var = 1 / a2. A bumpy bowl also places its vertex only as
    # well as the parabola fits it: the vertex -a1 / (2 a2) propagated from the fit's
    # coefficient covariance (the residuals' variance times the unscaled one) is added.
    J = np.array([a1 / (2 * a2 * a2), -1.0 / (2 * a2), 0.0])
    var_fit = resid ** 2 * float(J @ C @ J)
    var = opt.inflate / a2 + var_fit + opt.min_sigma_m ** 2
    if var > opt.max_sigma_m ** 2:
        return None
    return DepthAlignment(float(s), float(var), n)
