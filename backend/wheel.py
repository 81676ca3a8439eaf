"""Wheel odometry as pose-graph measurements: one relative SE(2) step per frame.

:class:`WheelSteps` turns a log's wheel odometry (stamped ``T_odom_base`` samples, see
:class:`planar_vo.io.wheel_odom.WheelOdometry`) into the step ``T_base_prev_base_curr``
between two consecutive frame stamps, interpolated on SE(2), with the information matrix
of :func:`wheel_step_information`. The graph adds it as a ``BetweenFactorPose2`` next to
the front-end's step (:meth:`planar_vo.backend.graph.PlanarPoseGraph.add_frame`).

Noise model: the covariances in odometry messages are often constants a driver fills in,
so they are not used. The sigma of a step grows with the distance ``d`` it travels and the
rotation ``r`` it turns (configurable in :class:`BackendConfig`)::

    sigma_x = sigma_y = hypot(wheel_odom_sigma_min_m, wheel_odom_sigma_per_m * d)
    sigma_theta       = hypot(wheel_odom_sigma_min_deg, wheel_odom_sigma_deg_per_m * d,
                              wheel_odom_sigma_per_rad * r)

Pure: no file I/O.
"""
from __future__ import annotations

import math

import numpy as np

from planar_vo.backend.config import BackendConfig
from planar_vo.geometry import se2_between, wrap_angle

__all__ = ["WheelSteps", "wheel_step_information", "fuse_steps"]


def wheel_step_information(step: np.ndarray, config: BackendConfig) -> np.ndarray:
    """(3, 3) information of an odometry step ``(x, y, theta)`` in Pose2 tangent order."""
    d = math.hypot(float(step[0]), float(step[1]))
    r = abs(float(step[2]))
    s_xy = math.hypot(config.wheel_odom_sigma_min_m, config.wheel_odom_sigma_per_m * d)
    s_th = math.sqrt(math.radians(config.wheel_odom_sigma_min_deg) ** 2
                     + (math.radians(config.wheel_odom_sigma_deg_per_m) * d) ** 2
                     + (config.wheel_odom_sigma_per_rad * r) ** 2)
    return np.diag(1.0 / np.array([s_xy, s_xy, s_th]) ** 2)


def fuse_steps(p1: np.ndarray, info1: np.ndarray, p2: np.ndarray, info2: np.ndarray) -> tuple:
    """Information-weighted mean of two small SE(2) steps (theta difference wrapped):
    ``(pose (3,), information (3, 3))``, e.g. the initial guess of a new pose."""
    p2 = np.array(p2, dtype=np.float64)
    p2[2] = p1[2] + float(wrap_angle(p2[2] - p1[2]))
    info = info1 + info2
    p = np.linalg.solve(info, info1 @ np.asarray(p1, dtype=np.float64) + info2 @ p2)
    p[2] = float(wrap_angle(p[2]))
    return p, info


class WheelSteps:
    """Odometry steps between consecutive frame stamps.

    ``odometry``: anything with ``at(stamps) -> (M, 3)`` ``T_odom_base`` (NaN outside its
    time span), e.g. :class:`planar_vo.io.wheel_odom.WheelOdometry`. Call :meth:`step`
    with every frame's stamp in order; it returns ``(pose, information)`` of the step from
    the previous call's stamp, or None for the first frame and where the odometry does not
    cover both stamps.
    """

    def __init__(self, odometry, config: BackendConfig | None = None):
        self.odometry = odometry
        self.config = config or BackendConfig()
        self._last: np.ndarray | None = None
        self.steps = 0        # steps returned
        self.uncovered = 0    # frames after the first without an odometry step

    def step(self, stamp: float) -> tuple[np.ndarray, np.ndarray] | None:
        pose = self.odometry.at([stamp])[0]
        prev, self._last = self._last, (pose if np.all(np.isfinite(pose)) else None)
        if prev is None or self._last is None:
            if prev is not None or self.steps or self.uncovered:
                self.uncovered += 1
            return None
        d = se2_between(prev, self._last)
        self.steps += 1
        return d, wheel_step_information(d, self.config)
