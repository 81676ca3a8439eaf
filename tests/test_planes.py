"""Inverse-depth histogram planes: exact ray-cast scenes, synthetic corridors, real TUM depth."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from planar_vo.core import geometry as g
from planar_vo.frontend.config import ManhattanConfig, PlaneConfig
from planar_vo.frontend.planes import FLOOR, WALL, PlaneDetector
from planar_vo.core.types import CameraIntrinsics

K = CameraIntrinsics(960, 540, 540.7, 540.7, 479.5, 269.5)
DATA = Path(__file__).resolve().parents[1] / "data" / "tum_fr1_xyz_head10"


def raycast(K, pitch, roll, planes_lev, noise=0.0, rng=None, max_depth=8.0):
    """Depth (H, W) float32 of planes ``[(n_lev (3,), d)]`` seen by a camera with mount tilt."""
    R = g.levelling_rotation(pitch, roll)
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    r = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    rl = r @ R.T
    best = np.full(len(r), np.inf)
    for n, d in planes_lev:
        den = rl @ np.asarray(n, float)
        with np.errstate(divide="ignore"):
            t = np.where(den > 1e-9, d / np.where(den > 1e-9, den, 1.0), np.inf)
        best = np.minimum(best, t)
    z = np.where(np.isfinite(best), best, 0.0)
    if noise:
        z = z + rng.normal(0.0, 1.0, z.shape) * noise * z ** 2
    z[(z > max_depth) | (z < 0)] = 0.0
    return z.reshape(K.height, K.width).astype(np.float32)


def corridor(yaw, h=0.8, left=1.2, right=0.9, ceiling=2.6, end=6.0):
    """Planes (lev frame) of a corridor whose axis has heading ``yaw`` (rad, CCW) in lev 2-D."""
    c, s = math.cos(yaw), math.sin(yaw)
    axis = np.array([-s, 0.0, c])      # 2-D (c, s) -> lev (x = -y2d, z = x2d)
    lft = np.array([-c, 0.0, -s])      # 2-D (-s, c)
    return [((0.0, 1.0, 0.0), h), ((0.0, -1.0, 0.0), ceiling - h), (lft, left), (-lft, right), (axis, end)]


@pytest.mark.parametrize("yaw_deg", [0.0, 17.0, -33.0])
def test_exact_corridor_planes(yaw_deg):
    rng = np.random.default_rng(1)
    pitch, roll = math.radians(10.0), math.radians(2.0)
    yaw = math.radians(yaw_deg)
    depth = raycast(K, pitch, roll, corridor(yaw), noise=0.0015, rng=rng)
    det = PlaneDetector(K, R_lev_cam=g.levelling_rotation(pitch, roll)).detect(depth)
    assert det.floor is not None and det.floor.kind == FLOOR
    assert math.degrees(math.acos(det.floor.normal[1])) < 0.05
    assert det.floor.offset == pytest.approx(0.8, abs=0.002)
    assert det.floor.support > 0.2
    # every wall's normal heading is the corridor's heading modulo 90 degrees
    big = [w for w in det.walls if w.support > 0.05]
    assert len(big) >= 2  # side walls and the end wall, as far as they are in view
    for w in big:
        assert w.kind == WALL
        err = math.degrees(float(g.wrap_quarter(w.yaw - yaw)))
        # near walls to 0.1 deg; the 6 m end wall (yaw sigma ~0.45 deg) within 1 sigma
        assert abs(err) < (0.1 if w.offset < 2.0 else math.degrees(w.yaw_sigma)), (err, w.offset)
        assert w.tilt < math.radians(0.2)
    offsets = sorted(round(w.offset, 2) for w in big)
    for d in offsets:
        assert min(abs(d - x) for x in (0.9, 1.2, 6.0)) < 0.03
    # the fit's yaw sigma is small but not zero
    assert all(0.0 < w.yaw_sigma < math.radians(0.5) for w in big)


def test_unlevelled_floor_search_recovers_tilt():
    """With the tilt unknown (identity levelling) the widened search still finds the floor,
    and its normal gives the mount tilt back through geometry.tilt_from_gravity."""
    rng = np.random.default_rng(4)
    pitch, roll = math.radians(14.0), math.radians(-3.0)
    depth = raycast(K, pitch, roll, corridor(0.2, h=0.65), noise=0.0015, rng=rng)
    det = PlaneDetector(K).detect(depth, levelled=False)
    assert det.floor is not None
    p, r = g.tilt_from_gravity(det.floor.normal)  # lev == cam here
    assert math.degrees(abs(p - pitch)) < 0.1 and math.degrees(abs(r - roll)) < 0.1
    assert det.floor.offset == pytest.approx(0.65, abs=0.003)


def test_no_planes_in_clutter_and_bad_input():
    rng = np.random.default_rng(2)
    depth = rng.uniform(0.5, 6.0, (K.height, K.width)).astype(np.float32)
    det = PlaneDetector(K).detect(depth)
    assert det.floor is None and det.walls == []
    empty = PlaneDetector(K).detect(np.zeros((K.height, K.width), np.float32))
    assert empty.n_valid == 0 and empty.walls == [] and empty.floor is None
    with pytest.raises(ValueError, match=r"\(540, 960\).*\(480, 640\)"):
        PlaneDetector(K).detect(np.zeros((480, 640), np.float32))
    with pytest.raises(ValueError, match="3, 3"):
        PlaneDetector(K).set_levelling(np.eye(4))


def test_floor_seed_refit_matches_search():
    pitch, roll = math.radians(10.0), math.radians(2.0)
    depth = raycast(K, pitch, roll, corridor(0.1))
    det = PlaneDetector(K, R_lev_cam=g.levelling_rotation(pitch, roll))
    a = det.detect(depth)
    b = det.detect(depth, floor_seed=a.floor)
    assert np.allclose(a.floor.normal, b.floor.normal, atol=1e-9)
    assert b.floor.offset == pytest.approx(a.floor.offset, abs=1e-9)
    assert len(b.walls) == len(a.walls)


# --------------------------------------------------------------------- synthetic corridor
SYNTH_FRAMES = list(range(0, 100, 9))  # 12 frames along an L-turn corridor


@pytest.fixture(scope="module")
def synth_lturn():
    from planar_vo.sim.synth import SynthConfig, render_sequence, synth_intrinsics, synth_mount

    cfg = SynthConfig(layout="lturn", n_frames=100, seed=3)
    return synth_intrinsics(cfg), synth_mount(cfg), list(render_sequence(cfg, SYNTH_FRAMES))


def test_synthetic_corridor_floor_and_walls(synth_lturn):
    K_s, mount, frames = synth_lturn
    pitch, roll, _ = g.mount_angles(mount.T_base_cam[:3, :3])
    R = g.levelling_rotation(pitch, roll)
    det = PlaneDetector(K_s, R_lev_cam=R)
    normal_err, wall_frames, wall_hits = [], 0, 0
    for f in frames:
        d = det.detect(f.rgbd.depth)
        assert d.floor is not None
        up_cam = -(R.T @ d.floor.normal)  # truth gives the upward normal
        normal_err.append(math.degrees(math.acos(min(1.0, float(up_cam @ f.truth["floor_normal_cam"])))))
        if f.truth["wall_fraction"] >= 0.10:
            wall_frames += 1
            wall_hits += bool(d.walls)
    assert max(normal_err) < 0.5, normal_err
    assert wall_frames >= 8
    assert wall_hits >= 0.95 * wall_frames


# --------------------------------------------------------------------- real data
@pytest.mark.skipif(not DATA.exists(), reason="sample data missing")
def test_tum_sample_planes():
    """Real Kinect v1 depth (handheld, strongly tilted): the desk-scene's dominant plane is
    found in every frame, fits the sensor noise and stays put between frames 33 ms apart."""
    from planar_vo.io import open_log

    with open_log(DATA) as log:
        det = PlaneDetector(log.intrinsics, PlaneConfig(unlevelled_tilt_deg=60.0))
        tracked = None
        n = 0
        for f in log.frames():
            d = det.detect(f.depth, levelled=False)
            assert d.n_valid > 0.5 * d.n_total
            planes = [p for p in d.horizontals + d.walls if p.support > 0.05]
            assert planes and all(p.rms_rel < 0.02 for p in planes)
            if tracked is None:
                tracked = max(planes, key=lambda p: p.support)
            else:
                # the same surface again (handheld, 33 ms apart): normal within 5 deg, offset 5 cm
                ang = [math.degrees(math.acos(min(1.0, float(p.normal @ tracked.normal)))) for p in planes]
                k = int(np.argmin(ang))
                assert ang[k] < 5.0 and abs(planes[k].offset - tracked.offset) < 0.05
                tracked = planes[k]
            n += 1
    assert n >= 9


@pytest.mark.parametrize("yaw_deg", [3.0, -5.0])
def test_first_frame_walls_are_fitted_within_the_range_learnt_ahead(yaw_deg):
    """An end wall standing just past the sensor's range (4.8 m, readings stop at 4.5 m)
    shows only as the near readings of its noise: fitted, it leans ~0.5 deg. Until the
    range is learnt (ten frames) the detector cannot leave it out, and frame 0's
    Manhattan observation is the run's heading reference (an unseen L ended 0.25 deg off
    from it). ``look_ahead`` over the first ten frames' depth learns the range before
    frame 0's walls are fitted."""
    pitch, roll = math.radians(17.0), math.radians(-2.4)
    R = g.levelling_rotation(pitch, roll)
    yaw = math.radians(yaw_deg)
    depths = [raycast(K, pitch, roll, corridor(yaw, end=4.8), noise=0.0015, rng=np.random.default_rng(k),
                      max_depth=4.5) for k in range(10)]

    def errors(det):
        return [abs(math.degrees(float(g.wrap_quarter(w.yaw - yaw)))) for w in det.detect(depths[0]).walls]

    assert max(errors(PlaneDetector(K, R_lev_cam=R))) > 0.3  # the mechanism
    ahead = PlaneDetector(K, R_lev_cam=R)
    ahead.look_ahead(depths)
    err = errors(ahead)
    assert ahead.range_max == pytest.approx(4.5, abs=0.01)
    assert len(err) == 2 and max(err) < 0.05, err


