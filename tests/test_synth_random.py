"""Randomized scenes (issue 9) and the sweep's statistics, against known numbers."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.bench.sweep import parse_seeds, plan, pool_normalised, spread, step_errors, summarise
from planar_vo.core.errors import InputError
from planar_vo.core.geometry import se2_compose, wrap_angle
from planar_vo.sim.synth import SynthConfig, render_sequence, synth_mount, synth_trajectory
from planar_vo.sim.synth_random import RANGES, describe, randomized_config
from planar_vo.io.trajectory import Trajectory

LAYOUTS = ("straight", "lturn", "loop", "two_frames", "hall")


def test_randomized_config_is_deterministic_and_within_ranges():
    assert describe(randomized_config(7, "lturn")) == describe(randomized_config(7, "lturn"))
    assert describe(randomized_config(7, "lturn")) != describe(randomized_config(8, "lturn"))
    textures, effects = set(), 0
    for seed in range(40):
        for layout in LAYOUTS:
            c = randomized_config(seed, layout)
            for key in ("corridor_width", "cam_height", "pitch_deg", "roll_deg", "speed", "door_proud_m",
                        "poster_proud_m", "box_density", "branch_angle_deg", "depth_incidence", "edge_dropout",
                        "image_noise", "vignetting", "light_gain"):
                lo, hi = RANGES[key]
                assert lo <= getattr(c, key) <= hi, (seed, layout, key)
            assert c.rate_hz in RANGES["rate_hz"] and c.n_frames >= 300
            assert c.speed * (c.duration - min(c.ramp_s, c.duration / 2)) >= 6.0  # path long enough
            assert 2 <= len(c.weave_components) <= 3
            textures.add(c.texture)
            effects += c.auto_exposure
    assert textures == {"none", "low", "medium", "rich"}
    assert 60 < effects < 140  # about half of the 200 logs have Kinect v2 timing effects
    assert randomized_config(3, "straight", n_frames=1000).n_frames >= 1000


@pytest.mark.parametrize("seed", range(12))
def test_wobble_turns_the_heading_fast_but_within_the_cap(seed):
    """Ground-truth heading rates stay at or below 10 deg/s (the cap) and the weave reaches
    several deg/s on some seeds: a slow weave alone would not show mechanism 1."""
    c = randomized_config(seed, "straight")
    stamps, poses = synth_trajectory(c)
    rate = np.degrees(np.abs(wrap_angle(np.diff(poses[:, 2])))) / np.diff(stamps)
    heading = np.degrees(np.abs(wrap_angle(poses[:, 2])))
    assert rate.max() <= 10.0 and heading.max() <= 6.0


def test_wobble_reaches_fast_heading_rates_on_some_seeds():
    peaks = [np.degrees(np.abs(wrap_angle(np.diff(synth_trajectory(randomized_config(s, "straight"))[1][:, 2]))))
             .max() * randomized_config(s, "straight").rate_hz for s in range(12)]
    assert max(peaks) > 6.0 and np.median(peaks) > 2.0


def test_randomized_render_with_every_effect_runs():
    c = randomized_config(11, "two_frames").__class__(**{**randomized_config(11, "two_frames").__dict__})
    c = c.at_resolution(240, 135)
    frames = list(render_sequence(c, frames=[0, c.n_frames // 2]))
    depth = frames[1].rgbd.depth
    assert frames[1].rgbd.color.shape == (135, 240, 3) and (depth > 0).mean() > 0.3
    # the default configuration is untouched by the new fields
    assert SynthConfig().door_proud_m == 0.012 and SynthConfig().edge_dropout == 0.5


def test_seeds_and_plan():
    assert parse_seeds("3-5") == [3, 4, 5] and parse_seeds("7") == [7]
    with pytest.raises(InputError):
        parse_seeds("5-3")
    jobs = plan([1, 2], ["straight", "hall"], 2)
    assert [j[:2] for j in jobs] == [(1, "straight"), (1, "hall"), (2, "straight"), (2, "hall")]
    assert [j[2] is not None for j in jobs] == [True, False, False, True]


def test_spread_and_pooled_normalised_errors():
    s = spread([1.0, 2.0, 3.0, 4.0, float("nan"), None])
    assert s == {"n": 4, "median": 2.5, "p90": pytest.approx(3.7), "worst": 4.0}
    pooled = pool_normalised([{"normalised": {"dpp": {"n": 2, "sum_sq": [2.0, 8.0, 0.5]}}},
                              {"normalised": {"dpp": {"n": 2, "sum_sq": [2.0, 0.0, 1.5]}}}])
    assert pooled["dpp"]["n"] == 4 and pooled["dpp"]["rms"] == pytest.approx([1.0, math.sqrt(2.0), math.sqrt(0.5)])


def test_summary_reports_smoothed_minus_raw_and_failures():
    rec = lambda lay, raw, sm: {"status": "ok", "layout": lay, "seed": 1, "frames": 10,  # noqa: E731
                                "raw_drift_pct": raw, "smoothed_drift_pct": sm, "raw_yaw_deg": -1.0,
                                "smoothed_yaw_deg": 0.5, "steps": dict.fromkeys(("dpp", "2pt", "partial", "bridged"), 1),
                                "normalised": {}}
    s = summarise([rec("lturn", 1.0, 0.5), rec("lturn", 0.2, 0.4),
                   {"status": "failed", "layout": "hall", "seed": 2, "reason": "boom"}])
    assert s["lturn"]["smoothed_minus_raw"]["worst"] == pytest.approx(0.2)
    assert s["all"]["raw_yaw_deg"]["median"] == 1.0  # absolute values
    assert s["failed"] == [{"name": "hall_s2", "reason": "boom"}]
    # a log whose run announced it could not estimate the motion is kept apart
    s = summarise([rec("lturn", 1.0, 0.5), {**rec("lturn", 9.0, 8.0), "motion": "not_estimated"}])
    assert s["all"]["logs"] == 2 and s["announced"]["logs"] == 1 and s["estimated"]["logs"] == 1
    assert s["estimated"]["smoothed_drift_pct"]["worst"] == pytest.approx(0.5)


def test_step_errors_against_ground_truth(tmp_path):
    """Normalised errors of hand-made steps: the true steps plus known offsets."""
    c = SynthConfig()
    T_bc = np.asarray(synth_mount(c).T_base_cam)
    base = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.02], [0.2, 0.01, 0.05]])
    cam = []
    for p in base:
        T = np.eye(4)
        T[:2, :2] = [[math.cos(p[2]), -math.sin(p[2])], [math.sin(p[2]), math.cos(p[2])]]
        T[:2, 3] = p[:2]
        cam.append(T @ T_bc)
    gt = Trajectory(np.array([0.0, 0.1, 0.2]), np.array(cam))
    from planar_vo.core.geometry import se2_between
    rows = ["index,stamp,status,x,y,theta,sigma_x,sigma_y,sigma_theta,inliers"]
    offsets = {1: (0.01, 0.0, 0.0), 2: (0.0, -0.02, 0.001)}
    for k in (1, 2):
        s = se2_between(base[k - 1], base[k]) + np.array(offsets[k])
        rows.append(f"{k},{0.1 * k},dpp,{s[0]},{s[1]},{s[2]},0.01,0.01,0.001,50")
    (tmp_path / "steps.csv").write_text("\n".join(rows) + "\n")
    out = step_errors(tmp_path / "steps.csv", gt, T_bc)
    # row 1 starts at a frame not in the file: only row 2 is scored
    assert out["dpp"]["n"] == 1
    assert out["dpp"]["sum_sq"] == pytest.approx([0.0, 4.0, 1.0], abs=1e-6)
    assert out["dpp"]["nees_sum"] == pytest.approx(5.0, abs=1e-6)  # no correlation columns
    assert se2_compose(base[0], se2_between(base[0], base[1])) == pytest.approx(base[1])
    # with the correlation columns: the error (0, -2, +1) sigma goes against a stated y-theta
    # correlation of +0.8, so it is far less likely than per axis (4 + 1 = 5) says
    rows = [rows[0] + ",keyframe_lag,rho_xy,rho_xtheta,rho_ytheta"] + [r + ",1,0,0,0.8" for r in rows[1:]]
    (tmp_path / "steps.csv").write_text("\n".join(rows) + "\n")
    out = step_errors(tmp_path / "steps.csv", gt, T_bc)
    z = np.array([-2.0, 1.0])
    C = np.array([[1.0, 0.8], [0.8, 1.0]])
    assert out["dpp"]["nees_sum"] == pytest.approx(float(z @ np.linalg.solve(C, z)), rel=1e-6)
    assert out["dpp"]["nees_sum"] > 5.0 * 1.5
    pooled = pool_normalised([{"normalised": out}, {"normalised": out}])
    assert pooled["dpp"]["n"] == 2 and pooled["dpp"]["nees"] == pytest.approx(out["dpp"]["nees_sum"])


# ------------------------------------------------------------------ speed dips
def _speeds(c):
    stamps, poses = synth_trajectory(c)
    return stamps, poses, np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1) / np.diff(stamps)


def test_a_speed_dip_slows_the_base_on_the_same_path():
    """A dip of depth 1 (a momentary stop) 3 s wide at mid-run: the base drives the same path
    in the same time (same first and last pose), is at the dip's centre at ~zero speed, and
    cruises the rest at the speed that makes up for the time lost (1 / k, k = 1 - 1.5 / T)."""
    plain = SynthConfig(layout="straight", n_frames=201, rate_hz=10.0, speed=0.5, weave=0.0)
    dip = SynthConfig(layout="straight", n_frames=201, rate_hz=10.0, speed=0.5, weave=0.0,
                      speed_dips=((0.5, 3.0, 1.0),))
    _, p0, v0 = _speeds(plain)
    stamps, p1, v1 = _speeds(dip)
    np.testing.assert_allclose(p1[[0, -1]], p0[[0, -1]], atol=1e-9)
    mid = np.abs(0.5 * (stamps[1:] + stamps[:-1]) - stamps[0] - 10.0) < 0.06
    assert v1[mid].max() < 0.01                       # stopped at the centre
    k = 1.0 - 1.5 / 20.0                              # half the width, depth 1, over 20 s
    assert v1[50:70].mean() == pytest.approx(0.5 / k, rel=1e-3)  # cruising outside the dip
    assert v0[50:70].mean() == pytest.approx(0.5, rel=1e-3)
    assert np.all(np.diff(p1[:, 0]) >= -1e-9)       # never backwards
    # a dip reaching back over the start still starts and ends the run where the plain one does
    early = SynthConfig(layout="straight", n_frames=201, rate_hz=10.0, speed=0.5, weave=0.0,
                        speed_dips=((0.02, 3.0, 0.8),))
    np.testing.assert_allclose(_speeds(early)[1][[0, -1]], p0[[0, -1]], atol=1e-9)


def test_speed_dips_are_validated():
    from planar_vo.core.errors import ConfigError
    with pytest.raises(ConfigError, match="speed_dips"):
        SynthConfig(speed_dips=((1.2, 2.0, 0.5),))
    with pytest.raises(ConfigError, match="speed_dips"):
        SynthConfig(speed_dips=((0.5, 2.0, 1.5),))
    with pytest.raises(ConfigError, match="below a stop"):  # two full stops on top of each other
        SynthConfig(n_frames=300, speed_dips=((0.5, 4.0, 1.0), (0.5, 4.0, 1.0)))


def test_randomized_speed_dips_leave_every_other_draw_and_the_log_names_alone():
    """``speed_dips=True`` adds the dips and changes nothing else of the seed's draw; without
    them a config's log name is what the sweeps' caches were rendered under (a tuning log of
    seed 3700). Every dip brakes within the cap and sits inside the cruise."""
    from planar_vo.bench.sweep import log_name
    assert log_name(randomized_config(3700, "hall")) == "hall_s3700_n300_4962a00a"
    n_dips = []
    for seed in range(20):
        for layout in LAYOUTS:
            a, b = randomized_config(seed, layout), randomized_config(seed, layout, speed_dips=True)
            da, db = describe(a), describe(b)
            assert db.pop("speed_dips") and da == db and a.speed_dips == ()
            T = b.duration
            for centre, width, depth in b.speed_dips:
                assert b.ramp_s + 0.5 * width - 1e-9 <= centre * T <= T - b.ramp_s - 0.5 * width + 1e-9
                assert math.pi * depth * b.speed / width <= RANGES["speed_dip_max_decel"] + 1e-9
                assert RANGES["speed_dip_depth"][0] <= depth <= RANGES["speed_dip_depth"][1]
            n_dips.append(len(b.speed_dips))
    assert min(n_dips) >= 1 and max(n_dips) >= 2
    # the slowest moment of a drawn log is the deepest dip's
    c = randomized_config(5, "straight", speed_dips=True)
    _, _, v = _speeds(c)
    deepest = max(d for _, _, d in c.speed_dips)
    assert v[15:-15].min() < (1.0 - deepest) * c.speed + 0.05
