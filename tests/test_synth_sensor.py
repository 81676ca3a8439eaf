"""The synthetic camera's Kinect v2 effects (``SynthConfig`` exposure/readout/delay/AE/flicker/flying pixels).

The timing effects are checked against the renderer itself: an image exposed over an
interval must match ideal renders at the poses of that interval, which pins the sign and
size of the image motion used to synthesise them.
"""
from __future__ import annotations

import numpy as np
import pytest

from planar_vo.core.errors import ConfigError
from planar_vo.sim.synth import (SENSOR_PRESETS, SynthConfig, SynthRenderer, _poses_at, _twists_at,
                                render_sequence, with_sensor)


def small(**kw) -> SynthConfig:
    return SynthConfig(layout="lturn", texture="medium", image_noise=0.0, **kw).at_resolution(320, 180)


def turning_frame(cfg: SynthConfig) -> float:
    """Time (s after the first frame) of the fastest yaw rate: the largest image motion."""
    t = np.arange(cfg.n_frames) / cfg.rate_hz
    return float(t[np.argmax(np.abs(_twists_at(cfg, SynthRenderer(cfg).scene, t)[:, 2]))])


def render_at(renderer: SynthRenderer, cfg: SynthConfig, t: float, twist=None) -> np.ndarray:
    pose = _poses_at(cfg, renderer.scene, np.array([t]))[0]
    tw = None if twist is None else _twists_at(cfg, renderer.scene, np.array([t]))[0]
    return renderer.render(pose, index=0, twist=tw).rgbd.color.astype(np.float64)


def interior(img: np.ndarray, m: int = 12) -> np.ndarray:
    return img[m:-m, m:-m]


def mad(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(interior(a) - interior(b)).mean())


@pytest.fixture(scope="module")
def ideal():
    cfg = small(seed=3)
    r = SynthRenderer(cfg)
    return cfg, r, turning_frame(cfg)


def test_twist_is_the_base_velocity_in_base_link_axes(ideal):
    cfg, r, t = ideal
    tw = _twists_at(cfg, r.scene, np.array([t]))[0]
    a, b = _poses_at(cfg, r.scene, np.array([t, t + 0.01]))
    # REP 103: x forward, y left, yaw counter-clockwise; the robot drives forwards
    assert abs(tw[0] - cfg.speed) < 0.02 * cfg.speed and abs(tw[1]) < 0.2 * cfg.speed
    assert tw[2] == pytest.approx((b[2] - a[2]) / 0.01, rel=0.02)
    step = np.array([[np.cos(a[2]), np.sin(a[2])], [-np.sin(a[2]), np.cos(a[2])]]) @ (b[:2] - a[:2])
    np.testing.assert_allclose(step / 0.01, tw[:2], atol=0.01)


def test_colour_delay_shows_the_scene_at_the_delayed_pose(ideal):
    cfg0, r0, t = ideal
    cfg = small(seed=3, color_delay_ms=30.0)
    r = SynthRenderer(cfg)
    d = r.color_delay_s
    assert abs(d) > 0.01  # this seed draws a usable delay (the bound is 30 ms)
    img = render_at(r, cfg, t, twist=True)
    # ideal views at times t + k d: the best match is k = 1 (resampling leaves a floor of ~2 grey levels)
    err = {k: mad(img, render_at(r0, cfg0, t + k * d)) for k in (-1.0, 0.0, 0.5, 1.0, 2.0)}
    assert min(err, key=err.get) == 1.0
    assert err[1.0] < 0.6 * err[0.0] and err[1.0] < 0.35 * err[-1.0]


def test_exposure_averages_the_views_over_the_shutter_interval(ideal):
    cfg0, r0, t = ideal
    cfg = small(seed=3, exposure_ms=40.0)
    img = render_at(SynthRenderer(cfg), cfg, t, twist=True)
    sharp = render_at(r0, cfg0, t)
    err = {e: mad(img, np.mean([render_at(r0, cfg0, t + s) for s in np.linspace(-e / 2, e / 2, 9)], axis=0))
           for e in (0.02, 0.04, 0.08)}  # averages of ideal views over shutter intervals of e seconds
    assert min(err, key=err.get) == 0.04
    assert err[0.04] < 0.5 * mad(img, sharp)
    # blur removes image gradient energy along the motion
    gx = lambda im: np.abs(np.diff(interior(im).mean(2), axis=1)).mean()  # noqa: E731
    assert gx(img) < 0.9 * gx(sharp)


def test_rolling_shutter_exposes_top_rows_first(ideal):
    cfg0, r0, t = ideal
    cfg = small(seed=3, readout_ms=60.0)
    img = render_at(SynthRenderer(cfg), cfg, t, twist=True)
    early, late = render_at(r0, cfg0, t - 0.03), render_at(r0, cfg0, t + 0.03)
    top, bottom = slice(12, 50), slice(130, 168)
    e_top, l_top = (np.abs(img[top] - x[top])[:, 12:-12].mean() for x in (early, late))
    e_bot, l_bot = (np.abs(img[bottom] - x[bottom])[:, 12:-12].mean() for x in (early, late))
    assert e_top < 0.6 * l_top and l_bot < 0.6 * e_bot


