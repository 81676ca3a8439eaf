"""Planes from inverse-depth histograms (paper Sec. 2.1), in the levelled camera frame.

For a plane ``n . X = d`` and a pixel with levelled normalised coordinates
``(x, y) = (X/Z, Y/Z)``, the inverse depth is linear: ``1/Z = (n_x x + n_y y + n_z) / d``.
Two consequences drive the detector:

* a horizontal plane (floor, ceiling) has one depth per levelled image *row*, a
  vertical plane (wall) one depth per levelled image *column*: in the histograms over
  (row, 1/Z) and (column, 1/Z) each such plane is a sharp line, everything else a smear;
* fitting ``q = n / d`` to ``1/Z = q . (x, y, 1)`` is linear least squares, and
  inverse-depth noise of RGB-D sensors is roughly uniform, so the fit is well posed.

Detection per family: build the histogram (``np.bincount``), keep each row's / column's
local inverse-depth peaks, let those cells vote for the plane's orientation angle and
inverse distance (a Hough transform over a few hundred cells, not the point cloud), then
fit ``q`` by least squares to the subsampled pixels near each peak and refit twice. No
RANSAC over the point cloud.
"""
from __future__ import annotations

import collections
import functools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from planar_vo.frontend.config import DEFAULT_DEPTH_RANGE, PlaneConfig
from planar_vo.frontend.features import UNDISTORT_CRITERIA
from planar_vo.core.types import CameraIntrinsics

FLOOR, CEILING, HORIZONTAL, WALL = "floor", "ceiling", "horizontal", "wall"


@dataclass(eq=False)
class Plane:
    """One detected plane in the levelled camera frame ``lev`` (y down).

    ``normal``: (3,) float64 unit vector from the camera towards the plane, so that
    ``normal . X_lev = offset`` with ``offset`` > 0 the camera-plane distance (m).
    ``support``: fraction of the (subsampled) image on the plane; ``n_points`` the count.
    ``rms``: RMS inverse-depth residual (1/m), ``rms_rel`` relative depth. ``extent``:
    angular width (rad) of the inliers across the image; ``width`` for walls the metres
    across that its inliers fill (:func:`_solid_runs`; a box face is under a metre wide, a
    corridor wall is not). ``cov_q``: (3, 3) covariance of the fit
    parameters ``q = normal / offset``. ``inliers``: (K,) int64 indices into the
    flattened subsampled grid (see :attr:`PlaneDetector.grid_shape`).
    """

    kind: str
    normal: np.ndarray
    offset: float
    support: float
    n_points: int
    rms: float
    cov_q: np.ndarray
    inliers: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, np.int64))
    rms_rel: float = 0.0  # RMS relative depth residual
    extent: float = 0.0   # angular width of the inliers along the histogram's image axis (rad)
    systematic: float = 0.0
    width: float = 0.0    # walls: horizontal width (m) its inliers fill (see _solid_runs)

    @property
    def yaw(self) -> float:
        """Heading (rad) of the horizontal part of the normal in the 2-D frame of ``lev``
        (x = forward = z_lev, y = left = -x_lev, counter-clockwise positive)."""
        return math.atan2(-self.normal[0], self.normal[2])

    @property
    def yaw_sigma(self) -> float:
        """Standard deviation (rad) of :attr:`yaw`: the fit's ``cov_q`` propagated, plus a
        systematic term for depth errors correlated across the plane (sensor bias, range
        truncation), ``systematic * rms_rel / extent`` -- far, narrow walls are poor compasses.
        """
        sys_ = self.systematic * self.rms_rel / max(self.extent, 1e-3)
        return float(math.sqrt(self.yaw_sigma_fit ** 2 + sys_ ** 2))

    @property
    def yaw_sigma_fit(self) -> float:
        """The part of :attr:`yaw_sigma` that changes from image to image: the fit's
        ``cov_q`` propagated (the pixel noise). The systematic term is the same wall seen
        from nearly the same place in the next image, so it cancels in a heading
        *difference* (the direction-plus-point yaw, eq. 1); it does not in one heading."""
        q = self.normal / self.offset
        r2 = q[0] ** 2 + q[2] ** 2
        J = np.array([-q[2] / r2, 0.0, q[0] / r2])
        return float(math.sqrt(max(J @ self.cov_q @ J, 0.0)))

    @property
    def tilt(self) -> float:
        """Angle (rad) between the normal and the horizontal plane (0 for a vertical wall)."""
        return math.asin(min(1.0, abs(self.normal[1])))


@dataclass
class PlaneDetection:
    """All planes of one depth image. ``floor`` is also the first of ``horizontals``."""

    floor: Plane | None
    horizontals: list[Plane]
    walls: list[Plane]
    n_valid: int          # subsampled pixels with a usable depth
    n_total: int          # subsampled pixels

    @property
    def wall_fraction(self) -> float:
        return float(sum(w.support for w in self.walls))


