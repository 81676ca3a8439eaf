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


def drive_front_end(d, intrinsics, T_base_cam, config):
    """The front-end over a :class:`~planar_vo.sim.problems.FarCornerDrive` (its corners, no
    walls, no images), frame by frame: yields ``(i, step, info, odometry)``, the step into
    frame ``i`` (None for frame 0), its diagnostics and the :class:`PlanarOdometry` after it
    (its ``_gap_links`` are those measured at frame ``i``)."""
    import numpy as np

    from planar_vo.core.steps import FrameDiagnostics
    from planar_vo.core.types import Mount
    from planar_vo.frontend.odometry import PlanarOdometry, _Prev

    odo = PlanarOdometry(intrinsics, Mount(T_base_cam), config)
    n = d.x.shape[1]
    ident = np.column_stack([np.arange(n), np.arange(n)])
    for i in range(len(d.x)):
        info = FrameDiagnostics()
        info.floor_seen = True
        yaw_prior = odo._last_motion[0] if odo._last_motion is not None else 0.0
        odo._unread = ~np.isfinite(d.P[i][:, 2])  # as process() takes it from the tracker (features.unread)
        step, _ = odo._measure(d.x[i], d.P[i], ident if i else ident[:0], [], [], [], yaw_prior, info)
        odo._prev = _Prev(None, d.x[i], d.P[i], [], [], [])
        odo._n += 1
        yield i, step, info, odo
