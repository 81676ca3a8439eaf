"""Peer RGB-D odometry wrappers against a ray-cast textured room with known motion."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.geometry import rot_x, rot_y
from planar_vo.io.types import CameraIntrinsics, RGBDFrame
from planar_vo.peers import PEER_METHODS, PeerMethod, PeerOptions, PeerStep, PeerTracker, make_method, track

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
