"""Synthetic corridor logs: rendering agrees with the ground truth it reports."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from planar_vo.core.errors import ConfigError, InputError
from planar_vo.core.geometry import mount_rotation, se2_to_matrix, tilt_from_gravity, wrap_quarter
from planar_vo.sim.synth import (SynthConfig, SynthRenderer, render_sequence, synth_intrinsics, synth_mount,
                                synth_trajectory, write_synth_log)
from planar_vo.sim.synth_scene import LABEL_CEILING, LABEL_FLOOR, LABEL_OTHER, LABEL_WALL

#: the corridor layouts of the drive tests (building and aliased: tests/test_synth_ring.py)
LAYOUTS = ("straight", "lturn", "loop", "two_frames", "hall")


def small(width=240, height=135, **kw) -> SynthConfig:
    """The default Kinect v2 camera resampled to a small image (fast tests)."""
    return SynthConfig(**kw).at_resolution(width, height)


def cam_points(cfg: SynthConfig, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera-frame points of a depth image (z along the optical axis)."""
    H, W = depth.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = depth.astype(np.float64)
    return np.stack([(u - cfg.cx) / cfg.fx * z, (v - cfg.cy) / cfg.fy * z, z], -1)


def world_points(cfg, frame, depth) -> np.ndarray:
    T = frame.T_world_cam
    return cam_points(cfg, depth) @ T[:3, :3].T + T[:3, 3]


FRAME = 200  # straight corridor, seed 0: walls, doors, posters and boxes in view


@pytest.fixture(scope="module")
def straight_ideal():
    """A mid-sequence straight-corridor frame with ideal depth, and its config."""
    cfg = small(layout="straight", texture="none", depth_noise=False)
    return cfg, next(render_sequence(cfg, [FRAME]))


# ----------------------------------------------------------------------------- config

def test_config_rejects_bad_values_naming_the_field():
    with pytest.raises(ConfigError, match="SynthConfig.layout"):
        SynthConfig(layout="maze")
    with pytest.raises(ConfigError, match="SynthConfig.texture"):
        SynthConfig(texture="shiny")
    with pytest.raises(ConfigError, match="SynthConfig.pitch_deg"):
        SynthConfig(pitch_deg=80.0)
    with pytest.raises(ConfigError, match=r"SynthConfig.n_frames: .*use at least (\d+) frames"):
        SynthConfig(layout="loop", n_frames=100)


def test_intrinsics_and_mount_follow_the_config():
    cfg = SynthConfig(pitch_deg=12.0, roll_deg=-3.0, cam_height=0.65, cam_x=0.2)
    K = synth_intrinsics(cfg)
    assert (K.width, K.height, K.fx, K.fy, K.cx, K.cy) == (960, 540, 540.7, 540.7, 479.5, 269.5)
    assert not K.has_distortion
    T = synth_mount(cfg).T_base_cam
    np.testing.assert_allclose(T[:3, :3], mount_rotation(math.radians(12.0), math.radians(-3.0)), atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [0.2, 0.0, 0.65])
    # the optical axis looks forward and 12 deg down
    np.testing.assert_allclose(T[:3, 2], [math.cos(math.radians(12)), 0.0, -math.sin(math.radians(12))], atol=1e-12)
    half = cfg.at_resolution(480, 270)
    assert (half.fx, half.cx, half.cy) == pytest.approx((270.35, 239.5, 134.5))


# ------------------------------------------------------------------------- trajectory

@pytest.mark.parametrize("layout, turn", [("straight", 0.0), ("lturn", math.pi / 2), ("two_frames", math.pi / 3),
                                          ("loop", 2 * math.pi), ("hall", math.pi)])
