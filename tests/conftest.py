"""Shared fixtures: small synthetic logs rendered once per session (per xdist worker)."""
import os

import pytest

from planar_vo.sim.synth import SynthConfig, write_synth_log


#: Most xdist workers ``-n auto`` starts: many tests run ``planar-vo run``, whose reader and
#: plot processes take a core of their own, and each worker holds its module's rendered logs.
MAX_WORKERS = 4


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject's addopts): one worker per usable core, at most MAX_WORKERS."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(MAX_WORKERS, cores or 1))


@pytest.fixture(scope="session")
def lturn_log(tmp_path_factory):
    """A 100-frame L-turn Kinect v2 qhd log (ROS 2 profile) with ground truth beside it."""
    out = tmp_path_factory.mktemp("logs") / "lturn.mcap"
    cfg = SynthConfig(layout="lturn", seed=5, n_frames=100, speed=0.5)
    write_synth_log(cfg, out, progress=False)
    return out


def rewrite_mcap(src, dst, edit):
    """Copy an MCAP message by message; ``edit(topic, k, data) -> data`` may change the payload of
    the ``k``-th message (0-based) on each topic, e.g. to corrupt it."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        w = Writer(g)
        w.start()
        schemas, channels, counts = {}, {}, {}
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas[schema.id], channel.metadata)
            k = counts.get(channel.topic, 0)
            counts[channel.topic] = k + 1
            w.add_message(channels[channel.id], msg.log_time, edit(channel.topic, k, msg.data), msg.publish_time)
        w.finish()


@pytest.fixture
def mcap_rewriter():
    """:func:`rewrite_mcap`, for tests in any folder."""
    return rewrite_mcap
