"""One log of a batch: ``planar-vo run``'s code path, then the figures for the summary.

:func:`run_log` is what a Ray task executes (and what a test can call without Ray). It
never raises for a problem of the log: a bad input or an unexpected error becomes a
record with ``status: failed`` and a one-line ``reason``; only an interrupt propagates.
"""
from __future__ import annotations

import json
import resource
import time
from pathlib import Path

#: Files a run or a batch writes into a result folder (removed before a log is re-run, so
#: that nothing of an earlier configuration stays next to the new results).
RESULT_FILES = ("raw.tum", "smoothed.tum", "poses.mcap", "report.json", "steps.csv", "config.yaml",
                "trajectory.png", "evaluation.json", "batch.json")
#: Statuses of a finished log whose result folder is complete (skipped on a re-run).
FINISHED = ("ok", "not_estimated", "partial")
STEP_STATUSES = (("dpp", "estimated_dpp"), ("2pt", "estimated_2pt"), ("partial", "partial"),
                 ("bridged", "bridged"), ("failed", "failed"))
METRICS = ("ate_rmse_m", "endpoint_drift_pct", "final_yaw_error_deg", "rpe_trans_per_m", "rpe_rot_deg_per_m",
           "path_length_m")


def clear_results(out_dir: Path) -> None:
    """Remove the files of an earlier run of this folder (nothing else in it)."""
    for name in RESULT_FILES:
        (out_dir / name).unlink(missing_ok=True)


def run_log(log: str, out_dir: str, config, gt_from_logs: bool = False) -> dict:
    """Run ``log`` into ``out_dir`` exactly as ``planar-vo run LOG --out DIR --quiet`` does
    (with ``--gt LOG.gt.tum`` when ``gt_from_logs`` and that file exists); with
    ``gt_from_logs`` also evaluate it against the ground truth found with the log, as
    ``planar-vo evaluate DIR`` does, into ``evaluation.json``. Returns the record."""
    from planar_vo.core.errors import PlanarVOError

    t0 = time.perf_counter()
    out = Path(out_dir)
    rec: dict = {}
    try:
        out.mkdir(parents=True, exist_ok=True)
        clear_results(out)
        rec = _run_and_describe(Path(log), out, config, gt_from_logs)
    except PlanarVOError as exc:
        rec = {"status": "failed", "reason": _one_line(str(exc))}
    except Exception as exc:  # noqa: BLE001 - one log's failure must not stop the fleet
        rec = {"status": "failed", "reason": _one_line(f"internal error: {type(exc).__name__}: {exc}")}
    rec["wall_s"] = round(time.perf_counter() - t0, 3)
    # ru_maxrss is in KiB on Linux; a task runs in its own worker process (max_calls=1)
    rec["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return rec


def _one_line(text: str) -> str:
    lines = [s.strip() for s in text.strip().splitlines() if s.strip()]
    return lines[0] if lines else "unknown error"


def _run_and_describe(log: Path, out: Path, config, gt_from_logs: bool) -> dict:
    from planar_vo.commands.run import exit_code
    from planar_vo.pipeline import run

    beside = log.with_suffix(".gt.tum")
    gt_path = beside if gt_from_logs and log.is_file() and beside.is_file() else None
    result = run(log, out, config, progress=False, gt_path=gt_path)
    rep = result.report
    code = exit_code(result)
    if result.partial and str(result.stop_reason or "").startswith("interrupted"):
        status = "interrupted"
    else:
        status = {0: "ok", 3: "partial", 4: "not_estimated"}.get(code, "failed")
    rec = {"status": status, "reason": result.stop_reason if result.partial else None,
           "frames": rep["frames"]["with_pose"], "fps": rep.get("fps"),
           "steps": {s: int(rep["frames"].get(k, 0)) for s, k in STEP_STATUSES},
           "motion": rep.get("motion", {}).get("verdict"),
           "planarity": rep.get("planarity", {}).get("verdict")}
    if status == "not_estimated":
        rec["reason"] = rep["motion"].get("message")
    if gt_from_logs:
        rec["metrics"] = _evaluate(log, out)
    return rec


def _evaluate(log: Path, out: Path) -> dict | None:
    """``{"ground_truth": source, "raw": {...}, "smoothed": {...}}`` or None without ground truth."""
    from planar_vo.evaluation import evaluate_run, ground_truth_for_log
    from planar_vo.io.atomic import write_text_atomic

    gt, source = ground_truth_for_log(log)
    if gt is None:
        return None
    ev = evaluate_run(out, gt)
    write_text_atomic(out / "evaluation.json", json.dumps(ev, indent=2) + "\n")
    return {"ground_truth": source, **{k: {m: ev[k].get(m) for m in METRICS} for k in ("raw", "smoothed")}}
