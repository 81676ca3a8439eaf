"""Low-texture regressions (issue 9): what a step states when the images say little.

1. A constant-velocity guess repeats the error of the step it copies: its stated sigma
   includes that step's sigma (partial steps' along-track error was 3x their sigma).
2. The guess copies the last measured translation, not a partial step's wall-corrected
   one, unless walls of two directions measured the whole translation (one wall fixes
   one direction only).

Tracked corners turning into edges (KLT sliding) are tested in test_features.py.
"""
from __future__ import annotations

import math

import numpy as np

from planar_vo.core import geometry as g
from planar_vo.core.steps import STATUS_BRIDGED, STATUS_DPP, STATUS_PARTIAL, FrameDiagnostics
from planar_vo.core.types import CameraIntrinsics, Mount
from planar_vo.frontend import odometry as odometry_module
from planar_vo.frontend.odometry import PlanarOdometry, lev_motion_to_base_step

K = CameraIntrinsics(480, 270, 250.0, 250.0, 239.5, 134.5)
# optical z forward, x right, y down on a base_link x forward, y left, z up; 0.2 m ahead
T_BASE_CAM = np.array([[0.0, 0.0, 1.0, 0.2], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0]])
MOUNT_SE2 = g.mount_se2(T_BASE_CAM)


def _odometry(dt: float, lateral_slip: float | None = None) -> PlanarOdometry:
    from planar_vo.frontend.config import FrontendConfig, OdometryConfig
    cfg = None if lateral_slip is None else FrontendConfig(odometry=OdometryConfig(lateral_slip=lateral_slip))
    odo = PlanarOdometry(K, Mount(T_BASE_CAM), cfg)
    odo._dt = dt
    return odo


def _measure(odo: PlanarOdometry, yaw: float, t: np.ndarray, sigma_t: float) -> None:
    """A measured (direction-plus-point) step, as _estimate accepts one."""
    cov = np.diag([math.radians(0.05) ** 2, sigma_t ** 2, sigma_t ** 2])
    assert odo._accept(yaw, t, cov, STATUS_DPP, 50, MOUNT_SE2, FrameDiagnostics()) is not None


def test_guess_states_the_error_of_the_step_it_copies():
    """30 Hz, 10 mm steps; the last measured step was 5 mm long along track (its sigma
    says 5 mm). The bridged and partial steps that copy it are 5 mm off each: their
    stated along-track sigma must cover that (the old 0.5 m/s^2 k dt^2 model said 1 mm)."""
    for mf_yaw in (None, (0.0, math.radians(0.05), 0.0)):
        odo = _odometry(1.0 / 30.0)
        t_true = np.array([0.0, 0.0, -0.010])
        _measure(odo, 0.0, t_true + np.array([0.0, 0.0, 0.005]), 0.005)
        true_step, _ = lev_motion_to_base_step(0.0, t_true, None, MOUNT_SE2)
        for k in range(1, 6):
            step, _ = odo._partial_or_bridge([], [], mf_yaw, MOUNT_SE2, FrameDiagnostics())
            assert step.status == (STATUS_BRIDGED if mf_yaw is None else STATUS_PARTIAL)
            assert step.guess_copies == k  # the k-th copy of one error (the back-end weighs them as one)
            sigma = np.sqrt(np.diag(np.linalg.inv(step.information)))
            err = step.pose - true_step
            assert abs(err[0]) > 0.004  # the copied error is there ...
            assert abs(err[0]) / sigma[0] < 2.0  # ... and stated


def test_partial_steps_copy_the_measured_translation_not_their_own(monkeypatch):
    """A partial step whose wall pair put it 17 mm sideways must not hand that offset to
    the next guesses: they copy the last measured translation. (A holonomic base: a wheeled
    one's prior holds the step near its heading, see the next test.)"""
    odo = _odometry(0.05, lateral_slip=0.0)
    t_true = np.array([0.0, 0.0, -0.014])
    _measure(odo, 0.0, t_true, 0.002)
    odo._last_motion = (0.0, t_true.copy())
    mf_yaw = (0.0, math.radians(0.05), 0.0)
    # a partial step whose one wall pair (wrongly) says 17 mm sideways
    with monkeypatch.context() as m:
        m.setattr(odometry_module, "wall_constraints", lambda *a, **k: [(np.array([1.0, 0.0]), 0.017, 0.002 ** 2)])
        first, _ = odo._partial_or_bridge([], [], mf_yaw, MOUNT_SE2, FrameDiagnostics())
    true_step, _ = lev_motion_to_base_step(0.0, t_true, None, MOUNT_SE2)
    assert abs(first.pose[1] - true_step[1]) > 0.008  # that step did take the wrong wall
    for _ in range(10):
        step, _ = odo._partial_or_bridge([], [], mf_yaw, MOUNT_SE2, FrameDiagnostics())
        assert np.abs(step.pose[:2] - true_step[:2]).max() < 0.002