def test_trajectory_is_smooth_planar_motion_with_the_layout_turn(layout, turn):
    cfg = SynthConfig(layout=layout)
    stamps, poses = synth_trajectory(cfg)
    assert poses.shape == (300, 3) and stamps.shape == (300,)
    np.testing.assert_allclose(np.diff(stamps), 0.1, atol=1e-6)
    theta = np.unwrap(poses[:, 2])
    assert theta[-1] - theta[0] == pytest.approx(turn, abs=1e-9)
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    assert step[0] < 0.005  # starts from rest
    assert step.max() * cfg.rate_hz < 1.15 * cfg.speed  # ~0.4 m/s (the weave adds a little on arcs)
    assert np.abs(np.diff(theta)).max() * cfg.rate_hz < cfg.max_yaw_rate * 1.1
    assert step.sum() == pytest.approx(cfg.path_length, rel=0.02)
    assert 11.0 < cfg.path_length < 12.5


@pytest.mark.parametrize("layout", LAYOUTS)
def test_robot_moves_along_its_heading(layout):
    # the same 29.9 s drive sampled at 100 Hz: a central difference's chord then deviates
    # from the tangent by at most ~omega * dt / 2 = 3 mrad (at curvature steps)
    cfg = SynthConfig(layout=layout, rate_hz=100.0, n_frames=2991)
    _, poses = synth_trajectory(cfg)
    d = poses[2:, :2] - poses[:-2, :2]
    moving = np.linalg.norm(d, axis=1) > 0.002
    course = np.arctan2(d[moving, 1], d[moving, 0])
    err = np.angle(np.exp(1j * (course - poses[1:-1][moving, 2])))
    assert moving.mean() > 0.9
    assert np.abs(err).max() < 4e-3


def test_loop_returns_to_its_start():
    _, poses = synth_trajectory(SynthConfig(layout="loop"))
    np.testing.assert_allclose(poses[-1, :2], poses[0, :2], atol=1e-9)
    assert abs(math.remainder(poses[-1, 2] - poses[0, 2], 2 * math.pi)) < 1e-9
    assert np.linalg.norm(poses[:, :2] - poses[0, :2], axis=1).max() > 2.5  # it did go somewhere


# --------------------------------------------------------------------------- geometry

def test_frame_pose_is_base_pose_times_mount(straight_ideal):
    cfg, f = straight_ideal
    _, poses = synth_trajectory(cfg)
    np.testing.assert_allclose(f.pose_world_base, poses[FRAME])
    np.testing.assert_allclose(f.T_world_cam, se2_to_matrix(poses[FRAME]) @ synth_mount(cfg).T_base_cam, atol=1e-12)
    assert f.rgbd.stamp == pytest.approx(cfg.start_stamp + FRAME / cfg.rate_hz)
    assert f.rgbd.color.shape == (135, 240, 3) and f.rgbd.color.dtype == np.uint8
    assert f.rgbd.depth.shape == (135, 240) and f.rgbd.depth.dtype == np.float32


def test_depth_back_projects_onto_the_known_floor_and_walls(straight_ideal):
    cfg, f = straight_ideal
    labels, depth = f.truth["labels"], f.rgbd.depth
    P = world_points(cfg, f, depth)
    floor = (labels == LABEL_FLOOR) & (depth > 0)
    walls = (labels == LABEL_WALL) & (depth > 0)
    assert floor.sum() > 3000 and walls.sum() > 3000
    assert np.abs(P[floor][:, 2]).max() < 1e-3  # floor at z = 0, to a millimetre
    # straight corridor walls at y = +-1 m; posters stand 4 mm and doors 12 mm proud of them
    off = 1.0 - np.abs(P[walls][:, 1])
    nearest = np.abs(off[:, None] - np.array([0.0, 0.004, 0.012])[None, :]).min(1)
    assert nearest.max() < 1e-3
    assert np.mean(np.abs(off) < 1e-3) > 0.2  # bare wall is in view too
    boxes = (labels == LABEL_OTHER) & (depth > 0)
    assert boxes.sum() > 300
    assert P[boxes][:, 2].min() > -1e-3 and P[boxes][:, 2].max() < 1.25  # on the floor, <= 2 stacked
    assert np.abs(P[boxes][:, 1]).max() < 1.0  # inside the corridor


