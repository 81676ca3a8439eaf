"""Helpers for the data-layer tests: seeded synthetic frames, low-level MCAP writing."""
from __future__ import annotations

import numpy as np
from planar_vo.io import messages as m
from planar_vo.io import ros2_msgdefs
from planar_vo.core.types import CameraIntrinsics, RGBDFrame

W, H = 64, 48
INTR = CameraIntrinsics(W, H, 50.0, 51.0, 31.5, 23.5)


def make_frames(n: int, seed: int, w: int = W, h: int = H, t0: float = 1_700_000_000.0, dt: float = 1 / 30):
    """``n`` frames of smooth random colour (JPEG-friendly) and depth on a 1 mm grid."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    frames = []
    for i in range(n):
        phase = rng.uniform(0, 2 * np.pi, 3)
        color = np.stack([127 + 100 * np.sin(xx / 7.0 + phase[c] + yy / 11.0) for c in range(3)], -1)
        color = np.clip(color + rng.normal(0, 2, color.shape), 0, 255).astype(np.uint8)
        mm = rng.integers(400, 6000, (h, w)).astype(np.float32)
        mm[rng.random((h, w)) < 0.1] = 0  # invalid pixels
        depth = mm / np.float32(1000.0)
        frames.append(RGBDFrame(i, t0 + i * dt, color, depth))
    return frames


def write_ros2(path, messages) -> None:
    """Low-level ROS 2 MCAP: ``messages`` = [(topic, datatype, msg dict, stamp)] in order."""
    from mcap_ros2.writer import Writer
    with open(path, "wb") as f:
        w = Writer(f)
        schemas = {}
        for topic, dtype, msg, stamp in messages:
            if dtype not in schemas:
                schemas[dtype] = w.register_msgdef(dtype, ros2_msgdefs.DEFINITIONS[dtype])
            t = m.stamp_to_ns(stamp)
            w.write_message(topic, schemas[dtype], msg, log_time=t, publish_time=t)
        w.finish()