def test_a_wheeled_base_resists_a_wrong_sideways_wall(monkeypatch):
    """The same wrong wall pair (17 mm sideways at a 2 mm sigma) on a wheeled base: the
    step's guess runs along its heading within 0.5 mm + 3 % of the 14 mm step
    (odometry.lateral_slip), so the wall moves it 3 mm (information-weighted), not 17."""
    odo = _odometry(0.05)
    t_true = np.array([0.0, 0.0, -0.014])
    _measure(odo, 0.0, t_true, 0.002)
    odo._last_motion = (0.0, t_true.copy())
    with monkeypatch.context() as m:
        m.setattr(odometry_module, "wall_constraints", lambda *a, **k: [(np.array([1.0, 0.0]), 0.017, 0.002 ** 2)])
        step, _ = odo._partial_or_bridge([], [], (0.0, math.radians(0.05), 0.0), MOUNT_SE2, FrameDiagnostics())
    true_step, _ = lev_motion_to_base_step(0.0, t_true, None, MOUNT_SE2)
    assert abs(step.pose[1] - true_step[1]) < 0.004
    assert abs(step.pose[1] - true_step[1]) / math.sqrt(np.linalg.inv(step.information)[1, 1]) < 4.0


def test_guess_copies_the_mean_of_the_last_measured_steps():
    """Five measured 20 mm steps, each off by +-3 mm along track (their noise), the last
    one +3 mm: the partial steps that follow guess the mean velocity, so each errs by the
    mean's error (0.6 mm), not by the last step's 3 mm copied again and again (68 partial
    steps in a row on a tuning log made 3 % of their path that way)."""
    odo = _odometry(0.05)
    t_true = np.array([0.0, 0.0, -0.020])
    for err in (-0.003, 0.003, -0.003, 0.003, 0.003):
        _measure(odo, 0.0, t_true + np.array([0.0, 0.0, err]), 0.003)
    true_step, _ = lev_motion_to_base_step(0.0, t_true, None, MOUNT_SE2)
    mf_yaw = (0.0, math.radians(0.05), 0.0)
    total = np.zeros(2)
    for _ in range(20):
        step, _ = odo._partial_or_bridge([], [], mf_yaw, MOUNT_SE2, FrameDiagnostics())
        assert step.status == STATUS_PARTIAL
        total += step.pose[:2] - true_step[:2]
    assert abs(total[0]) < 20 * 0.0007   # 20 x 0.6 mm, not 20 x 3 mm


def test_guess_sigma_stops_growing_at_the_top_speed():
    """30 Hz, 13 mm steps measured, then 300 partial steps with nothing measuring the
    distance along. The guess's sigma grows with the acceleration limit (0.5 m/s^2, 0.55
    mm a frame here) but never beyond what the top speed allows in one frame
    (odometry.bridge_max_speed 1 m/s, 33 mm): at 11 cm after 200 frames, a wall paired with
    another plane 27 cm off passed the 5-sigma gate as a measurement of a 13 mm step and
    the guesses copied it (a textureless tuning log, 2.7 -> 56 % drift)."""
    odo = _odometry(1.0 / 30.0)
    for err in (-0.001, 0.001, -0.001, 0.001, 0.0):   # measured with a millimetre's noise
        _measure(odo, 0.0, np.array([0.0, 0.0, -0.013 + err]), 0.001)
    mf_yaw = (0.0, math.radians(0.05), 0.0)
    sigmas = []
    for _ in range(300):
        odo._partial_or_bridge([], [], mf_yaw, MOUNT_SE2, FrameDiagnostics())
        sigmas.append(odo._bridge_sigmas(False)[0])
    assert sigmas[10] < 0.01                      # a few frames on: millimetres
    assert max(sigmas) <= 1.0 / 30.0 + 0.001      # the top speed's step, not 300 x 0.55 mm
    assert sigmas[-1] > 0.03                      # and it does get there
