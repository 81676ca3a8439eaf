"""Evaluate a run folder against ground truth: raw and smoothed side by side, the smoothed
trajectory without loop closures when the run closed loops (``smoothed_no_loops.tum``), and
the wheel odometry alone when the run had it (``wheel_odom.tum``)."""
from __future__ import annotations

import json
import math
from pathlib import Path

from evo.tools import file_interface

from planar_vo.core.errors import InputError
from planar_vo.io import open_log
from planar_vo.io.trajectory import read_tum_trajectory
from planar_vo.metrics import per_frame_errors, planarity, trajectory_errors

ROWS = [
    ("matched", "poses matched", "{:.0f}"),
    ("path_length_m", "path length [m]", "{:.2f}"),
    ("ate_rmse_m", "ATE RMSE [m]", "{:.3f}"),
    ("rpe_trans_per_m", "RPE trans [%/m]", "{:.2%}"),
    ("rpe_rot_deg_per_m", "RPE rot [deg/m]", "{:.3f}"),
    ("endpoint_drift_m", "end-point drift [m]", "{:.3f}"),
    ("endpoint_drift_pct", "end-point drift [% of path]", "{:.2f}"),
    ("final_yaw_error_deg", "final yaw error [deg]", "{:+.2f}"),
]


def load_ground_truth(path: str | Path):
    """Ground truth from a TUM file or from an MCAP log that carries ``/ground_truth``."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: ground-truth file not found; pass a TUM trajectory or an MCAP with /ground_truth to --gt")
    if p.suffix == ".mcap" or p.is_dir():
        with open_log(p) as log:
            gt = log.ground_truth
        if gt is None or len(gt) == 0:
            raise InputError(f"{p}: carries no ground truth (/ground_truth); pass a TUM file with --gt")
        return gt
    return read_tum_trajectory(p)


def ground_truth_for_log(log_path: str | Path, log=None):
    """``(Trajectory, source)`` carried by a log (``/ground_truth``) or in ``LOG.gt.tum`` beside
    it, else ``(None, None)``. ``log``: the already open RGBDLog, if any."""
    log_path = Path(log_path)
    try:
        if log is None and log_path.exists():
            with open_log(log_path) as opened:
                gt = opened.ground_truth
        else:
            gt = log.ground_truth if log is not None else None
    except InputError:
        gt = None
    if gt is not None and len(gt):
        return gt, f"{log_path} (/ground_truth)"
    beside = log_path.with_suffix(".gt.tum")
    if beside.exists():
        return read_tum_trajectory(beside), str(beside)
    return None, None


def find_ground_truth(run_dir: Path):
    """Ground truth for a run without ``--gt``: carried in its log, or ``LOG.gt.tum`` beside it."""
    report = Path(run_dir) / "report.json"
    if not report.exists():
        return None
    return ground_truth_for_log(json.loads(report.read_text()).get("log", ""))[0]


def _run_trajectories(run_dir: Path, gt):
    """``(gt, {name: evo trajectory})``: the run's ground truth (``gt`` or found) and the
    trajectories :func:`evaluate_run` compares, in :data:`COLUMNS` order."""
    if not (run_dir / "smoothed.tum").exists():
        raise InputError(f"{run_dir}: not a run folder (no smoothed.tum); run 'planar-vo run LOG --out {run_dir}' first")
    if gt is None:
        gt = find_ground_truth(run_dir)
    if gt is None:
        raise InputError(f"{run_dir}: no ground truth found in the run's log; pass one with --gt FILE")
    names = [n for n, _ in COLUMNS if n in ("raw", "smoothed") or (run_dir / f"{n}.tum").exists()]
    return gt, {n: file_interface.read_tum_trajectory_file(run_dir / f"{n}.tum") for n in names}


def evaluate_run(run_dir: str | Path, gt=None, *, max_dt: float = 0.02) -> dict:
    """Errors of ``raw.tum``, ``smoothed.tum`` (and ``smoothed_no_loops.tum``, ``wheel_odom.tum``
    when present) in ``run_dir`` against ``gt`` (a Trajectory)."""
    gt, trajectories = _run_trajectories(Path(run_dir), gt)
    result = {"ground_truth": {"poses": len(gt), **planarity(gt.poses)}}
    for name, est in trajectories.items():
        result[name] = trajectory_errors(est.timestamps, est.poses_se3, gt.stamps, gt.poses,
                                         max_dt=max_dt).as_dict()
    return result


#: Columns of :func:`format_per_frame_csv`, one row per trajectory and matched frame.
PER_FRAME_COLUMNS = ("trajectory", "stamp", "along_m", "left_m", "up_m", "yaw_deg")


def per_frame_run(run_dir: str | Path, gt=None, *, max_dt: float = 0.02) -> dict[str, dict]:
    """:func:`planar_vo.metrics.per_frame_errors` of each trajectory :func:`evaluate_run`
    compares, by name; a trajectory with fewer than 2 matched poses is left out."""
    gt, trajectories = _run_trajectories(Path(run_dir), gt)
    out = {}
    for name, est in trajectories.items():
        errors = per_frame_errors(est.timestamps, est.poses_se3, gt.stamps, gt.poses, max_dt=max_dt)
        if errors is not None:
            out[name] = errors
    return out


def format_per_frame_csv(per_frame: dict[str, dict]) -> str:
    """:func:`per_frame_run`'s result as CSV text with :data:`PER_FRAME_COLUMNS` (stamps in
    seconds to the microsecond, errors in metres and degrees)."""
    lines = [",".join(PER_FRAME_COLUMNS)]
    for name, e in per_frame.items():
        for row in zip(e["stamp"], e["along_m"], e["left_m"], e["up_m"], e["yaw_deg"]):
            lines.append(f"{name},{row[0]:.6f}," + ",".join(f"{v:.6f}" for v in row[1:]))
    return "\n".join(lines) + "\n"


#: Columns of the table: result key (= the run folder's file ``KEY.tum``), heading. The
#: smoothed trajectory without loop closures and the wheel odometry alone appear only when
#: the run wrote them (it closed loops; the log had wheel odometry).
COLUMNS = (("raw", "raw"), ("smoothed_no_loops", "smoothed, no loops"), ("smoothed", "smoothed"),
           ("wheel_odom", "wheel odom"))


def format_table(result: dict) -> str:
    cols = [(k, h) for k, h in COLUMNS if k in result]
    widths = [max(14, len(h) + 2) for _, h in cols]
    lines = [f"{'metric':<30}" + "".join(f"{h:>{w}}" for (_, h), w in zip(cols, widths))]
    for key, label, fmt in ROWS:
        cells = []
        for name, _ in cols:
            v = result[name][key]
            cells.append("n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v))
        lines.append(f"{label:<30}" + "".join(f"{c:>{w}}" for c, w in zip(cells, widths)))
    for name, heading in cols:
        if result[name].get("ate_alignment") == "first_pose":
            lines.append(f"{heading}: ATE after aligning the first poses (the ground truth is a straight line, "
                         "so the SE(3) alignment is undetermined)")
    g = result["ground_truth"]
    lines.append(f"ground truth: {g['poses']} poses, height range {g['height_range_m']:.3f} m, "
                 f"tilt range {g['tilt_range_deg']:.2f} deg")
    return "\n".join(lines)
