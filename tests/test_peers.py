"""Peer RGB-D odometry wrappers against a ray-cast textured room with known motion."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.core.geometry import rot_x, rot_y
from planar_vo.core.types import CameraIntrinsics, RGBDFrame
from planar_vo.bench.peer_methods import PEER_METHODS, PeerMethod, PeerOptions, PeerStep, PeerTracker, make_method, track

pytest.importorskip("open3d")
pytest.importorskip("cv2")

INTR = CameraIntrinsics(320, 240, 260.0, 260.0, 159.5, 119.5)
#: room: x in [-2.5, 2.5], y (down) in [-2.0, 0.6] (floor 0.6 m below the camera), z in [-3, 4]
ROOM_LO = np.array([-2.5, -2.0, -3.0])
ROOM_HI = np.array([2.5, 0.6, 4.0])


def _value_noise(grid: np.ndarray, a: np.ndarray, b: np.ndarray, cell: float) -> np.ndarray:
    """Bilinearly interpolated random grid at plane coordinates (a, b) metres."""
    n = grid.shape[0]
    x, y = a / cell, b / cell
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    g = lambda i, j: grid[i % n, j % n]  # noqa: E731
    return ((1 - fx) * (1 - fy) * g(x0, y0) + fx * (1 - fy) * g(x0 + 1, y0)
            + (1 - fx) * fy * g(x0, y0 + 1) + fx * fy * g(x0 + 1, y0 + 1))


def render(T_world_cam: np.ndarray, index: int = 0, seed: int = 7) -> RGBDFrame:
    """Colour (BGR uint8) and depth (float32 m) of the textured box room seen from ``T_world_cam``."""
    rng = np.random.default_rng(seed)  # same texture for every view
    coarse, fine = rng.random((64, 64)), rng.random((64, 64))
    v, u = np.mgrid[0:INTR.height, 0:INTR.width].astype(float)
    d_cam = np.stack([(u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy, np.ones_like(u)], -1)
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = d_cam @ R.T
    with np.errstate(divide="ignore"):
        t_lo = (ROOM_LO - o) / d
        t_hi = (ROOM_HI - o) / d
    t_all = np.where(d > 0, t_hi, t_lo)  # the wall each axis exits through
    axis = np.argmin(t_all, axis=-1)
    t = np.take_along_axis(t_all, axis[..., None], -1)[..., 0]
    P = o + t[..., None] * d
    value = np.zeros_like(t)
    for ax in range(3):
        a, b = [P[..., k] for k in range(3) if k != ax]
        m = axis == ax
        side = (d[..., ax] > 0).astype(float) * 17.0 + ax * 5.0  # decorrelate the six faces
        value[m] = (0.7 * _value_noise(coarse, a[m] + side[m], b[m], 0.25)
                    + 0.3 * _value_noise(fine, a[m], b[m] + side[m], 0.06))
    gray = np.clip(30 + 200 * value, 0, 255).astype(np.uint8)
    color = np.stack([gray, (0.9 * gray).astype(np.uint8), gray], -1)
    depth = t.astype(np.float32)  # d_cam has z = 1, so the ray parameter is the optical depth
    return RGBDFrame(index, 0.1 * index, color, depth)


def pose(yaw_deg: float, t, pitch_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot_y(math.radians(yaw_deg)) @ rot_x(math.radians(pitch_deg))
    T[:3, 3] = t
    return T


#: Step tolerances: the peers reach 0.01-4 mm and < 0.05 deg on these renders; a swapped
#: or inverted convention would be off by about 80 mm and 4 deg.
TOL_M, TOL_DEG = 0.006, 0.15


def errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error deg) of ``T_est`` against ``T_true``."""
    E = np.linalg.inv(T_true) @ T_est
    ang = math.degrees(math.acos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(E[:3, 3])), ang


# Four views of a robot-like path: forward, turning left (about -y in the y-down frame).
POSES = [pose(0, [0, 0, 0]), pose(-2.0, [0.01, 0.0, 0.04]), pose(-4.5, [0.025, 0.0, 0.075]),
         pose(-6.0, [0.04, 0.0, 0.11])]


