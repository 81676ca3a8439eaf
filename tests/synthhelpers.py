"""Shared by the tests that render small synthetic sequences in memory."""
from planar_vo.sim.synth import SynthConfig, render_sequence, synth_intrinsics, synth_mount


def render(**kw):
    """``(intrinsics, mount, frames)`` of ``SynthConfig(**kw)``; ``resolution=(w, h)``
    resamples the camera."""
    res = kw.pop("resolution", None)
    cfg = SynthConfig(**kw)
    if res is not None:
        cfg = cfg.at_resolution(*res)
    return synth_intrinsics(cfg), synth_mount(cfg), list(render_sequence(cfg))
