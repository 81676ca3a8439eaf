"""Corners in the colour image, associated between consecutive frames and lifted to 3-D.

Two interchangeable methods (``FeatureConfig.method``):

* ``"klt"``: Shi-Tomasi corners tracked with pyramidal Lucas-Kanade (forward-backward
  checked); survivors are kept and the set is topped up with new corners only where the
  image has none, so most frames skip detection. A gain change between the frames
  (auto-exposure, flicker), measured at the tracked corners, is undone before a second
  tracking pass, since LK assumes constant brightness.
* ``"orb"``: ORB keypoints and descriptors, mutual nearest neighbours in Hamming distance.

Pixel positions are undistorted with the calibration (``cv2.undistortPoints``, iterated to convergence, when the
distortion is non-zero) and lifted with the depth of a small neighbourhood, rejecting
depth edges. Points stay in the camera frame here; levelling is the caller's step.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from planar_vo.frontend.config import DEFAULT_DEPTH_RANGE, FeatureConfig
from planar_vo.core.types import CameraIntrinsics

#: Iterations of the undistortion fixed point: OpenCV's default 5 leave ~0.01 px in the
#: corners of strongly distorted lenses (Kinect v1 k3 = 1.16).
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)


@dataclass
class FeatureSet:
    """Corners of one frame.

    ``px``: (N, 2) float32 pixel positions (as measured, distorted). ``xy``: (N, 2) float64
    undistorted normalised camera coordinates. ``P_cam``: (N, 3) float64 camera-frame points
    (metres), NaN rows where the depth is missing or on an edge. ``desc``: (N, 32) uint8 ORB
    descriptors or None (klt). ``unread``: (N,) bool, no depth reading around the corner at
    all (:func:`unread`: beyond the range), or None.
    """

    px: np.ndarray
    xy: np.ndarray
    P_cam: np.ndarray
    desc: np.ndarray | None = None
    unread: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.px)


def undistort(px: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Normalised camera coordinates (N, 2) float64 of pixels ``px`` (N, 2)."""
    px = np.asarray(px, dtype=np.float64).reshape(-1, 2)
    if len(px) == 0:
        return np.zeros((0, 2))
    if intrinsics.has_distortion:
        return cv2.undistortPoints(px.reshape(-1, 1, 2), intrinsics.K,
                                   np.asarray(intrinsics.distortion, np.float64),
                                   R=np.eye(3), P=np.eye(3), criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
    return np.column_stack([(px[:, 0] - intrinsics.cx) / intrinsics.fx,
                            (px[:, 1] - intrinsics.cy) / intrinsics.fy])


def lift(px: np.ndarray, xy: np.ndarray, depth: np.ndarray, config: FeatureConfig,
         depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE) -> np.ndarray:
    """3-D points (N, 3) float64 in the camera frame, NaN where depth is unusable.

    Depth is read at the pixel nearest to ``px`` (N, 2) (the mean of its readable neighbours
    if it has no reading itself); a ``(2 w + 1)^2`` window whose readings spread by more
    than ``depth_edge_rel`` of that depth straddles a depth edge and is rejected, as are
    windows with fewer than half of their readings valid.
    """
    n = len(px)
    out = np.full((n, 3), np.nan)
    if n == 0:
        return out
    h, w = depth.shape
    win = _depth_windows(px, depth, config.depth_window).astype(np.float64)
    ok = (win >= depth_range[0]) & (win <= depth_range[1])
    centre = win[:, win.shape[1] // 2]
    # Depth of the pixel itself when readable, else the mean of the readable neighbours.
    cnt = ok.sum(1)
    mean = np.where(ok, win, 0.0).sum(1) / np.maximum(cnt, 1)
    z = np.where(ok[:, win.shape[1] // 2], centre, mean)
    spread = np.where(ok, win, -np.inf).max(1) - np.where(ok, win, np.inf).min(1)
    good = (cnt * 2 > win.shape[1]) & (spread <= config.depth_edge_rel * z)
    # Points projected outside the image (clipped above) have no depth of their own.
    inside = (px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
    good &= inside
    out[good, 0] = xy[good, 0] * z[good]
    out[good, 1] = xy[good, 1] * z[good]
    out[good, 2] = z[good]
    return out


def unread(px: np.ndarray, depth: np.ndarray, config: FeatureConfig,
           depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE) -> np.ndarray:
    """(N,) bool: corners ``px`` (N, 2) whose depth window (:func:`lift`'s) holds no reading
    within ``depth_range`` -- beyond the sensor's range, not on a depth edge (where some
    readings are there and disagree). Far corners (frontend/farcorners.py) are these."""
    if len(px) == 0:
        return np.zeros(0, bool)
    win = _depth_windows(px, depth, config.depth_window)
    return ~((win >= depth_range[0]) & (win <= depth_range[1])).any(1)


def _depth_windows(px: np.ndarray, depth: np.ndarray, r: int) -> np.ndarray:
    """(N, (2 r + 1)^2) depth readings around the pixels nearest to ``px`` (N, 2) (N > 0),
    the windows kept inside the image."""
    h, w = depth.shape
    cols = np.clip(np.rint(px[:, 0]).astype(np.int64), r, w - 1 - r)
    rows = np.clip(np.rint(px[:, 1]).astype(np.int64), r, h - 1 - r)
    off = np.arange(-r, r + 1)
    win = depth[rows[:, None, None] + off[None, :, None], cols[:, None, None] + off[None, None, :]]
    return win.reshape(len(px), -1)


def straddles_depth_jump(px: np.ndarray, depth: np.ndarray, half: int, max_rel: float,
                         depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE) -> np.ndarray:
    """True (N,) where the ``(2 half + 1)^2`` window around pixel ``px`` (N, 2) spans a
    depth discontinuity: the readings' inverse depth, less its least-squares plane in the
    pixel coordinates (a planar surface's inverse depth is affine in them, slanted floors
    included), spreads by more than ``max_rel`` of the centre's.

    LK tracks the window as one image motion. A window holding a near edge and the
    surface behind it holds two (parallax), and its corner -- mostly a T-junction where
    a box's silhouette crosses the skirting or the grout behind it, the strongest corners
    of a plain corridor -- is no world point: it slides along the edge. On the
    low-texture tuning logs such corners moved 2-6 px a frame beyond their true motion,
    each making its direction-plus-point candidate ~13 mm (half a step) long, and with
    6-9 inliers two or three of them made the steps 15-30 % long, all the same way.
    Readings outside ``depth_range`` (m) are left out; ``depth`` (H, W) float32 m.
    """
    n = len(px)
    if n == 0 or half <= 0:
        return np.zeros(n, bool)
    A, AA, A_T = _window_design(half)
    win = _patches(depth, px, half).reshape(n, -1)
    if win.dtype != np.float32:
        win = win.astype(np.float32)
    ok = (win >= depth_range[0]) & (win <= depth_range[1])
    inv = np.zeros(win.shape, np.float32)
    np.divide(np.float32(1.0), win, out=inv, where=ok)
    wt = ok.astype(np.float32)
    M = (wt @ AA).reshape(n, 3, 3) + np.eye(3) * 1e-9
    coef = np.linalg.solve(M, ((wt * inv) @ A)[..., None])[..., 0]
    res = inv - coef @ A_T
    res /= np.maximum(np.abs(coef[:, :1]), 1e-12)
    spread = np.where(ok, res, -np.inf).max(1) - np.where(ok, res, np.inf).min(1)
    return (ok.sum(1) >= 4) & (spread > max_rel)


@functools.lru_cache(maxsize=8)
def _window_design(half: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plane-in-pixel-offsets design of a ``(2 half + 1)^2`` window, cached (read-only):
    ``A`` (K, 3) float32 rows ``[1, du, dv]``, ``AA`` (K, 9) float32 their outer products,
    ``A_T`` (3, K) float64."""
    off = np.arange(-half, half + 1)
    du, dv = np.meshgrid(off, off)
    A = np.stack([np.ones(du.size), du.ravel(), dv.ravel()], axis=1)
    out = (A.astype(np.float32), (A[:, :, None] * A[:, None, :]).reshape(-1, 9).astype(np.float32),
           np.ascontiguousarray(A.T))
    for a in out:
        a.flags.writeable = False
    return out


def _patches(img: np.ndarray, px: np.ndarray, half: int) -> np.ndarray:
    """``(N, 2 half + 1, 2 half + 1)`` pixels of ``img`` (H, W) around the rounded points
    ``px`` (N, 2), the patches moved inside the image at its border.

    One flat ``take`` of row-major offsets: several times faster than indexing with two
    broadcast index arrays, for the same values.
    """
    h, w = img.shape
    cols = np.clip(np.rint(px[:, 0]).astype(np.int64), half, w - 1 - half)
    rows = np.clip(np.rint(px[:, 1]).astype(np.int64), half, h - 1 - half)
    off = np.arange(-half, half + 1)
    flat = (off[:, None] * w + off[None, :]).ravel()
    return np.take(img.reshape(-1), (rows * w + cols)[:, None] + flat[None, :]).reshape(
        len(px), 2 * half + 1, 2 * half + 1)


def _corner_ratio(img: np.ndarray, pts: np.ndarray, half: int) -> np.ndarray:
    """Smaller over larger eigenvalue (N,) of the gradient structure tensor in a
    ``(2 half + 1)``-pixel square around each point (N, 2) of ``img``.

    An edge has one strong gradient direction (ratio near 0): tracked along itself it
    shows no motion, the aperture problem. Shi-Tomasi's threshold is relative to the
    strongest corner, so on plain floors grout lines with faint mottling pass it, and
    their sliding made every step ~40 % short (a low-texture tuning log).
    """
    if len(pts) == 0:
        return np.zeros(0)
    # OpenCV's 3 x 3 Sobel gradients, summed over the window by a box filter, both with the
    # image mirrored at its border (BORDER_REFLECT_101), evaluated at the points only: the
    # whole-image filters cost ~3 ms for the ~100 corners of a detection, this ~0.4 ms.
    h, w = img.shape
    c = np.clip(np.rint(pts[:, 0]).astype(np.int64), 0, w - 1)
    r = np.clip(np.rint(pts[:, 1]).astype(np.int64), 0, h - 1)
    off = np.arange(-half, half + 1)
    rows = _reflect101(r[:, None] + off, h)[:, :, None]  # (N, k, 1) window rows, mirrored
    cols = _reflect101(c[:, None] + off, w)[:, None, :]  # (N, 1, k)

    def at(dr, dc):  # (N, k, k) float32 image at the window pixels' neighbour (dr, dc)
        return img[_reflect101(rows + dr, h), _reflect101(cols + dc, w)].astype(np.float32)

    # Sobel: [1 2 1] across, [-1 0 1] along (integer-valued: exact in float32)
    up_l, up_r, dn_l, dn_r = at(-1, -1), at(-1, 1), at(1, -1), at(1, 1)
    gx = (up_r - up_l) + 2 * (at(0, 1) - at(0, -1)) + (dn_r - dn_l)
    gy = (dn_l + 2 * at(1, 0) + dn_r) - (up_l + 2 * at(-1, 0) + up_r)
    a, b, d = ((p * q).sum((1, 2), dtype=np.float64) for p, q in ((gx, gx), (gx, gy), (gy, gy)))
    root = np.sqrt((0.5 * (a - d)) ** 2 + b * b)
    mean = 0.5 * (a + d)
    return np.where(mean + root > 0, (mean - root) / np.maximum(mean + root, 1e-12), 0.0)


def _reflect101(i: np.ndarray, n: int) -> np.ndarray:
    """Indices ``i`` (any shape, int) into an axis of length ``n`` >= 2, mirrored at its
    ends without repeating the edge (OpenCV's BORDER_REFLECT_101: -1 -> 1, n -> n - 2)."""
    i = np.abs(i)
    return np.where(i > n - 1, 2 * (n - 1) - i, i)


def _corner_ratio_at(img: np.ndarray, pts: np.ndarray, half: int) -> np.ndarray:
    """:func:`_corner_ratio` (N,) from ``(2 half + 3)``-pixel patches around the points
    (N, 2) only (the same 3 x 3 Sobel gradients, summed over the inner ``(2 half + 1)``
    square), for the few hundred tracked corners of every frame: the whole-image filters
    cost several milliseconds at 960 x 540, the patches a fraction of one.
    """
    if len(pts) == 0:
        return np.zeros(0)
    P = _patches(img, pts, half + 1).astype(np.float32)
    # Sobel 3 x 3: smoothing [1 2 1] across, difference [-1 0 1] along
    sx = P[:, :, 2:] - P[:, :, :-2]
    gx = sx[:, :-2] + 2 * sx[:, 1:-1] + sx[:, 2:]
    sy = P[:, 2:, :] - P[:, :-2, :]
    gy = sy[:, :, :-2] + 2 * sy[:, :, 1:-1] + sy[:, :, 2:]
    a = (gx * gx).sum((1, 2), dtype=np.float64)
    b = (gx * gy).sum((1, 2), dtype=np.float64)
    d = (gy * gy).sum((1, 2), dtype=np.float64)
    root = np.sqrt((0.5 * (a - d)) ** 2 + b * b)
    mean = 0.5 * (a + d)
    return np.where(mean + root > 0, (mean - root) / np.maximum(mean + root, 1e-12), 0.0)


def _coarse_means(gray: np.ndarray) -> np.ndarray:
    """Local means (H/4, W/4) float32: a 7 x 7 box over the 4 x 4-averaged image."""
    h, w = gray.shape
    small = cv2.resize(gray, (max(w // 4, 1), max(h // 4, 1)), interpolation=cv2.INTER_AREA)
    return cv2.boxFilter(small, cv2.CV_32F, (7, 7))


def _sample_quarter(img: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Bilinear samples (K,) of a quarter-size image at full-resolution pixels ``px`` (K, 2)."""
    q = (px.astype(np.float32) + 0.5) * 0.25 - 0.5
    return cv2.remap(img, q[None, :, 0], q[None, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()


class FeatureTracker:
    """Frame-to-frame corner association for one camera.

    :meth:`process` takes each frame once and returns its :class:`FeatureSet` and the
    matches ``(M, 2) int64`` of indices ``[i_prev, i_curr]`` into the previous and current
    sets (empty for the first frame).
    """

    def __init__(self, intrinsics: CameraIntrinsics, config: FeatureConfig | None = None,
                 depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE):
        self.intrinsics = intrinsics
        self.config = config or FeatureConfig()
        self.depth_range = depth_range  # (min, max) m of readings lifted to 3-D
        c = self.config
        if c.method not in ("klt", "orb"):
            raise ValueError(f"features.method must be 'klt' or 'orb', got {c.method!r}")
        self._prev: FeatureSet | None = None
        self._prev_pyr = None
        self._win = (c.klt_window, c.klt_window)
        self._crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, c.klt_iterations, 0.03)
        self._subpix_crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.05)
        if c.method == "orb":
            self._orb = cv2.ORB_create(nfeatures=c.orb_features, fastThreshold=12)
            self._bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
        self.last_detected = 0  # corners newly detected in the last frame (diagnostics)
        self.last_gain = 1.0    # brightness ratio to the previous frame (diagnostics)
        self._prev_box = self._box = None  # coarse local means of the previous / current image

    def process(self, gray: np.ndarray, depth: np.ndarray) -> tuple[FeatureSet, np.ndarray]:
        """Associate ``gray`` (H, W) uint8 with the previous frame; ``depth`` (H, W) float32 m."""
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise ValueError(f"gray must be (H, W) uint8, got {gray.shape} {gray.dtype}")
        if self.config.method == "orb":
            return self._process_orb(gray, depth)
        return self._process_klt(gray, depth)

    # ----------------------------------------------------------------- KLT
    def _process_klt(self, gray, depth):
        c = self.config
        pyr = gray  # OpenCV's Python binding takes images only, not prebuilt pyramids
        prev = self._prev
        matches = np.zeros((0, 2), np.int64)
        kept_px = np.zeros((0, 2), np.float32)
        if prev is not None and len(prev):
            p0 = prev.px.reshape(-1, 1, 2)
            # minEigThreshold drops windows without two strong gradient directions (edges of
            # untextured surfaces slide along themselves and would fake "no motion").
            p1, st, _ = cv2.calcOpticalFlowPyrLK(self._prev_pyr, pyr, p0, None, winSize=self._win,
                                                 maxLevel=c.klt_levels, criteria=self._crit,
                                                 minEigThreshold=c.klt_min_eig)
            ok = st.reshape(-1) == 1
            gain = self._gain(gray, p0.reshape(-1, 2)[ok], p1.reshape(-1, 2)[ok]) if c.gain_tolerance > 0 else 1.0
            self.last_gain = gain
            if abs(gain - 1.0) > c.gain_tolerance:
                # LK has no gain term: bring this image to the previous one's brightness and
                # track again from the first result.
                pyr = cv2.convertScaleAbs(gray, alpha=1.0 / gain)
                p1, st, _ = cv2.calcOpticalFlowPyrLK(self._prev_pyr, pyr, p0, p1, winSize=self._win,
                                                     maxLevel=c.klt_levels, criteria=self._crit,
                                                     flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
                                                     minEigThreshold=c.klt_min_eig)
                ok = st.reshape(-1) == 1
            if c.fb_check and ok.any():
                # Backward from the forward result, seeded with the forward motion.
                p0b, stb, _ = cv2.calcOpticalFlowPyrLK(pyr, self._prev_pyr, p1, p0.copy(), winSize=self._win,
                                                       maxLevel=c.klt_levels, criteria=self._crit,
                                                       flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
                                                       minEigThreshold=c.klt_min_eig)
                fb = np.linalg.norm((p0b - p0).reshape(-1, 2), axis=1)
                ok &= (stb.reshape(-1) == 1) & (fb <= c.fb_max_px)
            p1 = p1.reshape(-1, 2)
            h, w = gray.shape
            ok &= (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
            if c.min_corner_ratio > 0 and ok.any():
                # A corner found far away can turn into an edge as the camera nears it (a
                # grout-line crossing seen close up): LK then slides along the edge. Each
                # tracked corner is checked again in the window LK will use next.
                ok[ok] = _corner_ratio_at(gray, p1[ok], c.klt_window // 2) >= c.min_corner_ratio
            i_prev = np.flatnonzero(ok)
            kept_px = p1[i_prev].astype(np.float32)
            matches = np.column_stack([i_prev, np.arange(len(i_prev))]).astype(np.int64)
        new_px = self._detect_klt(gray, kept_px)
        self.last_detected = len(new_px)
        px = np.vstack([kept_px, new_px]) if len(new_px) else kept_px
        cur = self._make_set(px, depth)
        # the next frame is tracked against this one as captured (its gain is relative to it)
        self._prev, self._prev_pyr = cur, gray
        self._prev_box, self._box = self._box, None
        return cur, matches

    def _gain(self, gray: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> float:
        """Brightness ratio current / previous: the median over tracked corners (K, 2) of
        the ratio of their ~28 x 28 neighbourhood means (wide enough that LK's own
        gain-induced position bias hardly moves them; 7 x 7 box on a quarter-size image),
        sampled bilinearly. 1.0 with fewer than 8 usable corners."""
        if len(p0) < 8:
            return 1.0
        if self._prev_box is None:
            self._prev_box = _coarse_means(self._prev_pyr)
        box = self._box = _coarse_means(gray)
        a = _sample_quarter(self._prev_box, p0)
        b = _sample_quarter(box, p1)
        use = (a > 8) & (a < 247) & (b > 8) & (b < 247)  # saturated or black: no information
        if use.sum() < 8:
            return 1.0
        return float(np.median(b[use] / a[use]))

    def _detect_klt(self, gray, existing):
        """New Shi-Tomasi corners away from ``existing`` (K, 2), up to ``max_corners`` in all."""
        c = self.config
        want = c.max_corners - len(existing)
        # Top up only when the set has thinned noticeably: detection dominates KLT's cost.
        if want < 0.25 * c.max_corners and len(existing):
            return np.zeros((0, 2), np.float32)
        mask = None
        if len(existing):
            mask = np.full(gray.shape, 255, np.uint8)
            for x, y in np.rint(existing).astype(np.int32):
                cv2.circle(mask, (int(x), int(y)), c.min_distance, 0, -1)
        img = gray
        if c.detect_half:
            # Corners found at half resolution, positions refined at full resolution:
            # a quarter of the detector's cost for the same corners.
            img = cv2.pyrDown(gray)
            if mask is not None:
                mask = mask[::2, ::2].copy()
        pts = cv2.goodFeaturesToTrack(img, maxCorners=want, qualityLevel=c.quality_level,
                                      minDistance=max(1, c.min_distance // (2 if c.detect_half else 1)),
                                      mask=mask, blockSize=c.block_size)
        if pts is None:
            return np.zeros((0, 2), np.float32)
        pts = pts.reshape(-1, 1, 2).astype(np.float32)
        if c.min_corner_ratio > 0:
            pts = np.ascontiguousarray(pts[_corner_ratio(img, pts.reshape(-1, 2), c.corner_window)
                                           >= c.min_corner_ratio])
            if len(pts) == 0:
                return np.zeros((0, 2), np.float32)
        if c.detect_half:
            pts = pts * 2.0 + 0.5
            cv2.cornerSubPix(gray, pts, (3, 3), (-1, -1), self._subpix_crit)
        return pts.reshape(-1, 2)

    # ----------------------------------------------------------------- ORB
    def _process_orb(self, gray, depth):
        c = self.config
        kps, desc = self._orb.detectAndCompute(gray, None)
        px = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        cur = self._make_set(px, depth, desc)
        matches = np.zeros((0, 2), np.int64)
        prev = self._prev
        if prev is not None and prev.desc is not None and desc is not None and len(prev) and len(cur):
            ms = self._bf.match(prev.desc, desc)
            pairs = [(m.queryIdx, m.trainIdx) for m in ms if m.distance <= c.orb_max_hamming]
            if pairs:
                matches = np.array(pairs, np.int64)
        self.last_detected = len(px)
        self._prev = cur
        return cur, matches

    def _make_set(self, px, depth, desc=None) -> FeatureSet:
        c = self.config
        xy = undistort(px, self.intrinsics)
        P = lift(px, xy, depth, c, self.depth_range)
        if c.occlusion_rel > 0:
            # a corner whose tracking window spans a depth jump slides along the edge: its
            # image match may stay, its depth would make the 1-point translation long
            # (only corners that have a depth to lose are tested: a third of the test's cost)
            has = np.flatnonzero(np.isfinite(P[:, 2]))
            P[has[straddles_depth_jump(px[has], depth, c.klt_window // 2, c.occlusion_rel, self.depth_range)]] = np.nan
        return FeatureSet(px=px, xy=xy, P_cam=P, desc=desc, unread=unread(px, depth, c, self.depth_range))