@pytest.fixture(scope="module")
def frames():
    return [render(T, i) for i, T in enumerate(POSES)]


@pytest.mark.parametrize("name", list(PEER_METHODS))
def test_step_recovers_known_motion(frames, name):
    m = make_method(name, INTR)
    a, b = m.prepare(frames[0]), m.prepare(frames[1])
    step = m.estimate(a, b)
    assert step.ok, step.reason
    T_true = np.linalg.inv(POSES[0]) @ POSES[1]
    dt, dr = errors(step.T_prev_curr, T_true)
    assert dt < TOL_M and dr < TOL_DEG, (dt, dr)
    # The reverse pair gives the inverse motion.
    back = m.estimate(b, a)
    dt, dr = errors(back.T_prev_curr, np.linalg.inv(T_true))
    assert back.ok and dt < TOL_M and dr < TOL_DEG, (dt, dr)


@pytest.mark.parametrize("name", list(PEER_METHODS))
def test_track_chains_world_poses_and_counts_failures(frames, name):
    def restamp(f, i):
        return RGBDFrame(i, 0.1 * i, f.color, f.depth)

    broken = RGBDFrame(2, 0.2, frames[2].color, np.zeros_like(frames[2].depth))
    stream = [frames[0], frames[1], broken, restamp(frames[2], 3), restamp(frames[3], 4)]
    run = track(stream, INTR, [name], T_world_cam0=POSES[0])[name]
    stamps, poses = run.arrays()
    assert poses.shape == (5, 4, 4) and np.allclose(stamps, [0.0, 0.1, 0.2, 0.3, 0.4])
    assert np.allclose(poses[0], POSES[0])
    dt, dr = errors(poses[1], POSES[1])
    assert dt < TOL_M and dr < TOL_DEG
    # No depth in frame 2: both steps touching it fail; identity is chained and counted.
    assert run.failures == [2, 3] and run.reasons[2] and run.reasons[3]
    assert np.array_equal(poses[2], poses[1]) and np.array_equal(poses[3], poses[1])
    # Frame to frame again afterwards: the last pose is pose 1 composed with the true 2 -> 3 step.
    dt, dr = errors(poses[4], POSES[1] @ np.linalg.inv(POSES[2]) @ POSES[3])
    assert dt < 2 * TOL_M and dr < 2 * TOL_DEG, (dt, dr)  # two steps' errors
    assert run.time_s > 0 and math.isfinite(run.ms_per_frame)


def test_track_starts_from_given_world_pose(frames):
    T0 = pose(30.0, [1.0, -0.2, 0.5])  # any first pose: later ones are T0 @ T_cam0_cami
    runs = track(frames[:2], INTR, ["open3d_legacy"], T_world_cam0=T0)
    _, poses = runs["open3d_legacy"].arrays()
    dt, dr = errors(poses[1], T0 @ np.linalg.inv(POSES[0]) @ POSES[1])
    assert dt < TOL_M and dr < TOL_DEG


def test_constant_velocity_prior_chain(frames):
    runs = track(frames, INTR, ["open3d_tensor"], PeerOptions(init="constant_velocity"))
    _, poses = runs["open3d_tensor"].arrays()
    for k in range(1, 4):
        dt, dr = errors(poses[k], POSES[k])
        assert dt < k * TOL_M and dr < k * TOL_DEG, (k, dt, dr)


def test_input_validation():
    with pytest.raises(ValueError, match="unknown peer method 'orb'"):
        make_method("orb", INTR)
    with pytest.raises(ValueError, match="depth_max_m"):
        PeerOptions(depth_max_m=-1.0)
    with pytest.raises(ValueError, match="init"):
        PeerOptions(init="zero")
    m = make_method("opencv", INTR)
    bad = RGBDFrame(0, 0.0, np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320), np.float64))
    with pytest.raises(ValueError, match=r"depth must be \(H, W\) float32"):
        m.prepare(bad)
    small = RGBDFrame(0, 0.0, np.zeros((120, 160, 3), np.uint8), np.zeros((120, 160), np.float32))
    with pytest.raises(ValueError, match="160x120 but the intrinsics say 320x240"):
        m.prepare(small)
    with pytest.raises(ValueError, match=r"T_world_cam0 must be \(4, 4\)"):
        PeerTracker(m, np.eye(3))


