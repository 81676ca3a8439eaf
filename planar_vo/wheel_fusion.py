"""Wheel odometry in ``planar-vo run``: finding it, its steps for the graph, its outputs.

The pipeline calls three functions (so that its own code stays a few lines):
:func:`wheel_steps_for_run` before the frame loop, ``WheelSteps.step(stamp)`` per frame
(passed to ``graph.add_frame``), and :func:`write_wheel_outputs` at the end, which writes
``wheel_odom.tum`` (the odometry alone, as camera optical-frame poses ``T_odom_cam`` at
the frame stamps, ``odom`` re-based on the first frame like ``raw.tum``) and returns the
``wheel_odometry`` section of ``report.json``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from planar_vo.core.geometry import base_poses_to_cam_matrices

WHEEL_TUM = "wheel_odom.tum"


def wheel_steps_for_run(log, config):
    """``WheelSteps`` over the log's wheel odometry, or None when there is none or the
    configuration turns it off (``backend.wheel_odom: false``, ``--no-wheel-odom``)."""
    from planar_vo.backend.wheel import WheelSteps

    if not config.backend.wheel_odom:
        return None
    odometry = log.wheel_odometry(config.input.odom_topic)
    if odometry is None or len(odometry) < 2:
        return None
    return WheelSteps(odometry, config.backend)


def wheel_trajectory(stamps, odometry, T_base_cam):
    """The odometry alone at ``stamps`` as a camera-pose Trajectory re-based on the first
    stamp it covers, or None when it covers none of them."""
    from planar_vo.core.types import Trajectory
    from planar_vo.io.wheel_odom import se2_between_many

    stamps = np.asarray(stamps, dtype=np.float64)
    P = odometry.at(stamps)
    ok = np.all(np.isfinite(P), axis=1)
    if not ok.any():
        return None
    P = se2_between_many(np.repeat(P[ok][:1], ok.sum(), axis=0), P[ok])
    return Trajectory(stamps[ok], base_poses_to_cam_matrices(P, T_base_cam), frame_id="odom",
                      child_frame_id="camera_optical_frame")


def write_wheel_outputs(out: Path, steps, traj, backend_stats: dict) -> tuple[dict, dict]:
    """Write ``wheel_odom.tum`` (``traj``: :func:`wheel_trajectory` of the run, or None);
    returns ``(report section, {name: path})``."""
    from planar_vo.io.trajectory import write_tum_trajectory

    if steps is None:
        return {"used": False}, {}
    odo, cfg = steps.odometry, steps.config
    files = {}
    if traj is not None:
        write_tum_trajectory(Path(out) / WHEEL_TUM, traj)
        files["wheel_odom"] = str(Path(out) / WHEEL_TUM)
    factors = backend_stats.get("factors", {})
    report = {
        "used": True, "topic": odo.topic, "source": odo.source,
        "frames": [odo.frame_id, odo.child_frame_id], "samples": len(odo),
        "rate_hz": round(odo.rate_hz, 3),
        "steps_with_factor": int(factors.get("wheel_odom", 0)),
        "bridged_replaced": int(factors.get("bridged_by_wheel_odom", 0)),
        "frames_not_covered": int(steps.uncovered),
        "vision_translation_distrusted": int(steps.vision_distrusted),
        "noise_model": {k: getattr(cfg, k) for k in (
            "wheel_odom_sigma_min_m", "wheel_odom_sigma_per_m", "wheel_odom_sigma_min_deg",
            "wheel_odom_sigma_deg_per_m", "wheel_odom_sigma_per_rad")},
        "calibration": {**steps.calibration.report(), "applied": bool(cfg.wheel_odom_calibrate)},
        "trajectory": WHEEL_TUM if traj is not None else None,
    }
    return report, files


def motion_with_wheel_odometry(motion: dict, section: dict) -> dict:
    """``report.json`` ``motion`` when wheel odometry measured the translation of the steps
    vision left to a guess: the verdict counts the steps with an odometry factor too."""
    n = motion.get("steps", 0)
    wheel = int(section.get("steps_with_factor", 0)) if section.get("used") else 0
    vision = motion.get("translation_measured", 0)
    if not n or wheel <= vision:
        return motion
    from planar_vo.pipeline import GOOD_MEASURED_FRACTION, MIN_MEASURED_FRACTION

    out = dict(motion, wheel_odometry_steps=wheel)
    frac = wheel / n
    out["verdict"] = ("estimated" if frac >= GOOD_MEASURED_FRACTION else
                      "degraded" if frac >= MIN_MEASURED_FRACTION else "not_estimated")
    out["message"] = (f"translation measured by vision in {vision} of {n} steps and by wheel odometry in "
                      f"{wheel}: where vision had none, the trajectory follows the wheel odometry")
    return out
