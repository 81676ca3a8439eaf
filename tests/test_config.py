"""Typed configuration: defaults in code, YAML overrides, unknown keys rejected."""
import pytest

from planar_vo.config import RunConfig, dump_config, load_config
from planar_vo.core.errors import ConfigError


def test_defaults_round_trip_through_yaml(tmp_path):
    cfg = load_config()
    assert isinstance(cfg, RunConfig) and cfg.solver == "batch"
    p = tmp_path / "c.yaml"
    p.write_text(dump_config(cfg))
    assert load_config(p) == cfg


def test_file_and_overrides(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("solver: online\ninput:\n  stride: 2\n")
    cfg = load_config(p, {"input": {"stride": 3}, "frontend": {"levelling": {"pitch_deg": 10.0, "roll_deg": 2}}})
    assert cfg.solver == "online" and cfg.input.stride == 3
    assert cfg.frontend.levelling.pitch_deg == 10.0 and cfg.frontend.levelling.roll_deg == 2.0


@pytest.mark.parametrize("text, needle", [
    ("solvr: batch\n", "unknown config key 'solvr'"),
    ("input:\n  strid: 2\n", "unknown config key 'input.strid'"),
    ("input:\n  stride: two\n", "input.stride"),
    ("solver: fast\n", "solver"),
    ("input:\n  fx: 500.0\n", "fx, fy, cx, cy"),
    ("- a\n- b\n", "mapping"),
    ("mount:\n  pitch_deg: 10\n", "unknown config key 'mount'"),  # the mount is set in frontend.levelling
    ("frontend:\n  levelling:\n    pitch_deg: 10\n", "both pitch_deg and roll_deg"),
    ("frontend:\n  max_depth: 0.2\n", "'frontend.max_depth' must exceed"),
    ("frontend:\n  planes:\n    min_depth: 0.5\n", "unknown config key 'frontend.planes.min_depth'"),
    ("backend:\n  gate_sigmas: -1\n", "'backend.gate_sigmas' must be > 0"),
    ("frontend:\n  odometry:\n    wall_yaw_check_sigmas: -1\n", "'odometry.wall_yaw_check_sigmas' must be >= 0"),
])
def test_bad_config_is_one_clear_error(tmp_path, text, needle):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=None) as ei:
        load_config(p)
    assert needle in str(ei.value)


def test_exponent_without_sign_is_a_number(tmp_path):
    """PyYAML (YAML 1.1) reads ``1.0e12`` as a string; a float key takes it as the number."""
    from planar_vo.config import load_config

    p = tmp_path / "c.yaml"
    p.write_text("places:\n  prior_gate_chi2: 1.0e12\n")
    assert load_config(p).places.prior_gate_chi2 == 1.0e12