class _Recorder(PeerMethod):
    """Test double: returns a fixed step and records the initial guesses it was given."""

    name, label = "recorder", "recorder"
    STEP = pose(-1.0, [0.0, 0.0, 0.05])

    def __init__(self, options):
        super().__init__(INTR, options)
        self.inits = []

    def prepare(self, frame):
        return frame.index

    def estimate(self, prev, curr, init=None):
        self.inits.append(None if init is None else init.copy())
        return PeerStep(self.STEP.copy(), curr != 2, "" if curr != 2 else "reported failure")


def test_constant_velocity_init_follows_the_last_good_step():
    m = _Recorder(PeerOptions(init="constant_velocity"))
    t = PeerTracker(m)
    for i in range(5):
        t.add(RGBDFrame(i, float(i), np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.float32)))
    # steps into 1..4: no history, last step, (failure at 2 resets), none, last step
    assert m.inits[0] is None and np.array_equal(m.inits[1], m.STEP)
    assert m.inits[2] is None and np.array_equal(m.inits[3], m.STEP)
    assert t.run.failures == [2]
    assert np.allclose(t.run.poses[4], m.STEP @ m.STEP @ m.STEP)
    m2 = _Recorder(PeerOptions(init="identity"))
    t2 = PeerTracker(m2)
    for i in range(3):
        t2.add(RGBDFrame(i, float(i), np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.float32)))
    assert m2.inits == [None, None]


# ----------------------------------------------------------------- bench peers

@pytest.fixture(scope="module")
def synthetic_log(tmp_path_factory, frames):
    """The four rendered views as an MCAP (lossless images) carrying ground truth."""
    from planar_vo.io import RGBDLogWriter

    path = tmp_path_factory.mktemp("peers") / "room.mcap"
    with RGBDLogWriter(path, INTR, color_encoding="bgr8", depth_encoding="32FC1") as w:
        for f, T in zip(frames, POSES):
            w.write(f)
            w.write_ground_truth(f.stamp, T)
    return path


def _bench_args(*argv):
    import argparse

    from planar_vo.bench import peers as bench

    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    return bench, p.parse_args([str(a) for a in argv])


def test_bench_peers_figures_on_a_log_with_ground_truth(synthetic_log, tmp_path, capsys):
    out_json = tmp_path / "peers.json"
    bench, args = _bench_args(synthetic_log, "--methods", "open3d_tensor", "opencv",
                              "--json", out_json, "--out", tmp_path / "runs")
    assert bench.main(args) == 0
    text = capsys.readouterr().out
    assert "room.mcap: 4 frames 320x240, ground truth 4 poses" in text
    assert "Open3D tensor multi-scale" in text and "OpenCV RGB-D" in text
    import json

    res = json.loads(out_json.read_text())["logs"][0]
    assert res["frames"] == 4 and res["ground_truth"]["poses"] == 4
    for name in ("open3d_tensor", "opencv"):
        r = res["methods"][name]
        assert r["failures"] == 0 and r["ms_per_frame"] > 0
        e = r["errors"]
        assert e["matched"] == 4
        gt_path = sum(np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in zip(POSES, POSES[1:]))
        assert e["path_length_m"] == pytest.approx(gt_path, abs=1e-9)
        assert e["ate_rmse_m"] < TOL_M and abs(e["final_yaw_error_deg"]) < 3 * TOL_DEG
        # The kept trajectory starts at the ground-truth first pose and ends near the last.
        from planar_vo.io.trajectory import read_tum_trajectory

        traj = read_tum_trajectory(tmp_path / "runs" / "room" / f"{name}.tum")
        assert np.allclose(traj.poses[0], POSES[0], atol=1e-9)
        assert np.linalg.norm(traj.poses[-1][:3, 3] - POSES[-1][:3, 3]) < 3 * TOL_M
    assert res["ratios"] == {}  # planar-vo not run: no ratios


