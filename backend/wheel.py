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

Calibration: the odometry's scale, turn scale and heading drift per metre are estimated on
the way from the steps vision measured (:class:`WheelCalibration`, reported); with
``wheel_odom_calibrate`` they are also taken out of each odometry step before it enters
the graph (off by default: on the measured logs it did not help, see README).

Pure: no file I/O.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from planar_vo.backend.config import BackendConfig
from planar_vo.core.steps import STATUS_2PT, STATUS_DPP
from planar_vo.core.geometry import se2_between, wrap_angle

__all__ = ["WheelSteps", "WheelCalibration", "OdometryStep", "ScaleCheck", "wheel_step_information", "fuse_steps"]


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


class WheelCalibration:
    """The odometry's systematic errors, estimated from the steps vision measured.

    Model (that of :class:`planar_vo.io.wheel_odom.WheelOdomModel`): an odometry step of
    true length ``d`` and rotation ``theta`` reads ``(1 + scale) d`` and
    ``(1 + turn) theta + drift * d``. ``scale`` is the ratio of the summed forward motions
    over the steps whose translation vision measured (direction-plus-point, 2-point; steps
    on which the two differ by more than ``gate`` of the odometry's step + 5 mm are left
    out); ``turn`` and ``drift`` a least squares fit of the per-step heading differences against the odometry's turn and
    distance, regularised towards 0 as if one step of ``prior_rad`` turning and one of
    ``prior_m`` straight travel had shown no error (so that the weave of a straight
    corridor, a few 0.1 deg per step, does not decide the turn scale; a 90 deg turn does). Nothing is corrected
    before vision measured ``min_m`` metres.
    """

    def __init__(self, min_m: float = 1.0, prior_rad: float = 0.1, prior_m: float = 0.01,
                 gate: float = 0.5, max_scale: float = 0.1):
        self.min_m, self.gate, self.max_scale = min_m, gate, max_scale
        self.len_odo = self.len_vis = 0.0
        self.A = np.diag([prior_rad ** 2, prior_m ** 2])
        self.b = np.zeros(2)

    def observe(self, odo: np.ndarray, vis: np.ndarray) -> None:
        """One step measured by both: odometry ``odo`` and vision ``vis``, (3,) each."""
        # forward components: unbiased under vision's zero-mean noise (a norm is not)
        lo, lv = float(odo[0]), float(vis[0])
        if abs(lv - lo) > self.gate * abs(lo) + 0.005:
            return
        self.len_odo += lo
        self.len_vis += lv
        # regressors from the odometry, whose per-step noise is far below vision's: with
        # vision's turn as regressor its noise biased the fitted turn scale to -0.2 on a
        # straight corridor (errors in variables)
        a = np.array([float(odo[2]), abs(lo)])
        self.A += np.outer(a, a)  # heading regressors: vision's turn and the distance
        self.b += a * float(wrap_angle(odo[2] - vis[2]))

    @property
    def scale(self) -> float:
        if self.len_vis < self.min_m:
            return 0.0
        s = self.len_odo / self.len_vis - 1.0
        return float(s) if abs(s) <= self.max_scale else 0.0  # beyond: vision, not the wheels, is off

    @property
    def turn_and_drift(self) -> tuple[float, float]:
        """``(f, drift rad/m)`` of ``theta_odo - theta = f theta_odo + drift d``
        (``f = turn / (1 + turn)``)."""
        if self.len_vis < self.min_m:
            return 0.0, 0.0
        f, drift = np.linalg.solve(self.A, self.b)
        return float(np.clip(f, -self.max_scale, self.max_scale)), float(drift)

    def correct(self, odo: np.ndarray) -> np.ndarray:
        """The odometry step ``odo`` (3,) with the estimated errors taken out."""
        s = self.scale
        f, drift = self.turn_and_drift
        theta = float(odo[2]) * (1.0 - f) - drift * abs(float(odo[0]))
        return np.array([odo[0] / (1.0 + s), odo[1] / (1.0 + s), theta])

    def report(self) -> dict:
        f, drift = self.turn_and_drift
        return {"scale": round(self.scale, 5), "turn_scale": round(f / (1.0 - f), 5),
                "drift_deg_per_m": round(math.degrees(drift), 4), "vision_m": round(self.len_vis, 3)}


@dataclass
class OdometryStep:
    """The odometry's step into a frame for ``graph.add_frame(result, odometry=...)``:
    ``pose`` (3,) ``T_base_prev_base_curr``, ``information`` (3, 3), and whether vision's
    translation agrees with the odometry over the recent path (:class:`ScaleCheck`)."""

    pose: np.ndarray
    information: np.ndarray
    vision_agrees: bool = True


class ScaleCheck:
    """Does vision's forward motion agree with the odometry's over the last ``window_m``
    metres of steps both measured (judged from ``min_m`` on)? Vision can be confidently wrong (on a low-texture
    floor its steps came out 45 % short at a stated 4 mm sigma), while no working wheel
    odometry is off by more than ``max_disagreement`` over a metre or two."""

    def __init__(self, window_m: float, max_disagreement: float, min_m: float = 0.5):
        self.window_m, self.max, self.min_m = window_m, max_disagreement, min_m
        self._pairs: deque = deque()
        self._odo = self._vis = 0.0

    def observe(self, odo_fwd: float, vis_fwd: float) -> bool:
        """Add a step measured by both (forward motions in m); returns :attr:`agrees`."""
        self._pairs.append((odo_fwd, vis_fwd))
        self._odo += odo_fwd
        self._vis += vis_fwd
        while len(self._pairs) > 1 and abs(self._odo - self._pairs[0][0]) >= self.window_m:
            o, v = self._pairs.popleft()
            self._odo -= o
            self._vis -= v
        return self.agrees

    @property
    def agrees(self) -> bool:
        if abs(self._odo) < self.min_m:   # too short to tell vision's noise from a bias
            return True
        return abs(self._vis / self._odo - 1.0) <= self.max


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
        self.calibration = WheelCalibration()   # estimated always, applied if configured
        self._last: np.ndarray | None = None
        self.check = ScaleCheck(self.config.wheel_odom_check_m, self.config.wheel_odom_max_disagreement)
        self.steps = 0        # steps returned
        self.uncovered = 0    # frames after the first without an odometry step
        self.vision_distrusted = 0  # vision steps whose translation disagreed with the odometry

    def step(self, stamp: float, result=None) -> OdometryStep | None:
        """The step into the frame at ``stamp``; ``result``: that frame's
        :class:`FrameResult`, whose step (when vision measured its translation) enters the
        consistency check and then the calibration that corrects this odometry step."""
        pose = self.odometry.at([stamp])[0]
        prev, self._last = self._last, (pose if np.all(np.isfinite(pose)) else None)
        if prev is None or self._last is None:
            if prev is not None or self.steps or self.uncovered:
                self.uncovered += 1
            return None
        d = se2_between(prev, self._last)
        st = getattr(result, "step", None)
        agrees = self.check.agrees  # a partial step's guessed part comes from vision's velocity
        if st is not None and st.status in (STATUS_DPP, STATUS_2PT):
            agrees = self.check.observe(float(d[0]), float(st.pose[0]))
            if agrees:
                self.calibration.observe(d, np.asarray(st.pose, dtype=np.float64))
        self.vision_distrusted += not agrees
        if self.config.wheel_odom_calibrate:
            d = self.calibration.correct(d)
        self.steps += 1
        return OdometryStep(d, wheel_step_information(d, self.config), agrees)