# --------------------------------------------------------------------- wall widths
def raycast_rects(K, pitch, roll, rects, floor_h, max_depth=8.0):
    """Depth (H, W) float32 of vertical rectangles over a floor ``floor_h`` m below the
    camera. ``rects``: ``[(centre (x, z) lev m, heading rad of the face normal, width m,
    top above the floor m)]``; each is a face of that width, standing on the floor."""
    R = g.levelling_rotation(pitch, roll)
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    r = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3) @ R.T
    best = np.where(r[:, 1] > 1e-9, floor_h / np.where(r[:, 1] > 1e-9, r[:, 1], 1.0), np.inf)
    for (cx, cz), yaw, width, top in rects:
        n = np.array([-math.sin(yaw), 0.0, math.cos(yaw)])      # lev, from lev 2-D (cos, sin)
        along = np.array([math.cos(yaw), 0.0, math.sin(yaw)])
        c = np.array([cx, 0.0, cz])
        den = r @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c @ n) / den
        p = r * t[:, None]
        inside = (np.abs((p - c) @ along) <= width / 2) & (p[:, 1] <= floor_h) & (p[:, 1] >= floor_h - top)
        best = np.where(inside & (t > 0) & (t < best), t, best)
    z = np.where(np.isfinite(best), best, 0.0)
    z[(z > max_depth) | (z < 0)] = 0.0
    return z.reshape(K.height, K.width).astype(np.float32)


