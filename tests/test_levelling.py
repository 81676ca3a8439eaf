"""Levelling: precedence of config / mount / floor, robust floor estimation, the built mount."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.core import geometry as g
from planar_vo.frontend.config import LevellingConfig, PlaneConfig
from planar_vo.frontend.levelling import Levelling
from planar_vo.frontend.planes import PlaneDetector
from planar_vo.core.types import CameraIntrinsics, Mount

K = CameraIntrinsics(640, 360, 360.0, 360.0, 319.5, 179.5)


def _mount(pitch_deg, roll_deg, height, yaw_deg=0.0, x=0.1):
    T = np.eye(4)
    T[:3, :3] = g.mount_rotation(math.radians(pitch_deg), math.radians(roll_deg), math.radians(yaw_deg))
    T[:3, 3] = (x, 0.02, height)
    return Mount(T)


def _floor_in_lev(pitch, roll, lev_pitch, lev_roll, height):
    """Floor ``(normal, offset)`` seen in the frame levelled with (lev_pitch, lev_roll)
    by a camera truly mounted with (pitch, roll)."""
    down_cam = g.levelling_rotation(pitch, roll).T @ np.array([0.0, 1.0, 0.0])
    return g.levelling_rotation(lev_pitch, lev_roll) @ down_cam, height


def test_given_mount_is_used_and_not_refined():
    m = _mount(12.0, -1.5, 0.75, yaw_deg=3.0)
    lev = Levelling(LevellingConfig(), m)
    s = lev.state
    assert s.source == "mount" and s.ready
    assert math.degrees(s.pitch) == pytest.approx(12.0) and math.degrees(s.roll) == pytest.approx(-1.5)
    assert s.height == pytest.approx(0.75)
    assert not lev.needs_floor
    n, d = _floor_in_lev(math.radians(15), 0.0, s.pitch, s.roll, 0.9)
    assert lev.observe_floor(n, d, 0.3) is False
    assert lev.mount() is m


def test_config_overrides_mount_tilt_and_keeps_its_position():
    m = _mount(12.0, -1.5, 0.75, yaw_deg=3.0)
    lev = Levelling(LevellingConfig(pitch_deg=9.0, roll_deg=1.0), m)
    s = lev.state
    assert s.source == "config"
    assert math.degrees(s.pitch) == pytest.approx(9.0) and math.degrees(s.roll) == pytest.approx(1.0)
    built = lev.mount().T_base_cam
    p, r, y = g.mount_angles(built[:3, :3])
    assert math.degrees(p) == pytest.approx(9.0) and math.degrees(r) == pytest.approx(1.0)
    assert math.degrees(y) == pytest.approx(3.0)
    assert built[:3, 3] == pytest.approx([0.1, 0.02, 0.75])


def test_nan_height_in_mount_is_measured_from_the_floor():
    m = _mount(10.0, 2.0, float("nan"))
    lev = Levelling(LevellingConfig(), m)
    assert lev.state.height is None and lev.needs_floor
    s = lev.state
    n, d = _floor_in_lev(s.pitch, s.roll, s.pitch, s.roll, 0.83)
    lev.observe_floor(n, d, 0.3)
    assert lev.state.height == pytest.approx(0.83)
    assert lev.mount().T_base_cam[2, 3] == pytest.approx(0.83)


def test_floor_estimates_are_pooled_robustly():
    rng = np.random.default_rng(7)
    pitch, roll, h = math.radians(11.0), math.radians(-2.5), 0.62
    cfg = LevellingConfig(init_frames=5)
    lev = Levelling(cfg)
    assert lev.state.source == "initial" and not lev.state.ready
    for i in range(30):
        s = lev.state
        n, d = _floor_in_lev(pitch + rng.normal(0, 0.003), roll + rng.normal(0, 0.003), s.pitch, s.roll,
                             h + rng.normal(0, 0.005))
        if i in (12, 20):  # a table top or a ramp: a wildly different "floor"
            n, d = _floor_in_lev(pitch + 0.3, roll, s.pitch, s.roll, 0.3)
        lev.observe_floor(n, d, 0.3)
        if i == cfg.init_frames - 1:
            assert lev.state.ready
    s = lev.state
    assert s.source == "floor" and s.ready
    assert s.n_rejected == 2
    assert abs(math.degrees(s.pitch - pitch)) < 0.1 and abs(math.degrees(s.roll - roll)) < 0.1
    assert s.height == pytest.approx(h, abs=0.005)
    # built mount: base_link on the floor under the camera, heading along the camera
    T = lev.mount().T_base_cam
    assert T[:3, 3] == pytest.approx([0.0, 0.0, s.height])
    p, r, y = g.mount_angles(T[:3, :3])
    assert (p, r, y) == pytest.approx((s.pitch, s.roll, 0.0))
    # small support is ignored
    assert lev.observe_floor(np.array([0.0, 1.0, 0.0]), 1.0, 0.001) is False


def _raycast_floor(K, pitch, roll, h, rng):
    R = g.levelling_rotation(pitch, roll)
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    r = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    den = (r @ R.T)[:, 1]
    z = np.where(den > 1e-6, h / np.where(den > 1e-6, den, 1.0), 0.0)
    z = z + rng.normal(0, 1, z.shape) * 0.0015 * z ** 2
    z[(z > 8) | (z < 0)] = 0
    return z.reshape(K.height, K.width).astype(np.float32)


def test_levelling_converges_on_a_rendered_floor():
    rng = np.random.default_rng(3)
    pitch, roll, h = math.radians(18.0), math.radians(3.0), 0.55
    lev = Levelling(LevellingConfig(init_frames=3))
    det = PlaneDetector(K, PlaneConfig(stride=4))
    for _ in range(4):
        depth = _raycast_floor(K, pitch, roll, h, rng)
        s = lev.state
        det.set_levelling(s.R_lev_cam)
        d = det.detect(depth, levelled=s.ready, walls=False)
        assert d.floor is not None
        lev.observe_floor(d.floor.normal, d.floor.offset, d.floor.support)
    s = lev.state
    assert s.ready
    assert abs(math.degrees(s.pitch - pitch)) < 0.1 and abs(math.degrees(s.roll - roll)) < 0.1
    assert s.height == pytest.approx(h, abs=0.003)


def test_config_validation():
    from planar_vo.configtools import from_dict
    from planar_vo.core.errors import ConfigError
    from planar_vo.frontend.config import FrontendConfig

    with pytest.raises(ConfigError, match="levelling.heigth_m"):
        from_dict(FrontendConfig, {"levelling": {"heigth_m": 0.8}})
    with pytest.raises(ConfigError, match="height_m"):
        from_dict(FrontendConfig, {"levelling": {"height_m": -1.0}})
    cfg = from_dict(FrontendConfig, {"levelling": {"pitch_deg": 10, "roll_deg": 0}, "features": {"method": "orb"}})
    assert cfg.levelling.pitch_deg == 10.0 and cfg.features.method == "orb"