def test_floor_normal_matches_mount_and_the_rendered_floor(straight_ideal):
    cfg, f = straight_ideal
    n = f.truth["floor_normal_cam"]
    T = synth_mount(cfg).T_base_cam
    np.testing.assert_allclose(n, T[:3, :3].T @ [0.0, 0.0, 1.0], atol=1e-12)
    pitch, roll = tilt_from_gravity(-n)
    assert (pitch, roll) == pytest.approx((math.radians(cfg.pitch_deg), math.radians(cfg.roll_deg)), abs=1e-12)
    # plane fitted to the rendered floor: same normal, at the camera height
    X = cam_points(cfg, f.truth["depth_true"])[f.truth["labels"] == LABEL_FLOOR]
    centroid = X.mean(0)
    normal = np.linalg.svd(X - centroid, full_matrices=False)[2][2]
    normal *= np.sign(normal @ n)
    assert np.degrees(math.acos(min(1.0, normal @ n))) < 0.01
    assert -(centroid @ n) == pytest.approx(cfg.cam_height, abs=1e-3)
    # floor pixels are below the horizon: y_cam > 0 side of the image is mostly floor
    assert f.truth["floor_fraction"] == pytest.approx(np.mean(f.truth["labels"] == LABEL_FLOOR))


def test_manhattan_yaw_matches_walls_seen_in_depth(straight_ideal):
    cfg, f = straight_ideal
    theta = f.pose_world_base[2]
    assert abs(theta) > 0.02  # the weave turns the robot, so the yaw is not trivially 0
    yaws = f.truth["manhattan_yaws_base"]
    assert f.truth["manhattan_ids"] == [0]
    assert yaws[0] == pytest.approx(float(wrap_quarter(0.0 - theta)), abs=1e-12)
    # ManhattanObservation convention: world heading = theta + yaw + k pi/2
    k = (0.0 - theta - yaws[0]) / (math.pi / 2)
    assert abs(k - round(k)) < 1e-9
    # independent check: direction of the left wall in base_link from the depth image
    # (bare wall only: doors and posters are parallel planes a few mm in front)
    z = f.truth["depth_true"]
    Xb = cam_points(cfg, z) @ synth_mount(cfg).T_base_cam[:3, :3].T
    bare = np.abs(world_points(cfg, f, z)[..., 1] - 1.0) < 1e-4
    left = (f.truth["labels"] == LABEL_WALL) & bare
    assert left.sum() > 500
    xy = Xb[left][:, :2]
    d = np.linalg.svd(xy - xy.mean(0), full_matrices=False)[2][0]
    assert float(wrap_quarter(math.atan2(d[1], d[0]))) == pytest.approx(yaws[0], abs=1e-4)


def test_two_frames_reports_both_local_manhattan_frames():
    cfg = small(layout="two_frames", texture="none", depth_noise=False, width=96, height=54)
    _, poses = synth_trajectory(cfg)
    both = None
    for f in render_sequence(cfg, range(100, 240, 10)):
        if len(f.truth["manhattan_ids"]) == 2:
            both = f
            break
    assert both is not None, "the junction never shows both corridors"
    theta = both.pose_world_base[2]
    expected = {0: float(wrap_quarter(-theta)), 1: float(wrap_quarter(math.pi / 3 - theta))}
    for k, yaw, score in zip(both.truth["manhattan_ids"], both.truth["manhattan_yaws_base"],
                             both.truth["manhattan_scores"]):
        assert yaw == pytest.approx(expected[k], abs=1e-12)
        assert score >= cfg.min_wall_fraction
    scores = both.truth["manhattan_scores"]
    assert scores == sorted(scores, reverse=True)  # dominant first
    assert sum(scores) == pytest.approx(both.truth["wall_fraction"])
    # 60 deg apart: the two yaws differ by 30 deg modulo 90
    diff = abs(float(wrap_quarter(expected[1] - expected[0])))
    assert diff == pytest.approx(math.pi / 6, abs=1e-9)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_each_layout_renders_consistent_frames(layout):
    cfg = small(layout=layout, width=160, height=90)
    i = 120
    f = next(render_sequence(cfg, [i]))
    depth, labels = f.rgbd.depth, f.truth["labels"]
    assert depth.dtype == np.float32 and depth.shape == (90, 160)
    assert np.count_nonzero(depth) / depth.size > 0.4
    valid = depth > 0
    assert depth[valid].min() >= cfg.depth_min and depth[valid].max() <= cfg.depth_max
    assert set(np.unique(labels)) <= {0, LABEL_FLOOR, LABEL_WALL, LABEL_CEILING, LABEL_OTHER}
    assert f.truth["floor_fraction"] > 0.1
    P = world_points(cfg, f, f.truth["depth_true"])
    assert np.abs(P[labels == LABEL_FLOOR][:, 2]).max() < 1e-3
    assert f.rgbd.color.std() > 10  # not blank