def test_wall_width_tells_box_faces_from_walls():
    """Two 0.4 m box faces turned 7 deg, in line 1.6 m apart (one plane, inliers spanning
    two metres), measure what they fill, about 0.8 m, and a wall behind measures metres:
    what keeps box faces out of the Manhattan priors (``manhattan.min_wall_width_m``)."""
    pitch, roll = math.radians(8.0), 0.0
    box = math.radians(7.0)
    # the second face lies on the first one's plane, 1.6 m further along it (lev x, z)
    c1 = np.array([0.3, 2.2])
    c2 = c1 - 1.6 * np.array([math.cos(box), math.sin(box)])
    rects = [(c1, box, 0.4, 0.6), (c2, box, 0.4, 0.6), ((0.0, 4.5), 0.0, 9.0, 3.0)]
    depth = raycast_rects(K, pitch, roll, rects, floor_h=0.9)
    det = PlaneDetector(K, R_lev_cam=g.levelling_rotation(pitch, roll)).detect(depth)
    faces = [w for w in det.walls if abs(math.degrees(float(g.wrap_quarter(w.yaw - box)))) < 1.0]
    walls = [w for w in det.walls if abs(math.degrees(float(g.wrap_quarter(w.yaw)))) < 1.0]
    assert len(faces) == 1 and walls, [(math.degrees(w.yaw), w.width) for w in det.walls]
    # both faces are its inliers (the angular extent spans them), the width only them
    assert math.degrees(faces[0].extent) > 40.0
    assert 0.7 < faces[0].width < 0.9 < ManhattanConfig().min_wall_width_m, faces[0].width
    assert max(w.width for w in walls) > 3.0


def test_sensor_range_is_learnt_from_a_repeated_farthest_reading():
    """A range shows as the same farthest reading frame after frame (the floor's readings
    stop at 4.5 m); a corridor's end wall the robot drives towards is the farthest
    surface too, but its depth changes. Only the first becomes ``range_max``, and then
    walls are fitted where their depth is within ``1 - range_margin`` of it."""
    pitch, roll = math.radians(8.0), 0.0
    R = g.levelling_rotation(pitch, roll)
    wall = ((-math.sin(0.2), 0.0, math.cos(0.2)), 4.1)  # a wall 4.1 m away, partly past the range
    det = PlaneDetector(K, R_lev_cam=R)
    for k in range(12):
        rng = np.random.default_rng(k)
        depth = raycast(K, pitch, roll, [((0.0, 1.0, 0.0), 0.5), wall], noise=0.0015, rng=rng, max_depth=4.5)
        found = det.detect(depth).walls
        assert len(found) == 1
        grid = depth[det._o::det.config.stride, det._o::det.config.stride].ravel()
        far = np.percentile(grid[found[0].inliers], 99)
        if k < 9:  # not learnt yet: the wall is fitted up to the range
            assert far > 4.4, far
    assert det.range_max == pytest.approx(4.5, abs=0.01)
    margin = PlaneConfig().range_margin
    assert far < (1.0 - margin) * 4.5 + 0.05, far  # then short of it (by the wall's depth, not the readings')
    approach = PlaneDetector(K, R_lev_cam=R)
    for k in range(12):
        end = 6.5 - 0.2 * k
        depth = raycast(K, pitch, roll, corridor(0.0, h=0.5, end=end))
        walls = approach.detect(depth).walls
        assert any(abs(w.offset - end) < 0.05 for w in walls)  # the end wall is always fitted
    assert approach.range_max == 0.0