def normalised_grid(intrinsics: CameraIntrinsics, stride: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Undistorted normalised rays of the subsampled pixel grid.

    Returns ``(xy (M, 2) float64, offset, (h, w))``: the grid takes pixels
    ``depth[o::stride, o::stride]`` with ``o = stride // 2``, flattened row-major.
    """
    o = stride // 2
    us = np.arange(o, intrinsics.width, stride, dtype=np.float64)
    vs = np.arange(o, intrinsics.height, stride, dtype=np.float64)
    uu, vv = np.meshgrid(us, vs)
    px = np.stack([uu.ravel(), vv.ravel()], axis=1)
    if intrinsics.has_distortion:
        xy = cv2.undistortPoints(px.reshape(-1, 1, 2), intrinsics.K,
                                 np.asarray(intrinsics.distortion, np.float64),
                                 R=np.eye(3), P=np.eye(3), criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
    else:
        xy = np.stack([(px[:, 0] - intrinsics.cx) / intrinsics.fx,
                       (px[:, 1] - intrinsics.cy) / intrinsics.fy], axis=1)
    return xy.astype(np.float64), o, (len(vs), len(us))


class PlaneDetector:
    """Inverse-depth histogram plane detector for one camera.

    Build once per camera; call :meth:`set_levelling` when ``R_lev_cam`` changes and
    :meth:`detect` per depth image. The per-pixel levelled rays are cached, so a frame
    costs one strided copy of the depth, a few ``bincount`` calls and small fits.
    """

    def __init__(self, intrinsics: CameraIntrinsics, config: PlaneConfig | None = None,
                 R_lev_cam: np.ndarray | None = None, depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE):
        self.intrinsics = intrinsics
        self.config = config or PlaneConfig()
        self.depth_range = depth_range  # (min, max) m
        self.range_max = 0.0  # the sensor's range (m) once learnt, else 0 (see _learn_range)
        self._far: collections.deque = collections.deque(maxlen=_RANGE_FRAMES)  # farthest reading per frame
        self._far_ahead: list[float] = []  # the same, of frames not yet detected (look_ahead)
        self._xy_cam, self._o, self.grid_shape = normalised_grid(intrinsics, self.config.stride)
        self.n_total = self._xy_cam.shape[0]
        step = math.radians(self.config.hough_step_deg)
        self._wall_angles = np.arange(-math.radians(130), math.radians(130) + 1e-9, step)
        self._horiz_angles = {}
        for levelled, tilt_deg in ((True, self.config.horizontal_tilt_deg), (False, self.config.unlevelled_tilt_deg)):
            tilt = math.radians(tilt_deg)
            down = np.arange(math.pi / 2 - tilt, math.pi / 2 + tilt + 1e-9, step)
            self._horiz_angles[levelled] = np.concatenate([down, -down[::-1]])  # floor- and ceiling-like
        self.set_levelling(np.eye(3) if R_lev_cam is None else R_lev_cam)

    # ------------------------------------------------------------------ levelling
    def set_levelling(self, R_lev_cam: np.ndarray) -> None:
        """Cache levelled rays for ``R_lev_cam`` (3, 3)."""
        R = np.asarray(R_lev_cam, dtype=np.float64)
        if R.shape != (3, 3):
            raise ValueError(f"R_lev_cam must be (3, 3), got {R.shape}")
        self.R_lev_cam = R
        rays = np.column_stack([self._xy_cam, np.ones(self.n_total)]) @ R.T
        ok = rays[:, 2] > 0.05
        rz = np.where(ok, rays[:, 2], 1.0)
        self._ray_ok = ok
        self._zscale = rz                      # Z_lev = Z_cam * zscale
        self._x = rays[:, 0] / rz              # levelled normalised coordinates
        self._y = rays[:, 1] / rz
        c = self.config
        xs, ys = self._x[ok], self._y[ok]
        self._xr = (xs.min(), xs.max() + 1e-9)
        self._yr = (ys.min(), ys.max() + 1e-9)
        self._wr = (1.0 / self.depth_range[1], 1.0 / self.depth_range[0])
        # Pre-computed bins of the image axes (the inverse-depth bin changes per frame).
        nb = c.n_image_bins
        self._xbin = np.clip(((self._x - self._xr[0]) / (self._xr[1] - self._xr[0]) * nb).astype(np.int64), 0, nb - 1)
        self._ybin = np.clip(((self._y - self._yr[0]) / (self._yr[1] - self._yr[0]) * nb).astype(np.int64), 0, nb - 1)

    # ------------------------------------------------------------------ detection
    def inverse_depth(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Levelled inverse depth of the grid: ``(idx (V,) int64, w (V,) float64)`` for valid pixels."""
        c = self.config
        if depth.ndim != 2 or depth.shape != (self.intrinsics.height, self.intrinsics.width):
            raise ValueError(f"depth must be ({self.intrinsics.height}, {self.intrinsics.width}), got {depth.shape}")
        z = depth[self._o::c.stride, self._o::c.stride].ravel()
        valid = (z >= self.depth_range[0]) & (z <= self.depth_range[1]) & self._ray_ok
        idx = np.flatnonzero(valid)
        w = 1.0 / (z[idx].astype(np.float64) * self._zscale[idx])
        return idx, w

    def look_ahead(self, depths: Iterable[np.ndarray]) -> None:
        """Learn the sensor's range from the first frames' depth (H, W) float32 m before
        their walls are measured, as :meth:`_learn_range` would after them.

        Without it the first ``_RANGE_MIN_FRAMES`` frames fit walls that run past the range
        with no range limit: their far ends, cut where the readings stop, tilt the fit.
        Frame 0's Manhattan observation is the run's heading reference, and on a held-out
        L (lturn_s6300) it was 0.35 deg off the later frames' (0.02 deg among themselves).
        """
        for depth in depths:
            idx, w = self.inverse_depth(depth)
            if len(w):
                self._far_ahead.append(self._farthest(idx, w))

    def _farthest(self, idx: np.ndarray, w: np.ndarray) -> float:
        """The farthest camera depth (m) among grid points ``idx`` with levelled inverse
        depths ``w`` (non-empty; see :meth:`inverse_depth`)."""
        return float(1.0 / np.min(w * self._zscale[idx]))

    def _learn_range(self, pts: "_Points") -> float:
        """Learn the sensor's range from this frame's farthest reading; return the least
        camera inverse depth (1/m) a wall point's *predicted* depth may have (0: no limit).

        A range shows as the same farthest reading frame after frame; a scene's extent
        (a corridor's end wall, the farthest surface while the robot drives towards it)
        does not. So :attr:`range_max` is set when, over the last ``_RANGE_FRAMES``
        frames (at least ``_RANGE_MIN_FRAMES``), half of them read within 2 % of their
        median farthest depth: it is that median (and stays once set).
        """
        if len(pts.w):
            self._far.append(self._farthest(pts.idx, pts.w))
        # Until the stream has its own _RANGE_MIN_FRAMES readings, a look-ahead's stand in.
        far = self._far if len(self._far) >= _RANGE_MIN_FRAMES else self._far_ahead
        if len(far) >= _RANGE_MIN_FRAMES:
            far = np.array(far)
            med = float(np.median(far))
            if np.mean(np.abs(far - med) <= 0.02 * med) >= 0.5:
                self.range_max = med
        m = self.config.range_margin
        return 1.0 / ((1.0 - m) * self.range_max) if m > 0 and self.range_max > 0 else 0.0

    def detect(self, depth: np.ndarray, floor_offset_hint: float | None = None,
               levelled: bool = True, walls: bool = True, floor_seed: Plane | None = None) -> PlaneDetection:
        """Detect horizontal planes (floor first) and walls in ``depth`` (H, W) float32 metres.

        ``floor_offset_hint``: expected camera height (m); when given, the floor is the
        strongest downward-facing plane within 30 % of it. ``floor_seed``: the previous
        frame's floor (same levelled frame); under planar motion it is this frame's floor
        too, so it is refitted directly and the horizontal Hough search is skipped when
        that succeeds. ``levelled=False`` widens the floor search to
        ``unlevelled_tilt_deg`` (tilt not yet known); ``walls=False`` stops after the
        horizontal planes.
        """
        c = self.config
        idx, w = self.inverse_depth(depth)
        pts = _Points(idx, w, self._x[idx], self._y[idx])
        tilt = c.horizontal_tilt_deg if levelled else c.unlevelled_tilt_deg
        horizontals: list[Plane] = []
        floor = None
        if floor_seed is not None:
            floor = self._refit_seed(pts, floor_seed.normal / floor_seed.offset, vertical=False, max_tilt_deg=tilt)
            if floor is not None and floor.normal[1] > 0:
                horizontals = [floor]
            else:
                floor = None
        if floor is None:
            horizontals = self._detect_family(pts, self._ybin, self._horiz_angles[levelled], vertical=False,
                                              max_planes=2, max_tilt_deg=tilt)
            for p in horizontals:
                if p.normal[1] > 0 and (floor_offset_hint is None
                                        or abs(p.offset - floor_offset_hint) < 0.3 * floor_offset_hint):
                    floor = p
                    break
            if floor is not None:
                horizontals.remove(floor)
                horizontals.insert(0, floor)
        for p in horizontals:
            if p is floor:
                p.kind = FLOOR
            elif p.normal[1] < 0:
                p.kind = CEILING
        found = []
        min_wall_w = self._learn_range(pts)
        if walls:
            rest = pts
            if horizontals:
                keep = np.ones(len(idx), bool)
                keep[np.searchsorted(idx, np.concatenate([p.inliers for p in horizontals]))] = False
                rest = pts.subset(keep)
            found = self._detect_family(rest, self._xbin, self._wall_angles, vertical=True,
                                        max_planes=c.max_walls, max_tilt_deg=c.wall_tilt_deg, min_w=min_wall_w)
        return PlaneDetection(floor, horizontals, found, len(idx), self.n_total)

    # ------------------------------------------------------------------ internals
    def _refit_seed(self, pts: "_Points", q: np.ndarray, vertical: bool, max_tilt_deg: float) -> Plane | None:
        """Fit the plane near a predicted ``q = n / d`` (no Hough); None if it is not there."""
        c = self.config
        tol = c.inlier_rel_depth
        pred = pts.x * q[0] + pts.y * q[1] + q[2]
        band = np.flatnonzero(np.abs(pts.w - pred) < 2.0 * tol * pts.w)
        if len(band) < max(10, int(c.min_support * self.n_total)):
            return None
        plane = self._fit(pts.x[band], pts.y[band], pts.w[band], np.ones(len(band), bool), tol,
                          pts.x[band] if vertical else pts.y[band], vertical and c.layer_step)
        if not self._acceptable(plane, vertical, max_tilt_deg):
            return None
        plane.kind = WALL if vertical else HORIZONTAL
        self._finish(plane, pts.x[band] if vertical else pts.y[band])
        plane.inliers = pts.idx[band[plane.inliers]]
        return plane

    def _finish(self, plane: Plane, u: np.ndarray) -> None:
        """Angular extent of the inliers (2nd-98th percentile of ``u``) and the error model."""
        uu = u[plane.inliers]
        if len(uu) > 400:
            uu = uu[:: len(uu) // 200]
        lo, hi = _percentiles(uu, _EXTENT_QUANTILES)
        plane.extent = float(math.atan(hi) - math.atan(lo))
        plane.systematic = self.config.systematic_fraction
        if plane.kind == WALL:
            plane.width = sum(wall_width(plane.normal, plane.offset, a, b, self.depth_range[1])
                              for a, b in _solid_runs(u[plane.inliers], float(lo), float(hi)))

    def _acceptable(self, plane: Plane | None, vertical: bool, max_tilt_deg: float) -> bool:
        c = self.config
        if plane is None or plane.n_points < max(10, int(c.min_support * self.n_total)):
            return False
        n = plane.normal
        if (abs(n[1]) if vertical else math.hypot(n[0], n[2])) > math.sin(math.radians(max_tilt_deg)):
            return False
        # Residuals spread evenly over the band (relative RMS -> tol / sqrt(3)) mean a line
        # through clutter, not a surface; real planes sit well inside it.
        return plane.rms_rel <= 0.45 * c.inlier_rel_depth

    def _detect_family(self, pts: "_Points", ubin_all, angles, vertical: bool, max_planes: int,
                       max_tilt_deg: float, min_w: float = 0.0) -> list[Plane]:
        """Planes of one family (walls or horizontals), strongest Hough line first. ``min_w``:
        least camera inverse depth (1/m) of a point's predicted depth (0: any); a cut on the
        points' own depth would truncate their noise as the sensor's range does."""
        c = self.config
        planes: list[Plane] = []
        min_pts = max(10, int(c.min_support * self.n_total))
        if len(pts.idx) < min_pts:
            return planes
        idx, w = pts.idx, pts.w
        u = pts.y if not vertical else pts.x
        cells = self._histogram_cells(idx, w, u, ubin_all)
        if cells is None:
            return planes
        cw, cell_w, cell_u = cells
        vote_idx, lo, lbin_w, nd = self._hough_bins(cell_w, cell_u, angles)
        na = len(angles)
        alive = np.ones(len(cw), bool)
        pool = np.ones(len(idx), bool)  # raw points not yet explained
        tol = c.inlier_rel_depth
        failures = 0
        # The accumulator of the live cells: spent cells' votes are taken out as they die.
        # Votes are whole counts, so the sums are exact and independent of the order.
        acc = _votes(vote_idx, cw, na * nd)
        while len(planes) < max_planes and failures < 2 and alive.any():
            best = int(np.argmax(acc))
            if acc[best] < 0.5 * min_pts:
                break  # what is left cannot make a plane of the minimum support
            ai, di = divmod(best, nd)
            a = angles[ai]
            inv_d = math.exp(lo + (di + 0.5) * lbin_w)
            # The cells this line explains are spent, whether or not the fit is accepted.
            pred_cell = inv_d * (cell_u * math.sin(a) + math.cos(a))
            spent = alive & ~(np.abs(cell_w - pred_cell) > 1.5 * tol * cell_w)
            alive &= ~spent
            acc -= _votes(vote_idx[spent], cw[spent], na * nd)
            # Least squares on the raw points near the line, then refits of the full plane.
            pred = inv_d * (u * math.sin(a) + math.cos(a))
            band = np.flatnonzero(pool & (np.abs(w - pred) < 3.0 * tol * w))
            if min_w > 0:  # by the line's depth, not the points' own (see PlaneConfig.range_margin)
                band = band[pred[band] * self._zscale[idx[band]] >= min_w]
            if len(band) < min_pts:
                failures += 1
                continue
            wb_ = w[band]
            sel = np.abs(wb_ - pred[band]) < 2.0 * tol * wb_
            xb, yb = pts.x[band], pts.y[band]
            plane = self._fit(xb, yb, wb_, sel, tol, xb if vertical else yb, vertical and c.layer_step)
            if not self._acceptable(plane, vertical, max_tilt_deg):
                failures += 1
                continue
            plane.kind = WALL if vertical else HORIZONTAL
            # Points within twice the tolerance are explained (noise tails would otherwise
            # seed parallel ghost planes); the plane keeps its strict inliers.
            q = plane.normal / plane.offset
            pool[band[np.abs(wb_ - (xb * q[0] + yb * q[1] + q[2])) < 2.0 * tol * wb_]] = False
            self._finish(plane, xb if vertical else yb)
            plane.inliers = idx[band[plane.inliers]]
            planes.append(plane)
        return planes

    def _histogram_cells(self, idx, w, u, ubin_all):
        """Peaks of the (image row or column, inverse depth) histogram: ``(count (C,),
        mean w (C,), mean u (C,))`` of the cells, or None when no cell is a peak."""
        c = self.config
        nb, nw = c.n_image_bins, c.n_invdepth_bins
        w0, w1 = self._wr
        wb = ((w - w0) * (nw / (w1 - w0))).astype(np.int32)
        np.minimum(wb, nw - 1, out=wb)
        flat = ubin_all[idx] * nw + wb
        cnt = np.bincount(flat, minlength=nb * nw).reshape(nb, nw).astype(np.float32)
        # Per row/column: local maxima of the count summed over 3 inverse-depth bins.
        c3 = _box3(cnt)
        peak = c3 >= c.min_cell_count
        peak[:, 1:] &= c3[:, 1:] >= c3[:, :-1]
        peak[:, :-1] &= c3[:, :-1] > c3[:, 1:]
        ci, cj = np.nonzero(peak)
        if len(ci) == 0:
            return None
        # Cell means of w and u over the same 3 bins.
        sw = np.bincount(flat, weights=w, minlength=nb * nw).reshape(nb, nw)
        su = np.bincount(flat, weights=u, minlength=nb * nw).reshape(nb, nw)
        cw = c3[ci, cj].astype(np.float64)
        jl, jr = np.maximum(cj - 1, 0), np.minimum(cj + 1, nw - 1)
        cell_w = (sw[ci, cj] + sw[ci, jl] * (cj > 0) + sw[ci, jr] * (cj < nw - 1)) / cw
        cell_u = (su[ci, cj] + su[ci, jl] * (cj > 0) + su[ci, jr] * (cj < nw - 1)) / cw
        return cw, cell_w, cell_u

    def _hough_bins(self, cell_w, cell_u, angles):
        """Hough vote: each cell, for each orientation a, proposes log(1/d) = log w - log(u sin a + cos a).
        Returns ``(accumulator index (C, A) or -1, log(1/d) origin, bin width, bins)``."""
        den = (cell_u[:, None] * np.sin(angles)[None, :] + np.cos(angles)[None, :]).astype(np.float32)
        ok = den > 0.05
        lbin_w = math.log1p(self.config.inlier_rel_depth)
        lo = math.log(1.0 / 30.0)
        nd = int(math.ceil((math.log(1.0 / 0.1) - lo) / lbin_w))
        logd = (np.log(cell_w).astype(np.float32) - lo)[:, None] - np.log(np.where(ok, den, 1.0))
        dbin = (logd * np.float32(1.0 / lbin_w)).astype(np.int32)
        ok &= (logd >= 0) & (dbin < nd)
        vote_idx = np.where(ok, np.arange(len(angles), dtype=np.int32)[None, :] * nd + dbin, -1)
        return vote_idx, lo, lbin_w, nd

    def _fit(self, x, y, w, sel, tol, u, layers: bool = False) -> Plane | None:
        """Least-squares ``w = q . (x, y, 1)`` over ``sel``, refitted on its own inliers.

        ``x, y, w``: (K,) candidate points; returns a Plane whose ``inliers`` index them.
        ``u``: (K,) the levelled image coordinate the plane's depth varies along (``x`` for
        walls, ``y`` for floors): lines of constant ``u`` lie on the plane at one depth.
        ``layers``: the last fit may hold two parallel layers in sections along ``u``
        (:func:`_layer_step`, :meth:`_fit_layers`).
        The normal equations are accumulated with masked dot products (no copies).
        """
        q = None
        thr = tol
        rel = None

        def normal_equations(sel):
            m = sel.astype(np.float64)
            xm, ym = x * m, y * m
            sx, sy, n = xm.sum(), ym.sum(), m.sum()
            sxy = xm @ y
            AtA = np.array([[xm @ x, sxy, sx], [sxy, ym @ y, sy], [sx, sy, n]])
            return AtA, np.array([xm @ w, ym @ w, m @ w]), n

        for it in range(self.config.refit_iterations + 1):
            AtA, Atb, n = normal_equations(sel)
            if n < 10:
                return None
            try:
                q = np.linalg.solve(AtA, Atb)
            except np.linalg.LinAlgError:
                return None
            rel = 1.0 - (x * q[0] + y * q[1] + q[2]) / w
            if it == 0:
                sel = np.abs(rel) < thr  # relative depth error within the band
                continue
            # Then keep the dominant layer only: doors and posters a centimetre proud of a
            # wall are parallel layers inside the band, and one fit across both tilts the
            # wall by tenths of a degree (see _dominant_layer).
            res = w * rel  # inverse-depth residual (1/m), roughly uniform noise (see above)
            sel = _dominant_layer(u, res, sel, self.config.refit_sigmas, tol * _median(w[sel]))
        k = np.flatnonzero(sel)
        if len(k) < 10:
            return None
        layered = _layer_step(u, w * rel, w, sel) if layers else None
        if layered is not None:
            return self._fit_layers(x, y, w, *layered, sel)
        r = w[k] * rel[k]
        s2 = float(r @ r) / max(len(k) - 3, 1)
        try:
            cov = s2 * np.linalg.inv(normal_equations(sel)[0])
        except np.linalg.LinAlgError:
            return None
        nq = float(np.linalg.norm(q))
        if not nq > 0:
            return None
        return Plane(kind="", normal=q / nq, offset=1.0 / nq, support=len(k) / self.n_total,
                     n_points=len(k), rms=math.sqrt(s2), cov_q=cov, inliers=k,
                     rms_rel=float(np.sqrt(np.mean(rel[k] ** 2))))

    def _fit_layers(self, x, y, w, keep: np.ndarray, sections: list[np.ndarray],
                    sel: np.ndarray) -> Plane | None:
        """Least squares ``w = q . (x, y, 1) + w sum_i eps_i s_i`` over ``keep`` (K,) bool,
        ``s_i`` the ``sections`` ((K,) bool each) of the other layers: one normal and each
        section's relative offset ``eps_i`` (a layer ``delta`` proud of a plane at distance
        ``d`` has inverse depths ``d / (d - delta)`` times the plane's). The covariance is
        the whole fit's, so the tilt's sigma grows by what the offsets take from it.

        The distance is the single fit's over ``sel`` (K,) bool (the inliers of both
        layers), at the new normal: which layer holds the most points changes from frame to
        frame as the camera moves, and wall offsets are differenced between frames (a wall
        read 4-10 mm nearer in one frame than the last reads as a step of that much; on the
        tuning seeds the direction-plus-point steps' forward errors went 1.5 -> 1.9 sigmas
        RMS with the most points' layer as the plane)."""
        k = np.flatnonzero(keep)
        if len(k) < 10:
            return None
        cols = [x[k], y[k], np.ones(len(k))]
        for sec in sections:
            sk = sec[k]
            if 10 <= int(sk.sum()) <= len(k) - 10:  # else the edges took (nearly) all of a layer
                cols.append(w[k] * sk)
        A = np.stack(cols, axis=1)
        AtA = A.T @ A
        try:
            sol = np.linalg.solve(AtA, A.T @ w[k])
            cov = np.linalg.inv(AtA)[:3, :3]
        except np.linalg.LinAlgError:
            return None
        res = w[k] - A @ sol
        s2 = float(res @ res) / max(len(k) - A.shape[1], 1)
        q, cov = sol[:3], s2 * cov
        nq = float(np.linalg.norm(q))
        if not nq > 0:
            return None
        j = np.flatnonzero(sel)
        a = (x[j] * q[0] + y[j] * q[1] + q[2]) / nq  # n . (x, y, 1): w = a / d
        aa = float(a @ a)
        if not aa > 0:
            return None
        q = q / nq * (float(a @ w[j]) / aa)
        nq = float(np.linalg.norm(q))
        if not nq > 0:
            return None
        # support, extent and the residuals' spread are the single fit's too (all inliers)
        rel = 1.0 - (x[j] * q[0] + y[j] * q[1] + q[2]) / w[j]
        return Plane(kind="", normal=q / nq, offset=1.0 / nq, support=len(j) / self.n_total,
                     n_points=len(j), rms=math.sqrt(s2), cov_q=cov, inliers=j,
                     rms_rel=float(np.sqrt(np.mean(rel * rel))))


#: Columns (bands of the levelled image x) of a wall's inliers that count towards its
#: width hold at least this fraction of the fullest band's inliers.
_SOLID_FRACTION = 0.25


def _solid_runs(u: np.ndarray, lo: float, hi: float, bands: int = 32, max_gap: int = 2) -> list[tuple[float, float]]:
    """The parts ``[(a, b), ...]`` of ``[lo, hi]`` covered by solid bands of ``u`` (K,):
    bands holding at least ``_SOLID_FRACTION`` of the fullest band's points, runs
    bridging at most ``max_gap`` bands without.

    A vertical plane's inliers also take whatever lies on its extension within the depth
    tolerance -- another box face in line with it, the thin strips where it crosses the
    floor -- so the inliers of a 0.4 m box face can span two metres. A surface fills its
    columns; the strips fill a few rows. The runs are kept apart: their widths add up
    without the gaps between them (a door taken out as its own layer, pillars in a row).
    """
    if not hi > lo or len(u) == 0:
        return [(lo, hi)]
    n = np.bincount(np.clip(((u - lo) * (bands / (hi - lo))).astype(np.int64), 0, bands - 1), minlength=bands)
    k = np.flatnonzero(n >= _SOLID_FRACTION * n.max())
    cuts = np.flatnonzero(np.diff(k) > max_gap + 1)
    starts, ends = np.r_[k[0], k[cuts + 1]], np.r_[k[cuts], k[-1]]
    step = (hi - lo) / bands
    return [(lo + step * a, lo + step * (b + 1)) for a, b in zip(starts, ends)]


def wall_width(normal: np.ndarray, offset: float, lo: float, hi: float, max_depth: float) -> float:
    """Horizontal distance (m) between the points of a vertical plane seen at levelled
    image x coordinates ``lo`` and ``hi`` (normalised, X / Z): the rays ``(u, 1) Z`` meet
    the wall's trace ``n_x X + n_z Z = offset`` at ``Z = offset / (n_x u + n_z)``. Depths
    beyond ``max_depth`` (a ray grazing the wall) are cut there.
    """
    pts = []
    for u in (lo, hi):
        den = normal[0] * u + normal[2]
        z = offset / den if den > offset / max_depth else max_depth
        pts.append((u * z, z))
    return float(math.hypot(pts[1][0] - pts[0][0], pts[1][1] - pts[0][1]))


@dataclass
class _Points:
    """Valid grid samples of one frame: grid index, inverse depth, levelled x and y."""

    idx: np.ndarray
    w: np.ndarray
    x: np.ndarray
    y: np.ndarray

    def subset(self, keep: np.ndarray) -> "_Points":
        return _Points(self.idx[keep], self.w[keep], self.x[keep], self.y[keep])


def _votes(vote_idx: np.ndarray, weight: np.ndarray, size: int) -> np.ndarray:
    """Hough accumulator (size,) float64: each row of ``vote_idx`` (C, A) int32 (-1: no vote)
    votes ``weight`` (C,) into its bins."""
    m = vote_idx >= 0
    return np.bincount(vote_idx[m], weights=np.broadcast_to(weight[:, None], vote_idx.shape)[m],
                       minlength=size)


#: Frames over which the sensor's range is learnt (PlaneDetector._learn_range).
_RANGE_FRAMES = 100
_RANGE_MIN_FRAMES = 10

#: Quantiles of the inliers' image coordinate that bound a plane's angular extent.
_EXTENT_QUANTILES = np.array([2.0, 98.0]) / 100.0


def _percentiles(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``np.quantile(a, q)`` (linear interpolation) of a 1-D float array, bit for bit.

    ``q`` (Q,) float64 fractions in [0, 1]; the interpolation is numpy's, including its
    switch to ``b - (b - a) (1 - t)`` above ``t = 0.5``.
    """
    n = a.size
    v = (n - 1) * q
    lo = np.floor(v).astype(np.intp)
    hi = lo + 1
    top = v >= n - 1
    lo[top] = -1
    hi[top] = -1
    part = np.partition(a, np.unique(np.concatenate(([0, -1], lo, hi))))
    if np.isnan(part[-1]):
        return np.full(len(q), np.nan)
    x0, x1 = part[lo], part[hi]
    t = v - lo
    d = x1 - x0
    return np.where(t >= 0.5, x1 - d * (1 - t), x0 + d * t)



def _median(a: np.ndarray) -> float:
    """``np.median`` of a 1-D float array, bit for bit, without its general-axis overhead
    (plane refits call it several times per plane)."""
    n = a.size
    if n == 0:
        return float("nan")
    k = n // 2
    part = np.partition(a, [k - 1, k, n - 1] if n % 2 == 0 else [k, n - 1])
    if np.isnan(part[-1]):
        return float("nan")
    return float(part[k]) if n % 2 else float((part[k - 1] + part[k]) / 2.0)


def _band_medians(r: np.ndarray, band: np.ndarray, count: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Per band, the value of rank ``count // 2`` of ``r`` (K,) among the points of that band
    (``band`` (K,) int; ``count`` (B,) points per band, ``which`` (B,) bool bands wanted).

    The same values as sorting the points by (band, r), for the price of a stable integer
    sort (a radix sort on bytes) and one small partition per band.
    """
    key = band.astype(np.uint8) if len(count) <= 256 else band
    rb = r[np.argsort(key, kind="stable")]  # a fresh array: partitioned in place, band by band
    ends, counts = np.cumsum(count).tolist(), count.tolist()
    out = []
    for i in np.flatnonzero(which).tolist():
        seg = rb[ends[i] - counts[i]:ends[i]]
        seg.partition(counts[i] // 2)
        out.append(seg[counts[i] // 2])
    return np.array(out, dtype=np.float64)


@functools.lru_cache(maxsize=64)
def _pairs(m: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(m, 1)``, cached (read-only): every pair of ``m`` bands."""
    ia, ib = np.triu_indices(m, 1)
    ia.flags.writeable = ib.flags.writeable = False
    return ia, ib


#: Inliers sampled for the dominant-layer statistics of one plane fit.
_LAYER_SAMPLES = 8192
_SIGMA_SAMPLES = 4096


def _residual_sample(r: np.ndarray, sel: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(idx, r[idx], sigma)``: an evenly spread subsample of the inliers ``sel`` (K,) bool
    (indices, residuals ``r`` (K,)) and the residuals' noise sigma.

    The statistics of a plane's layers come from subsamples, so their cost stops growing
    with the plane: the noise sigma from ~_SIGMA_SAMPLES differences of consecutive samples
    (grid neighbours, nearly always on one surface, so a second layer does not inflate it;
    2 % precision), the band medians from ~_LAYER_SAMPLES inliers (~170 a band; fewer let a
    door shift the consensus). Selections made from them still cover every point.
    """
    idx = np.flatnonzero(sel)
    n_sel = len(idx)
    rs = r[idx]
    step = -(-n_sel // _SIGMA_SAMPLES)
    sig_d = rs[1::step] - rs[:-1:step]  # consecutive grid samples (neighbours), every step-th pair
    step = -(-n_sel // _LAYER_SAMPLES)
    if step > 1:
        idx = idx[::step]
        rs = rs[::step]
    sig = 1.4826 / math.sqrt(2.0) * _median(np.abs(sig_d)) if len(sig_d) > 10 else 0.0
    return idx, rs, sig


def _band_of(u: np.ndarray, lo: float, scale: float, nb: int) -> np.ndarray:
    """Band (K,) int64 of every point ``u`` (K,): ``(u - lo) scale`` truncated, clipped to
    ``[0, nb)`` (the points outside the sample's range fall in the end bands)."""
    t = u - lo
    t *= scale
    band = t.astype(np.int64)
    return np.clip(band, 0, nb - 1, out=band)


def _dominant_layer(u: np.ndarray, r: np.ndarray, sel: np.ndarray, k: float, max_half: float) -> np.ndarray:
    """Points (K,) bool of the dominant layer of a plane fit's residuals.

    ``u`` (K,): image coordinate along which the plane's depth varies; ``r`` (K,): residuals
    (inverse depth, 1/m) in grid order; ``sel`` (K,) bool: current inliers. A layer proud of
    the plane (a door) covers whole lines of constant ``u`` (door edges are vertical, and
    vertical lines are columns in the levelled image), so the residuals are summarised per
    band of ``u`` by their median -- precise to ``sigma / sqrt(n)`` -- and a consensus line
    through those medians (every pair of bands tried, bands weighted by their points)
    picks the layer with the most support; a fit's tilt error is linear in ``u``, a second
    layer is not on that line. Points of the consensus bands within ``k`` sigmas of the
    fit (at most ``max_half``) are kept. The noise sigma comes from differences of
    consecutive samples -- grid neighbours, nearly always on one surface -- so a second
    layer does not inflate it as it inflates the residuals' own spread.
    """
    n_sel = int(sel.sum())
    idx, rs, sig = _residual_sample(r, sel)
    half = min(max_half, max(0.1 * max_half, k * sig))
    us = u[idx]
    lo, hi = float(us.min()), float(us.max())
    nb = int(min(48, max(4, n_sel // 60)))
    if not (sig > 0 and hi > lo):
        return sel & (np.abs(r) < half)
    b = np.minimum(((us - lo) * (nb / (hi - lo))).astype(np.int64), nb - 1)
    n = np.bincount(b, minlength=nb)
    full = n >= 5
    med = _band_medians(rs, b, n, full)
    uc = np.bincount(b, weights=us, minlength=nb)[full] / n[full]
    nf = n[full].astype(np.float64)
    # 3 sigmas of a band median; at least 0.1 % of the inverse depth (1 mm per metre of
    # depth, far below a door's offset), so noise-free data keeps every band
    tau = np.maximum(3.0 * 1.2533 * sig / np.sqrt(nf), 0.03 * max_half)
    m = len(med)
    if m < 3:
        return sel & (np.abs(r) < half)
    ia, ib = _pairs(m)
    slope = (med[ib] - med[ia]) / (uc[ib] - uc[ia])
    icpt = med[ia] - slope * uc[ia]
    d = slope[:, None] * uc[None, :]  # |med - (icpt + slope uc)| per (pair, band), in place
    d += icpt[:, None]
    np.subtract(med[None, :], d, out=d)
    inl = np.abs(d, out=d) < tau[None, :]
    # the bands' weights are whole counts (< 2^24): float32 sums are exact, the argmax the same
    best = int(np.argmax(inl.astype(np.float32) @ nf.astype(np.float32)))
    good = np.zeros(nb, bool)
    good[np.flatnonzero(full)[inl[best]]] = True
    bin_all = _band_of(u, lo, nb / (hi - lo), nb)
    # Around the fit itself, not the consensus line: the line is only as good as the band
    # medians, and a band cut around a slightly wrong line would bias the refit towards it.
    return good[bin_all] & (np.abs(r) < half)

#: A wall's fit takes another layer (_layer_step) when that section's offset removes at
#: least this much of the band medians' misfit (chi-square in band-median noise units; on
#: 48 bands of pure noise the best of the ~1000 sections gains 7 in the median draw, 17 in
#: the 99th percentile) and moves the section by at least this fraction of its inverse
#: depth (1 mm a metre; doors and posters stand 3-10 mm proud); at most this many sections.
_STEP_MIN_CHI2 = 25.0
_STEP_MIN_REL = 1e-3
_STEP_MAX_SECTIONS = 3
#: A section spans at least this many bands (of up to 48), and the base layer keeps at
#: least this share of the wall's weight.
_STEP_MIN_BANDS = 2
_STEP_BASE_SHARE = 0.25


def _layer_step(u: np.ndarray, r: np.ndarray, w: np.ndarray, sel: np.ndarray):
    """Parallel layers in contiguous sections of a plane fit's inliers, or None.

    ``u`` (K,): image coordinate along which the plane's depth varies; ``r`` (K,): residuals
    (inverse depth, 1/m); ``w`` (K,): inverse depths; ``sel`` (K,) bool: the inliers.
    Returns ``(keep, sections)``: ``keep`` (K,) bool, the inliers without the bands either
    side of each section's edges (an edge falls inside a band, whose points are of both
    layers), and ``sections``, a list of (K,) bool, each section's points.

    :func:`_dominant_layer` drops a layer whose bands are off the consensus line, but layers
    of similar support each holding one part of an oblique wall give nearly collinear band
    medians: the line through them is tilted by their offsets over their separation (a door
    10 mm proud at 2.2 m tilted a held-out wall by 0.2-0.44 deg). A layer is a constant
    relative offset, a tilt is linear in ``u``: the band medians are fitted as a line plus
    ``eps w`` over contiguous sections of bands, added one at a time (the section that
    removes the most misfit, while it removes ``_STEP_MIN_CHI2`` and moves ``_STEP_MIN_REL``),
    so the tilt comes from within the layers. A wall without a clear step keeps the single
    plane and the precision of its whole extent.
    """
    bands = _layer_bands(u, r, w, sel)
    if bands is None:
        return None
    med, uc, zc, W, full, lo, hi = bands
    m = len(med)
    a, b = _sections(m)
    chosen = _layer_sections(med, uc, zc, W, a, b) if len(a) else []
    if not chosen:
        return None
    fb = np.flatnonzero(full)
    nb = len(full)
    bin_all = _band_of(u, lo, nb / (hi - lo), nb)
    keep, sections = sel.copy(), []
    for c in chosen:
        first, last = int(fb[a[c]]), int(fb[b[c] - 1])
        sections.append(sel & (bin_all >= first) & (bin_all <= last))
        edges = ([first - 1, first] if a[c] > 0 else []) + ([last, last + 1] if b[c] < m else [])
        keep &= ~np.isin(bin_all, edges)
    return keep, sections


@functools.lru_cache(maxsize=64)
def _sections(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Every section ``[a, b)`` of ``m`` bands holding at least ``_STEP_MIN_BANDS`` of them
    and leaving as many outside: ``(a, b)`` (S,) int each, cached (read-only)."""
    a, b = np.triu_indices(m + 1, _STEP_MIN_BANDS)
    ok = b - a <= m - _STEP_MIN_BANDS
    a, b = a[ok], b[ok]
    a.flags.writeable = b.flags.writeable = False
    return a, b


def _layer_bands(u: np.ndarray, r: np.ndarray, w: np.ndarray, sel: np.ndarray):
    """The inliers' residuals summarised in bands of ``u`` (as :func:`_dominant_layer`):
    ``(median residual, centred mean u, mean w, inverse variance of the median)`` (M,) each
    over the bands holding at least 5 samples, the (B,) bool of those bands, and the ``u``
    range ``lo, hi`` the B bands divide; None when there are too few points or bands."""
    n_sel = int(sel.sum())
    if n_sel < 400:
        return None
    idx, rs, sig = _residual_sample(r, sel)
    us, ws = u[idx], w[idx]
    lo, hi = float(us.min()), float(us.max())
    nb = int(min(48, max(4, n_sel // 60)))
    if not (sig > 0 and hi > lo):
        return None
    b = np.minimum(((us - lo) * (nb / (hi - lo))).astype(np.int64), nb - 1)
    n = np.bincount(b, minlength=nb)
    full = n >= 5
    if int(full.sum()) < 6:
        return None
    med = _band_medians(rs, b, n, full)
    nf = n[full].astype(np.float64)
    uc = np.bincount(b, weights=us, minlength=nb)[full] / nf
    zc = np.bincount(b, weights=ws, minlength=nb)[full] / nf  # a layer's offset is eps w
    W = nf / (1.2533 * sig) ** 2
    return med, uc - uc.mean(), zc, W, full, lo, hi


def _layer_sections(med, uc, zc, W, a: np.ndarray, b: np.ndarray) -> list[int]:
    """Greedy choice among the band sections ``[a, b)`` (S,) int: the weighted least squares
    of ``med`` on ``(1, uc)`` plus ``zc`` over each chosen section, sections added while the
    best one removes ``_STEP_MIN_CHI2`` of the misfit and moves ``_STEP_MIN_REL``. Returns
    the chosen indices into ``a, b``."""
    m = len(med)

    def seg(v):
        c = np.concatenate(([0.0], np.cumsum(v)))
        return c[b] - c[a]

    X = np.stack([np.ones(m), uc], axis=1)  # (m, p) regressors so far
    chosen: list[int] = []
    used = np.zeros(m)
    czz = seg(W * zc * zc)
    Wt = float(W.sum())
    wz = W * zc
    cw_cols = [seg(wz * X[:, j]) for j in range(X.shape[1])]  # c'W x_j per section, per column
    while len(chosen) < _STEP_MAX_SECTIONS:
        # Sections are disjoint and leave the base layer a share of the wall (a sum of
        # sections covering it all is the line itself, w being linear in u along a wall;
        # one leaving only the ends' bands took a held-out wall's ends, where it meets
        # the next wall, for a layer and tilted it by 0.76 deg)
        free = (seg(used) == 0) & (Wt - seg(W) - float(W @ used) >= _STEP_BASE_SHARE * Wt)
        XtW = X.T * W
        try:
            M = np.linalg.inv(XtW @ X)
        except np.linalg.LinAlgError:
            break
        res = med - X @ (M @ (XtW @ med))
        if float(res @ (W * res)) < _STEP_MIN_CHI2:
            break  # no section can remove more misfit than there is
        # adding the column c = zc over [a, b): the misfit drops by (c'W res)^2 / (c'W c - c'W X M X'W c)
        num = seg(wz * res)
        cwx = np.stack(cw_cols, axis=1)  # (S, p)
        den = czz - np.einsum("sp,pq,sq->s", cwx, M, cwx)
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.where(free & (den > 0.05 * czz), num * num / den, 0.0)
        best = int(np.argmax(gain))
        if not (gain[best] >= _STEP_MIN_CHI2 and abs(num[best] / den[best]) >= _STEP_MIN_REL):
            break
        chosen.append(best)
        used[a[best]:b[best]] = 1.0
        col = np.zeros(m)
        col[a[best]:b[best]] = zc[a[best]:b[best]]
        X = np.column_stack([X, col])
        cw_cols.append(seg(wz * col))
    return chosen


def _box3(a: np.ndarray) -> np.ndarray:
    """Sum over 3 neighbouring bins along the last axis (zero padded)."""
    out = a.copy()
    out[:, 1:] += a[:, :-1]
    out[:, :-1] += a[:, 1:]
    return out