def test_bench_peers_rejects_bad_arguments(synthetic_log, tmp_path):
    from planar_vo.core.errors import InputError

    bench, args = _bench_args(synthetic_log, synthetic_log, "--gt", tmp_path / "a.tum")
    with pytest.raises(InputError, match="--gt given 1 times for 2 logs"):
        bench.main(args)
    bench, args = _bench_args(tmp_path / "missing.mcap")
    with pytest.raises(InputError, match="missing.mcap: no such log"):
        bench.main(args)
    bench, args = _bench_args(synthetic_log, "--frames", "1")
    with pytest.raises(InputError, match="--frames must be >= 2"):
        bench.main(args)


def test_format_table_ratios_and_missing_values():
    from planar_vo.bench.peers import _ratios, format_table

    def row(label, drift, ms):
        return {"label": label, "failures": 1, "ms_per_frame": ms,
                "errors": {"ate_rmse_m": 0.01, "endpoint_drift_pct": drift, "final_yaw_error_deg": float("nan"),
                           "path_length_m": 10.0}}

    res = {"log": "x/loop.mcap", "frames": 300, "image_size": [640, 480],
           "ground_truth": {"poses": 300}, "peer_pass": {"decode_ms_per_frame": 4.0},
           "methods": {"planar_vo_smoothed": row("planar-vo smoothed", 0.2, 5.0),
                       "open3d_tensor": row("Open3D tensor multi-scale", 3.0, 50.0),
                       "opencv": row("OpenCV RGB-D", 1.5, 30.0)},
           "planar_vo_end_to_end": {"fps": 80.0}}
    res["ratios"] = _ratios(res)
    assert res["ratios"]["best_peer"] == "opencv"
    assert res["ratios"]["drift_ratio_best_peer_over_planar_vo"] == pytest.approx(7.5)
    assert res["ratios"]["speedup_vs_open3d_tensor"] == pytest.approx(4.0)  # 80 fps / 20 fps
    text = format_table(res)
    assert "loop.mcap: 300 frames 640x480, ground truth 300 poses, path 10.00 m" in text
    assert "= 4.00x (target >= 3x: met)" in text and "= 7.50x (target >= 5x: met)" in text
    assert "n/a" in text  # the NaN yaw error


def test_bench_peers_with_planar_vo_on_a_synthetic_log(lturn_log, capsys):
    """planar-vo's rows, end-to-end fps and both target ratios, on the first 12 frames."""
    import json

    bench, args = _bench_args(lturn_log, "--frames", "12", "--methods", "planar_vo", "open3d_tensor",
                              "--json", lturn_log.parent / "peers12.json")
    assert bench.main(args) == 0
    text = capsys.readouterr().out
    res = json.loads((lturn_log.parent / "peers12.json").read_text())["logs"][0]
    m = res["methods"]
    assert list(m) == ["planar_vo_raw", "planar_vo_smoothed", "open3d_tensor"]
    assert res["ground_truth"]["source"].endswith("(/ground_truth)")
    for name, r in m.items():
        assert r["frames"] == 12 and r["errors"]["matched"] == 12, name
        assert r["ms_per_frame"] > 0
        # 12 frames at 0.5 m/s after a 1 s ramp: a few decimetres, a few millimetres of error
        assert r["errors"]["ate_rmse_m"] < 0.02, (name, r["errors"])
    e2e = res["planar_vo_end_to_end"]
    assert e2e["fps"] > 0 and e2e["decode_ms_per_frame"] > 0
    q = res["ratios"]
    assert q["speedup_vs_open3d_tensor"] == pytest.approx(e2e["fps"] * m["open3d_tensor"]["ms_per_frame"] / 1000)
    assert q["best_peer"] == "open3d_tensor"
    assert q["drift_ratio_best_peer_over_planar_vo"] == pytest.approx(
        m["open3d_tensor"]["errors"]["endpoint_drift_pct"] / m["planar_vo_smoothed"]["errors"]["endpoint_drift_pct"])
    assert "planar-vo end-to-end fps / Open3D tensor fps" in text and "best peer (Open3D tensor" in text