def test_hall_has_long_stretches_without_walls_in_range():
    cfg = small(layout="hall", texture="none", depth_noise=False, width=64, height=36)
    step = 3
    wall = np.array([f.truth["wall_fraction"] for f in render_sequence(cfg, range(0, cfg.n_frames, step))])
    runs, run = [], 0
    for w in wall:
        run = run + 1 if w == 0.0 else 0
        runs.append(run)
    longest_s = max(runs) * step / cfg.rate_hz
    assert longest_s >= 6.0
    assert (wall == 0.0).mean() > 0.5
    assert wall.max() > 0.1  # walls do come into range near the turn and the end


# ------------------------------------------------------------------------------ sensor

def test_depth_noise_follows_the_documented_model():
    cfg = small(layout="straight", texture="none", width=480, height=270)
    f = next(render_sequence(cfg, [FRAME]))
    d, z = f.rgbd.depth.astype(np.float64), f.truth["depth_true"].astype(np.float64)
    valid = d > 0
    # millimetre quantisation and range
    assert np.abs(d[valid] * 1000 - np.rint(d[valid] * 1000)).max() < 0.01
    assert d[valid].min() >= 0.5 and d[valid].max() <= 4.5
    r = (d - z)[valid]
    zv = z[valid]
    for lo, hi in ((0.8, 1.5), (1.5, 2.5), (2.5, 3.5), (3.5, 4.3)):
        sel = (zv >= lo) & (zv < hi)
        assert sel.sum() > 2000
        sigma = cfg.depth_sigma0 + cfg.depth_sigma2 * zv[sel] ** 2
        expected = math.sqrt(np.mean(sigma ** 2) + 1e-6 / 12)  # + quantisation
        assert np.std(r[sel]) == pytest.approx(expected, rel=0.1)
        assert abs(np.mean(r[sel])) < 0.1 * expected + 2e-4
    # holes: few overall, but every far-side pixel of a big depth jump is dropped
    in_range = (z >= 0.5) & (z <= 4.5)
    lost = np.mean(~valid[in_range])
    assert 0.0005 < lost < 0.05
    far = np.zeros_like(valid)  # far side of every jump of more than 0.02 + 0.03 z^2 m
    for a, b, fa, fb in ((z[:, :-1], z[:, 1:], far[:, :-1], far[:, 1:]), (z[:-1], z[1:], far[:-1], far[1:])):
        thr = 0.02 + 0.03 * np.minimum(a, b) ** 2
        fb |= (b - a) > thr
        fa |= (a - b) > thr
    far &= in_range
    assert far.sum() > 100 and not valid[far].any()


def test_ideal_depth_is_the_true_depth_in_range(straight_ideal):
    cfg, f = straight_ideal
    z = f.truth["depth_true"]
    in_range = (z >= cfg.depth_min) & (z <= cfg.depth_max)
    np.testing.assert_array_equal(f.rgbd.depth[in_range], z[in_range])
    assert not f.rgbd.depth[~in_range].any()


def test_texture_levels_control_trackable_features():
    counts = []
    for tex in ("none", "low", "medium", "rich"):
        f = next(render_sequence(small(layout="straight", texture=tex), [150]))
        g = cv2.cvtColor(f.rgbd.color, cv2.COLOR_BGR2GRAY)
        counts.append(len(cv2.FastFeatureDetector_create(20).detect(g)))
    assert counts == sorted(counts) and len(set(counts)) == 4
    assert counts[-1] > 5 * counts[0]


