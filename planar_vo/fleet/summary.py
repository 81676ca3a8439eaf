"""The batch's summary in RESULTS: ``summary.csv``, ``summary.json`` and ``summary.md``.

One row per log: its result folder, status (ok, not_estimated, partial, failed,
interrupted), whether it was skipped as finished before, the one-line reason of a
problem, frames, frames per second, steps per status, the motion and planarity verdicts,
and with ground truth the raw and smoothed metrics of ``planar-vo evaluate``.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

from planar_vo.fleet.task import FINISHED, METRICS, STEP_STATUSES

COLUMNS = (["name", "log", "status", "skipped", "reason", "frames", "fps", "wall_s", "peak_rss_mb"]
           + [f"steps_{s}" for s, _ in STEP_STATUSES] + ["motion", "planarity"]
           + [f"{k}_{m}" for k in ("raw", "smoothed") for m in METRICS])


def rows(result) -> list[dict]:
    """Flat per-log rows (the CSV columns), in the order the logs were found."""
    out = []
    for job in result.jobs:
        rec = job.record or {}
        row = {"name": job.name, "log": str(job.log), "status": rec.get("status", "not_run"),
               "skipped": job.skipped, "reason": rec.get("reason"), "frames": rec.get("frames"),
               "fps": rec.get("fps"), "wall_s": rec.get("wall_s"), "peak_rss_mb": rec.get("peak_rss_mb"),
               "motion": rec.get("motion"), "planarity": rec.get("planarity")}
        for s, _ in STEP_STATUSES:
            row[f"steps_{s}"] = (rec.get("steps") or {}).get(s)
        metrics = rec.get("metrics") or {}
        for k in ("raw", "smoothed"):
            for m in METRICS:
                row[f"{k}_{m}"] = (metrics.get(k) or {}).get(m)
        out.append(row)
    return out


def totals(result, table: list[dict]) -> dict:
    ran = [r for r in table if not r["skipped"] and r["status"] in FINISHED]
    frames_run = sum(int(r["frames"] or 0) for r in ran)
    by_status: dict[str, int] = {}
    for r in table:
        by_status[r["status"]] = by_status.get(r["status"], 0) + 1
    return {"logs": len(table), "by_status": by_status, "skipped": sum(r["skipped"] for r in table),
            "frames": sum(int(r["frames"] or 0) for r in table), "frames_run": frames_run,
            "wall_s": round(result.wall_s, 2), "run_s": round(result.run_s, 2),
            "fps_overall": round(frames_run / result.run_s, 2) if result.run_s > 0 and frames_run else None,
            "interrupted": result.interrupted, "ray": result.ray}


def write_summary(out: Path, result) -> dict:
    """Write the three summary files atomically; returns the JSON document."""
    from planar_vo.io.atomic import write_text_atomic

    table = rows(result)
    doc = {"totals": totals(result, table), "logs": table}
    write_text_atomic(out / "summary.json", json.dumps(doc, indent=2, default=float) + "\n")
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in table:
        w.writerow({k: ("" if r[k] is None else r[k]) for k in COLUMNS})
    write_text_atomic(out / "summary.csv", buf.getvalue())
    write_text_atomic(out / "summary.md", markdown(doc, out))
    return doc


def _fmt(v, spec: str) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return format(v, spec)


def markdown(doc: dict, out: Path) -> str:
    t = doc["totals"]
    lines = ["# planar-vo batch", "",
             f"{t['logs']} logs: " + ", ".join(f"{n} {s}" for s, n in sorted(t["by_status"].items()))
             + f"; {t['skipped']} skipped as finished before. {t['frames']} frames in all, {t['frames_run']} "
             f"run now in {t['run_s']:.1f} s" + (f" ({t['fps_overall']:.1f} frames/s over the fleet)" if t["fps_overall"] else "")
             + f"; Ray: {t['ray'].get('mode')}" + (" (interrupted)" if t["interrupted"] else "") + ".", "",
             "| log | status | frames | fps | dpp / 2pt / partial / bridged / failed | motion | planarity "
             "| raw drift % | smoothed drift % | raw ATE m | smoothed ATE m | smoothed yaw deg |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in doc["logs"]:
        status = r["status"] + (" (skipped)" if r["skipped"] else "") + (f": {r['reason']}" if r["reason"] else "")
        steps = " / ".join(_fmt(r[f"steps_{s}"], "d") for s, _ in STEP_STATUSES) if r["frames"] else ""
        lines.append(f"| {r['name']} | {status.replace('|', '/')} | {_fmt(r['frames'], 'd')} | {_fmt(r['fps'], '.1f')} "
                     f"| {steps} | {r['motion'] or ''} | {r['planarity'] or ''} "
                     f"| {_fmt(r['raw_endpoint_drift_pct'], '.2f')} | {_fmt(r['smoothed_endpoint_drift_pct'], '.2f')} "
                     f"| {_fmt(r['raw_ate_rmse_m'], '.3f')} | {_fmt(r['smoothed_ate_rmse_m'], '.3f')} "
                     f"| {_fmt(r['smoothed_final_yaw_error_deg'], '+.2f')} |")
    lines += ["", "## Trajectories", ""]
    for r in doc["logs"]:
        if (out / r["name"] / "trajectory.png").is_file():
            lines += [f"### {r['name']}", "", f"![{r['name']}]({r['name']}/trajectory.png)", ""]
    return "\n".join(lines) + "\n"
