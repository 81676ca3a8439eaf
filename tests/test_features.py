"""Corner association (KLT, ORB), undistortion and lifting to 3-D."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from planar_vo.frontend.config import FeatureConfig
from planar_vo.frontend.features import FeatureTracker, lift, undistort, unread
from planar_vo.core.types import CameraIntrinsics

K = CameraIntrinsics(640, 480, 500.0, 500.0, 319.5, 239.5)


def _texture(rng, h=480, w=640):
    img = rng.random((h // 4, w // 4)).astype(np.float32)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    img = (img - img.min()) / (img.max() - img.min())
    return (30 + 200 * img).astype(np.uint8)


def _warp(img, H):
    return cv2.warpPerspective(img, H, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("method,median_px,tol_px,frac", [("klt", 0.1, 0.3, 0.9), ("orb", 1.0, 2.5, 0.8)])
def test_matches_follow_a_known_homography(method, median_px, tol_px, frac):
    rng = np.random.default_rng(11)
    img0 = _texture(rng)
    H = np.array([[1.01, 0.01, 6.5], [-0.008, 1.0, -3.25], [1e-5, 0.0, 1.0]])
    img1 = _warp(img0, H)
    depth = np.full(img0.shape, 2.0, np.float32)
    tr = FeatureTracker(K, FeatureConfig(method=method))
    f0, m0 = tr.process(img0, depth)
    assert len(m0) == 0 and len(f0) > 100
    f1, m = tr.process(img1, depth)
    assert len(m) > 0.5 * len(f0)
    p0 = f0.px[m[:, 0]].astype(np.float64)
    p1 = f1.px[m[:, 1]].astype(np.float64)
    pred = cv2.perspectiveTransform(p0.reshape(-1, 1, 2), H).reshape(-1, 2)
    err = np.linalg.norm(pred - p1, axis=1)
    # away from the reflected border, matches are accurate
    inside = (pred[:, 0] > 30) & (pred[:, 0] < 610) & (pred[:, 1] > 30) & (pred[:, 1] < 450)
    # ORB keypoints live on a scale pyramid: pixel-level, KLT sub-pixel
    assert np.median(err[inside]) < median_px
    assert np.mean(err[inside] < tol_px) > frac


def test_klt_reuses_tracks_and_tops_up():
    rng = np.random.default_rng(12)
    img = _texture(rng)
    depth = np.full(img.shape, 2.0, np.float32)
    cfg = FeatureConfig(method="klt", max_corners=200)
    tr = FeatureTracker(K, cfg)
    f0, _ = tr.process(img, depth)
    assert tr.last_detected == len(f0) <= 200
    # the same image again: every corner survives, no new detection needed
    f1, m = tr.process(img.copy(), depth)
    assert len(m) >= 0.95 * len(f0) and tr.last_detected == 0
    assert np.allclose(f1.px[m[:, 1]], f0.px[m[:, 0]], atol=0.05)
    # a blank image loses every track (no texture), and nothing new is found
    f2, m2 = tr.process(np.full_like(img, 128), depth)
    assert len(m2) == 0 and len(f2) == 0


def test_undistort_matches_opencv_and_identity():
    px = np.array([[10.0, 20.0], [319.5, 239.5], [600.0, 470.0]])
    xy = undistort(px, K)
    assert np.allclose(xy[1], [0.0, 0.0])
    assert np.allclose(xy[0], [(10 - 319.5) / 500.0, (20 - 239.5) / 500.0])
    Kd = CameraIntrinsics(640, 480, 517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))
    xyd = undistort(px, Kd)
    # re-distorting gives the pixels back
    back, _ = cv2.projectPoints(np.column_stack([xyd, np.ones(3)]), np.zeros(3), np.zeros(3), Kd.K,
                                np.array(Kd.distortion))
    assert np.allclose(back.reshape(-1, 2), px, atol=1e-3)


def test_lift_uses_depth_and_rejects_edges_and_holes():
    depth = np.full((480, 640), 2.0, np.float32)
    depth[:, 320:] = 3.0          # a depth edge at column 320
    depth[100:110, 100:110] = 0.0  # a hole
    px = np.array([[200.0, 200.0], [319.6, 200.0], [104.0, 104.0], [500.0, 300.0], [-3.0, 5.0]])
    xy = undistort(px, K)
    P = lift(px, xy, depth, FeatureConfig())
    assert np.allclose(P[0], [xy[0, 0] * 2.0, xy[0, 1] * 2.0, 2.0])
    assert np.isnan(P[1]).all()          # straddles the edge
    assert np.isnan(P[2]).all()          # in the hole
    assert P[3, 2] == pytest.approx(3.0)
    assert np.isnan(P[4]).all()          # outside the image
    # a pixel whose own reading is missing takes its readable neighbours' mean
    depth2 = np.full((480, 640), 2.5, np.float32)
    depth2[200, 200] = 0.0
    assert lift(px[:1], xy[:1], depth2, FeatureConfig())[0, 2] == pytest.approx(2.5)


def test_unread_is_beyond_the_range_not_an_edge_or_a_hole_among_readings():
    """Far corners (frontend/farcorners.py) are those with no reading around them at all: a
    region the sensor does not reach (0 = no reading, or past its range), a dropout wider
    than the depth window; not a depth edge, nor a corner whose window holds a reading."""
    depth = np.full((480, 640), 2.0, np.float32)
    depth[:, 400:] = 0.0            # beyond the range (no reading)
    depth[:200, 300:400] = 9.5      # read, but past the 8 m range
    depth[100:110, 100:110] = 0.0   # a dropout wider than the 3 x 3 window
    depth[203:205, 103:105] = 0.0   # a hole inside it
    px = np.array([[500.0, 300.0], [350.0, 100.0], [399.6, 300.0], [104.0, 104.0], [104.0, 204.0],
                   [200.0, 300.0]])
    got = unread(px, depth, FeatureConfig())
    assert got.tolist() == [True, True, False, True, False, False]
    tr = FeatureTracker(K)
    assert tr._make_set(px.astype(np.float32), depth).unread.tolist() == got.tolist()
    assert unread(px[:0], depth, FeatureConfig()).shape == (0,)


def test_bad_input():
    tr = FeatureTracker(K)
    with pytest.raises(ValueError, match=r"\(480, 640, 3\) uint8"):
        tr.process(np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640), np.float32))
    with pytest.raises(ValueError, match="method"):
        FeatureTracker(K, FeatureConfig(method="sift"))


@pytest.mark.parametrize("gain", [0.9, 1.12])
def test_klt_compensates_a_gain_change(gain):
    """Auto-exposure between frames: LK assumes constant brightness, the tracker rescales."""
    rng = np.random.default_rng(13)
    img0 = _texture(rng)
    H = np.array([[1.0, 0.0, 4.3], [0.0, 1.0, -2.7], [0.0, 0.0, 1.0]])
    img1 = np.clip(_warp(img0, H).astype(np.float64) * gain, 0, 255).astype(np.uint8)
    depth = np.full(img0.shape, 2.0, np.float32)
    errs = {}
    for tol in (0.0, 0.01):
        tr = FeatureTracker(K, FeatureConfig(method="klt", gain_tolerance=tol))
        f0, _ = tr.process(img0, depth)
        f1, m = tr.process(img1, depth)
        p0, p1 = f0.px[m[:, 0]].astype(np.float64), f1.px[m[:, 1]].astype(np.float64)
        pred = cv2.perspectiveTransform(p0.reshape(-1, 1, 2), H).reshape(-1, 2)
        inside = (pred[:, 0] > 30) & (pred[:, 0] < 610) & (pred[:, 1] > 30) & (pred[:, 1] < 450)
        errs[tol] = (np.linalg.norm(pred - p1, axis=1)[inside], len(m))
    assert tr.last_gain == pytest.approx(gain, abs=0.01)
    comp, plain = errs[0.01], errs[0.0]
    assert np.median(comp[0]) < 0.05
    assert np.mean(comp[0] ** 2) < 0.5 * np.mean(plain[0] ** 2)
    assert comp[1] >= plain[1]


def _grout_floor(shift: int) -> np.ndarray:
    """A 640 x 480 image, textured on the left; on the right a plain, faintly mottled floor
    with three vertical grout lines (edges, no corners), shifted down by ``shift`` pixels,
    with fresh sensor noise (sigma 3 grey levels) per frame."""
    rng = np.random.default_rng(3)
    h, w = 520, 640
    tex = _texture(rng, h, w).astype(np.float32)
    mott = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 2.0)
    img = 128.0 + 2.0 * (mott - mott.mean()) / mott.std()
    img[:, :320] = tex[:, :320]
    for x0 in (400, 480, 560):
        img[:, x0:x0 + 3] -= 60
    img = cv2.GaussianBlur(img, (0, 0), 0.8)[20 - shift:500 - shift]
    img = img + np.random.default_rng(100 + shift).normal(0.0, 3.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_klt_drops_tracked_corners_that_became_edges():
    """Corners tracked onto an edge (a grout-line crossing seen close up) slide along it:
    on the low-texture tuning logs they followed half of their image motion and made the
    steps 25 % short. A tracked point on a grout line must not come back as a match."""
    img0, img1 = _grout_floor(0), _grout_floor(2)   # the floor moves 2 px down the image
    depth = np.full(img0.shape, 2.0, np.float32)
    tr = FeatureTracker(K, FeatureConfig(max_corners=1000))
    f0, _ = tr.process(img0, depth)
    edge = np.array([[x + 1.0, y] for x in (400, 480, 560) for y in range(60, 440, 40)], np.float32)
    start = np.vstack([f0.px, edge]).astype(np.float32)
    tr._prev = tr._make_set(start, depth)   # as if these had been tracked here
    f1, m = tr.process(img1, depth)
    err = f1.px[m[:, 1]] - start[m[:, 0]] - np.array([0.0, 2.0])
    assert len(m) > 0.8 * len(f0)
    # every match follows the motion: none slid along a line (the old code kept seven
    # points of the grout lines, 0.9 px short on average, up to 2 px)
    assert np.abs(err).max() < 0.6
    assert np.median(np.abs(err)) < 0.1


def _corridor_depth(rng, h=480, w=640):
    """Optical-axis depth (h, w) of a camera 0.5 m above a floor, pitched 12 deg down, 0.9 m
    from a wall on its left, with a box face 1.2 m ahead covering columns 400-639 above
    row 260 (a near silhouette against the wall and floor), plus Kinect-like noise."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ray = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], -1)
    p = np.radians(12.0)
    R = np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]])  # camera -> level
    d = ray @ R.T
    z = np.full((h, w), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for t in (0.5 / d[..., 1], -0.9 / d[..., 0]):          # floor (level y down), left wall
            z = np.where((t > 0) & (t < z), t, z)
    z = np.where(np.isfinite(z), z, 6.0)
    box = (u >= 400) & (v < 260)
    z[box] = np.minimum(z[box], 1.2 / d[box][:, 2])
    z = z * 1.0  # t along a unit-z camera ray is the optical depth
    z = z + (0.0015 + 0.0015 * z * z) * rng.standard_normal(z.shape)
    return z.astype(np.float32)


def test_windows_across_a_depth_jump_are_flagged_slanted_surfaces_are_not():
    from planar_vo.frontend.features import straddles_depth_jump
    depth = _corridor_depth(np.random.default_rng(3))
    # on the box's left silhouette (column 400) and its bottom edge (row 260): within LK's
    # 11 x 11 window of the jump to the floor or wall behind
    edge = np.array([[397.0, 220.0], [403.0, 100.0], [400.0, 200.0], [500.0, 257.0], [600.0, 263.0]])
    # a slanted floor near and far, the left wall seen obliquely, the floor-wall crease,
    # the box face, all at least 7 px from the silhouette
    smooth = np.array([[300.0, 460.0], [300.0, 300.0], [200.0, 280.0], [40.0, 150.0], [80.0, 300.0],
                       [500.0, 150.0], [392.0, 220.0], [600.0, 268.0]])
    flags = straddles_depth_jump(np.vstack([edge, smooth]), depth, 5, FeatureConfig().occlusion_rel)
    assert flags.tolist() == [True] * len(edge) + [False] * len(smooth)


def test_corner_ratio_at_the_corners_equals_opencvs_whole_image_filters():
    """_corner_ratio evaluates Sobel gradients and their box sums at the corners only; it must
    give what OpenCV's whole-image filters give (BORDER_REFLECT_101 at the edges), points on
    and next to the border included."""
    from planar_vo.frontend.features import _corner_ratio

    rng = np.random.default_rng(5)
    img = _texture(rng, 120, 160)
    img[40:60, 50:90] = rng.integers(0, 256, (20, 40))  # strong gradients: large tensor sums
    pts = np.vstack([rng.uniform([0, 0], [159, 119], (300, 2)),
                     [[0, 0], [159, 119], [0, 119], [159, 0], [1, 60], [158, 61], [80, 1], [81, 118]]])
    for half in (1, 3):
        f = img.astype(np.float32)
        gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
        k = (2 * half + 1, 2 * half + 1)
        a, b, d = (cv2.boxFilter(p, cv2.CV_64F, k, normalize=False) for p in (gx * gx, gx * gy, gy * gy))
        c = np.rint(pts[:, 0]).astype(int)
        r = np.rint(pts[:, 1]).astype(int)
        a, b, d = a[r, c], b[r, c], d[r, c]
        root = np.sqrt((0.5 * (a - d)) ** 2 + b * b)
        mean = 0.5 * (a + d)
        want = np.where(mean + root > 0, (mean - root) / np.maximum(mean + root, 1e-12), 0.0)
        got = _corner_ratio(img, pts.astype(np.float32), half)
        assert np.allclose(got, want, rtol=0, atol=1e-12)


def test_patches_are_the_windows_moved_inside_the_image():
    from planar_vo.frontend.features import _patches

    img = np.arange(30 * 40, dtype=np.float32).reshape(30, 40)
    pts = np.array([[0.2, 0.4], [39.0, 29.0], [20.4, 10.6], [2.0, 27.0]])
    got = _patches(img, pts, 2)
    for p, g in zip(pts, got):
        c = int(np.clip(np.rint(p[0]), 2, 37))
        r = int(np.clip(np.rint(p[1]), 2, 27))
        assert np.array_equal(g, img[r - 2:r + 3, c - 2:c + 3])