def test_still_camera_is_unchanged_by_timing_effects(ideal):
    cfg0, r0, t = ideal
    cfg = small(seed=3, exposure_ms=20.0, readout_ms=15.0, color_delay_ms=16.0)
    pose = _poses_at(cfg, r0.scene, np.array([t]))[0]
    a = SynthRenderer(cfg).render(pose, index=5, twist=np.zeros(3)).rgbd.color
    b = r0.render(pose, index=5).rgbd.color
    assert np.abs(a.astype(int) - b).max() <= 1


def test_auto_exposure_holds_the_mean_grey_and_flicker_varies_it():
    frames = [40, 120, 200, 260]
    ideal = [f.rgbd.color.mean() for f in render_sequence(small(seed=4), frames)]
    ae = [f.rgbd.color.mean() for f in render_sequence(small(seed=4, auto_exposure=True, ae_target=90.0), frames)]
    assert np.ptp(ideal) > 5.0  # the views differ in brightness...
    np.testing.assert_allclose(ae, 90.0, atol=2.0)  # ...but auto-exposure meters them to the target
    fl = [f.rgbd.color.mean() for f in render_sequence(small(seed=4, auto_exposure=True, ae_target=90.0,
                                                             flicker=0.05), range(100, 130))]
    ratio = np.std(np.array(fl) / 90.0)
    assert 0.025 < ratio < 0.08


def test_flying_pixels_lie_between_the_surfaces_of_a_depth_edge():
    cfg0 = SynthConfig(layout="straight", texture="none", seed=0).at_resolution(240, 135)
    holes = next(render_sequence(cfg0, [200]))
    fly = next(render_sequence(SynthConfig(**{**cfg0.__dict__, "flying_pixels": 1.0}), [200]))
    zt = fly.truth["depth_true"]
    d0, d1 = holes.rgbd.depth, fly.rgbd.depth
    changed = (d0 == 0) & (d1 > 0)
    assert changed.sum() > 30
    # each returned edge pixel is a mixture: within the depth range of its 3x3 true neighbourhood
    r, c = np.nonzero(changed)
    r, c = np.clip(r, 1, zt.shape[0] - 2), np.clip(c, 1, zt.shape[1] - 2)
    nb = np.stack([zt[r + i, c + j] for i in (-1, 0, 1) for j in (-1, 0, 1)], 1)
    nb = np.where(nb > 0, nb, np.nan)
    lo, hi = np.nanmin(nb, 1), np.nanmax(nb, 1)
    inside = (d1[changed] > lo - 0.05) & (d1[changed] < hi + 0.05)
    assert inside.mean() > 0.95
    # and most are neither surface: strictly away from the true depth of their own pixel
    assert (np.abs(d1[changed] - zt[changed]) > 0.02).mean() > 0.5
    # other readings are untouched (the random dropouts that follow in the stream move)
    same = ~changed & (d0 > 0) & (d1 > 0)
    np.testing.assert_array_equal(d0[same], d1[same])


def test_kinect2_preset_renders_deterministically_and_subset_independent():
    cfg = with_sensor(small(seed=5), "kinect2")
    assert cfg.auto_exposure and cfg.exposure_ms == SENSOR_PRESETS["kinect2"]["exposure_ms"]
    a = list(render_sequence(cfg, [30, 90]))
    b = list(render_sequence(cfg, [90]))
    np.testing.assert_array_equal(a[1].rgbd.color, b[0].rgbd.color)
    np.testing.assert_array_equal(a[1].rgbd.depth, b[0].rgbd.depth)
    assert with_sensor(cfg, "ideal") == small(seed=5)


def test_sensor_settings_are_validated():
    with pytest.raises(ConfigError, match="SynthConfig.exposure_ms"):
        SynthConfig(exposure_ms=-1.0)
    with pytest.raises(ConfigError, match="SynthConfig.exposure_ms: .*frame period"):
        SynthConfig(exposure_ms=90.0, readout_ms=20.0)
    with pytest.raises(ConfigError, match="SynthConfig.flying_pixels"):
        SynthConfig(flying_pixels=1.5)
    with pytest.raises(ConfigError, match="sensor 'kinect1'"):
        with_sensor(SynthConfig(), "kinect1")


def test_cli_sensor_flag(tmp_path, capsys):
    from planar_vo.cli import main

    out = tmp_path / "k.mcap"
    assert main(["synth", str(out), "--layout", "straight", "--frames", "30", "--size", "64x36",
                 "--sensor", "kinect2", "--quiet"]) == 0
    assert out.exists()
    capsys.readouterr()
    assert main(["synth", str(tmp_path / "x.mcap"), "--layout", "straight", "--sensor", "kinect1"]) == 2
    err = capsys.readouterr().err
    assert "--sensor 'kinect1'" in err and "kinect2" in err