# ---------------------------------------------------------------------- determinism

def test_rendering_is_deterministic_and_frame_order_independent():
    cfg = small(layout="lturn", texture="medium", width=160, height=90)
    a = list(render_sequence(cfg, [0, 7]))
    b = list(render_sequence(cfg, [7]))
    np.testing.assert_array_equal(a[1].rgbd.color, b[0].rgbd.color)
    np.testing.assert_array_equal(a[1].rgbd.depth, b[0].rgbd.depth)
    np.testing.assert_array_equal(a[1].truth["labels"], b[0].truth["labels"])
    other = next(render_sequence(SynthConfig(**{**cfg.__dict__, "seed": 1}), [7]))
    assert not np.array_equal(other.rgbd.depth, b[0].rgbd.depth)
    assert not np.array_equal(other.rgbd.color, b[0].rgbd.color)


def test_renderer_rejects_frames_outside_the_sequence():
    cfg = small(layout="straight", texture="none", width=32, height=18)
    with pytest.raises(IndexError, match="frame 300"):
        list(render_sequence(cfg, [300]))


# ------------------------------------------------------------------------------ logs

@pytest.mark.parametrize("profile", ["ros2", "foxglove"])
def test_written_log_reads_back_with_ground_truth(tmp_path, profile):
    from planar_vo.io import open_log
    from planar_vo.io.trajectory import read_tum_trajectory

    cfg = small(layout="straight", n_frames=30, width=160, height=90)
    paths = write_synth_log(cfg, tmp_path / "s.mcap", profile=profile, progress=False)
    assert paths == {"log": str(tmp_path / "s.mcap"), "ground_truth": str(tmp_path / "s.gt.tum")}
    gt = read_tum_trajectory(paths["ground_truth"])
    renderer = SynthRenderer(cfg)
    stamps, poses = synth_trajectory(cfg)
    first = renderer.render(poses[0], 0, stamps[0])
    assert len(gt) == 30
    np.testing.assert_allclose(gt.stamps, stamps, atol=1e-6)
    np.testing.assert_allclose(gt.poses[0], first.T_world_cam, atol=1e-9)
    with open_log(paths["log"]) as log:
        assert log.intrinsics.width == 160 and log.intrinsics.fx == pytest.approx(cfg.fx)
        np.testing.assert_allclose(log.mount.T_base_cam, synth_mount(cfg).T_base_cam, atol=1e-9)
        np.testing.assert_allclose(log.ground_truth.poses, gt.poses, atol=1e-9)
        frames = list(log.frames())
    assert len(frames) == 30
    np.testing.assert_array_equal(frames[0].depth, first.rgbd.depth)  # PNG depth is lossless in mm
    assert np.abs(frames[0].color.astype(int) - first.rgbd.color).mean() < 4  # JPEG


def test_write_into_missing_directory_is_an_input_error(tmp_path):
    cfg = small(layout="straight", n_frames=30, width=32, height=18)
    with pytest.raises(InputError, match="does not exist"):
        write_synth_log(cfg, tmp_path / "nope" / "s.mcap", progress=False)


def test_cli_writes_a_log_and_names_bad_flags(tmp_path, capsys):
    from planar_vo.cli import main

    out = tmp_path / "c.mcap"
    rc = main(["synth", str(out), "--layout", "straight", "--frames", "30", "--size", "64x36", "--quiet"])
    assert rc == 0 and out.exists() and (tmp_path / "c.gt.tum").exists()
    assert str(out) in capsys.readouterr().out
    for flags, name in ((["--texture", "shiny"], "--texture"), (["--size", "big"], "--size"),
                        (["--frames", "5"], "--frames"), (["--profile", "ros1"], "--profile"),
                        (["--speed-dips"], "--randomize")):
        rc = main(["synth", str(tmp_path / "d.mcap"), "--layout", "straight", *flags])
        assert rc == 2
        assert name in capsys.readouterr().err
    assert not (tmp_path / "d.mcap").exists()
