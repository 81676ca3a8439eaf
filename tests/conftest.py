"""Shared fixtures: small synthetic logs rendered once per session."""
import pytest

from planar_vo.io.synth import SynthConfig, write_synth_log


@pytest.fixture(scope="session")
def lturn_log(tmp_path_factory):
    """A 100-frame L-turn Kinect v2 qhd log (ROS 2 profile) with ground truth beside it."""
    out = tmp_path_factory.mktemp("logs") / "lturn.mcap"
    cfg = SynthConfig(layout="lturn", seed=5, n_frames=100, speed=0.5)
    write_synth_log(cfg, out, progress=False)
    return out
