"""Accuracy over randomized scenes: ``planar-vo bench sweep --seeds A-B``.

``planar-vo bench sweep --seeds 1000-1007 [--layouts straight,lturn,loop,two_frames,hall]
[--long K] [--cache DIR] [--out DIR] [--workers 2] [--config FILE]``

For every seed and layout a randomized log (:func:`planar_vo.sim.synth_random.randomized_config`)
is rendered into the cache (kept, and reused while its parameters are the same: rendering
is the slow part), run end to end with ``planar-vo run``'s code path and the given
configuration, and compared with its ground truth. ``--long K`` makes K of the logs at
least 1000 frames (errors grow with length), spread evenly over the logs chosen: with
``--layouts`` a subset of the layouts gets its own K long logs, so its logs are not all
among those of the full sweep over the same seeds. Printed per layout and over all logs:
median, 90th percentile and worst of raw and smoothed end-point drift (% of path) and
|final yaw| (deg), and smoothed minus raw drift; the steps per status; and the normalised
step errors per status -- each step's error against the ground truth divided by the sigma
the front-end states for it, RMS per component (x, y, theta), which is about 1 when the
stated uncertainty is honest. Everything also goes to ``OUT/sweep.json`` and ``OUT/sweep.md``.

Tune on one range of seeds, report on another.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

LAYOUTS = ("straight", "lturn", "loop", "two_frames", "hall")
LONG_FRAMES = 1000
STATUSES = ("dpp", "2pt", "partial", "bridged")
#: The normalised errors' entry of the gap links (gap_links.csv), next to the statuses'.
GAP_LINK = "gap_link"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", required=True, metavar="A-B", help="inclusive seed range, e.g. 1000-1007")
    parser.add_argument("--layouts", default=",".join(LAYOUTS), help="comma-separated (default: all five)")
    parser.add_argument("--long", type=int, default=0, metavar="K",
                        help=f"make K of the logs at least {LONG_FRAMES} frames (default 0)")
    parser.add_argument("--cache", default="runs/sweep_cache", help="rendered logs, reused (default runs/sweep_cache)")
    parser.add_argument("--out", default="runs/sweep", help="run folders, sweep.json, sweep.md (default runs/sweep)")
    parser.add_argument("--workers", type=int, default=2, help="logs rendered and run in parallel (default 2)")
    parser.add_argument("--config", default=None, help="run configuration YAML (as planar-vo run --config)")
    parser.add_argument("--speed-dips", action="store_true",
                        help="the base also slows down within its cruise, down to a momentary stop (other logs "
                             "than without: every other draw of a seed stays the same)")


def parse_seeds(text: str) -> list[int]:
    from planar_vo.core.errors import InputError
    try:
        a, _, b = text.partition("-")
        lo, hi = int(a), int(b or a)
    except ValueError:
        raise InputError(f"--seeds {text!r}: expected A-B, e.g. 1000-1007") from None
    if hi < lo:
        raise InputError(f"--seeds {text!r}: the range is empty")
    return list(range(lo, hi + 1))


def plan(seeds: list[int], layouts: list[str], n_long: int) -> list[tuple[int, str, int | None]]:
    """``(seed, layout, min_frames or None)`` per log; the long ones spread evenly."""
    jobs = [(s, lay) for s in seeds for lay in layouts]
    long_idx = set(np.linspace(0, len(jobs) - 1, n_long).round().astype(int).tolist()) if n_long > 0 else set()
    return [(s, lay, LONG_FRAMES if i in long_idx else None) for i, (s, lay) in enumerate(jobs)]


def log_name(cfg) -> str:
    from planar_vo.sim.synth_random import describe

    key = hashlib.sha1(json.dumps(describe(cfg), sort_keys=True).encode()).hexdigest()[:8]
    return f"{cfg.layout}_s{cfg.seed}_n{cfg.n_frames}_{key}"


# ------------------------------------------------------------------ one log
def run_one(seed: int, layout: str, min_frames: int | None, cache: str, out: str, config_path: str | None,
            speed_dips: bool = False) -> dict:
    """Render (or reuse) one randomized log, run it, evaluate it; a dict for the summary.
    Runs in a worker process; never raises (a failure is reported with its reason)."""
    from planar_vo.sim.synth_random import describe, randomized_config

    rec: dict = {"seed": seed, "layout": layout}
    try:
        cfg = randomized_config(seed, layout, n_frames=min_frames, speed_dips=speed_dips)
        name = log_name(cfg)
        rec.update(name=name, scene=describe(cfg))
        log = Path(cache) / f"{name}.mcap"
        t0 = time.perf_counter()
        if not (log.exists() and Path(cache, f"{name}.gt.tum").exists()):
            from planar_vo.sim.synth import write_synth_log
            tmp = Path(cache) / f"{name}.part.mcap"
            paths = write_synth_log(cfg, tmp, progress=False)
            os.replace(paths["ground_truth"], Path(cache) / f"{name}.gt.tum")
            os.replace(tmp, log)
        rec["render_s"] = round(time.perf_counter() - t0, 1)
        rec.update(_run_and_evaluate(log, cfg, Path(out) / name, config_path))
        rec["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - one log's failure must not stop the sweep
        rec["status"] = "failed"
        rec["reason"] = f"{type(exc).__name__}: {exc}"
    return rec


def _run_and_evaluate(log: Path, cfg, run_dir: Path, config_path: str | None) -> dict:
    from planar_vo.config import load_config
    from planar_vo.evaluation import evaluate_run
    from planar_vo.sim.synth import synth_mount
    from planar_vo.io.trajectory import read_tum_trajectory
    from planar_vo.pipeline import run

    config = load_config(config_path, {"output": {"plot": False, "poses_mcap": False}})
    t0 = time.perf_counter()
    result = run(log, run_dir, config, progress=False)
    gt = read_tum_trajectory(str(log)[:-5] + ".gt.tum")
    ev = evaluate_run(run_dir, gt)
    rep = result.report
    out = {"run_s": round(time.perf_counter() - t0, 1), "frames": rep["frames"]["with_pose"],
           "path_m": ev["smoothed"]["path_length_m"], "motion": rep.get("motion", {}).get("verdict"),
           "manhattan_frames": rep["backend"].get("manhattan_frames"),
           "steps": {s: _count(rep["frames"], s) for s in STATUSES}}
    for k in ("raw", "smoothed"):
        out[f"{k}_drift_pct"] = ev[k]["endpoint_drift_pct"]
        out[f"{k}_yaw_deg"] = ev[k]["final_yaw_error_deg"]
        out[f"{k}_ate_m"] = ev[k]["ate_rmse_m"]
    T_base_cam = np.asarray(synth_mount(cfg).T_base_cam)
    out["normalised"] = step_errors(run_dir / "steps.csv", gt, T_base_cam)
    if (run_dir / "gap_links.csv").exists():
        out["normalised"][GAP_LINK] = gap_link_errors(run_dir / "gap_links.csv", gt, T_base_cam)
    return out


def _count(frames: dict, status: str) -> int:
    return int(frames.get({"dpp": "estimated_dpp", "2pt": "estimated_2pt"}.get(status, status), 0))


def step_errors(steps_csv: Path, gt, T_base_cam: np.ndarray) -> dict:
    """Per status: ``{"n", "sum_sq": [x, y, theta], "nees_sum"}`` of the steps' errors
    against the ground truth divided by their stated sigmas (summed squares, so logs pool
    exactly), and the sum of the normalised squared errors ``e^T C^-1 e`` over the whole
    stated covariance ``C`` (3 per step on average when it is honest; per axis the sigmas
    can look right while the correlations are wrong). Files without the correlation
    columns (``rho_*``) are scored as uncorrelated."""
    from planar_vo.core.geometry import se2_between, wrap_angle

    rows = list(csv.DictReader(open(steps_csv)))
    inv_bc = np.linalg.inv(T_base_cam)

    out: dict = {}
    # steps.csv has a row for every frame but the first, in order: the step of row k
    # starts at the frame of row k - 1 (the first row's start frame is not in the file)
    stamps = [float(r["stamp"]) for r in rows]
    for k in range(1, len(rows)):
        r = rows[k]
        g = se2_between(_base_at(gt, inv_bc, stamps[k - 1]), _base_at(gt, inv_bc, stamps[k]))
        e = np.array([float(r["x"]), float(r["y"]), float(r["theta"])]) - g
        e[2] = float(wrap_angle(e[2]))
        s = np.array([float(r["sigma_x"]), float(r["sigma_y"]), float(r["sigma_theta"])])
        rho = [float(r.get(k) or 0.0) for k in ("rho_xy", "rho_xtheta", "rho_ytheta")]
        corr = np.array([[1.0, rho[0], rho[1]], [rho[0], 1.0, rho[2]], [rho[1], rho[2], 1.0]])
        z = e / s
        d = out.setdefault(r["status"], {"n": 0, "sum_sq": [0.0, 0.0, 0.0], "nees_sum": 0.0})
        d["n"] += 1
        d["sum_sq"] = [a + float(b) for a, b in zip(d["sum_sq"], z ** 2)]
        d["nees_sum"] += float(z @ np.linalg.lstsq(corr, z, rcond=None)[0])
    return out


def _base_at(gt, inv_bc: np.ndarray, stamp: float) -> np.ndarray:
    """Ground-truth base_link pose ``(x, y, theta)`` nearest ``stamp``."""
    i = int(np.argmin(np.abs(gt.stamps - stamp)))
    T = gt.poses[i] @ inv_bc
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])


def gap_link_errors(links_csv: Path, gt, T_base_cam: np.ndarray) -> dict:
    """As :func:`step_errors`, of the run's ``gap_links.csv``: translation only (the links
    state no yaw), so ``sum_sq``'s theta is NaN and ``e^T C^-1 e`` is 2 per link when honest."""
    from planar_vo.core.geometry import se2_between

    inv_bc = np.linalg.inv(T_base_cam)
    d = {"n": 0, "sum_sq": [0.0, 0.0, float("nan")], "nees_sum": 0.0}
    for r in csv.DictReader(open(links_csv)):
        g = se2_between(_base_at(gt, inv_bc, float(r["from_stamp"])), _base_at(gt, inv_bc, float(r["to_stamp"])))
        e = np.array([float(r["x"]), float(r["y"])]) - g[:2]
        s = np.array([float(r["sigma_x"]), float(r["sigma_y"])])
        rho = float(r["rho_xy"])
        z = e / s
        d["n"] += 1
        d["sum_sq"] = [d["sum_sq"][0] + float(z[0] ** 2), d["sum_sq"][1] + float(z[1] ** 2), float("nan")]
        d["nees_sum"] += float(z @ np.linalg.solve(np.array([[1.0, rho], [rho, 1.0]]), z))
    return d


# ------------------------------------------------------------------ statistics
def spread(values) -> dict:
    """``{"n", "median", "p90", "worst"}`` of finite values (worst = largest)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if len(v) == 0:
        return {"n": 0, "median": float("nan"), "p90": float("nan"), "worst": float("nan")}
    return {"n": int(len(v)), "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "worst": float(v.max())}


def pool_normalised(records: list[dict]) -> dict:
    """Normalised RMS per status and component and the mean normalised squared error over
    the whole covariance, pooled over logs: ``{status: {"n", "rms": [x, y, th], "nees"}}``."""
    acc: dict = {}
    for r in records:
        for status, d in (r.get("normalised") or {}).items():
            a = acc.setdefault(status, {"n": 0, "sum_sq": np.zeros(3), "nees_sum": 0.0})
            a["n"] += d["n"]
            a["sum_sq"] += np.asarray(d["sum_sq"])
            a["nees_sum"] += float(d.get("nees_sum", np.sum(d["sum_sq"])))
    return {s: {"n": a["n"], "rms": (np.sqrt(a["sum_sq"] / a["n"]).tolist() if a["n"] else [float("nan")] * 3),
                "nees": a["nees_sum"] / a["n"] if a["n"] else float("nan")}
            for s, a in acc.items()}


METRICS = (("raw_drift_pct", "raw drift %", False), ("smoothed_drift_pct", "smoothed drift %", False),
           ("raw_yaw_deg", "raw |yaw| deg", True), ("smoothed_yaw_deg", "smoothed |yaw| deg", True),
           ("smoothed_minus_raw", "smoothed - raw drift %", False))


def group_records(records: list[dict]) -> dict[str, list[dict]]:
    """The summary's rows: ``{row: records}`` -- one per layout (in ``records``' order),
    ``all``, ``announced`` and ``estimated``, over the records whose status is ``ok``."""
    ok = [r for r in records if r.get("status") == "ok"]
    groups = {lay: [r for r in ok if r["layout"] == lay] for lay in dict.fromkeys(r["layout"] for r in records)}
    groups["all"] = ok
    # a run that announced it could not estimate the motion (report.json ``motion``) is not a
    # silent failure: its drift is listed with all logs and left out of this row
    groups["announced"] = [r for r in ok if r.get("motion") == "not_estimated"]
    groups["estimated"] = [r for r in ok if r.get("motion") != "not_estimated"]
    return groups


def summarise(records: list[dict]) -> dict:
    for r in records:
        if r.get("status") == "ok":
            r["smoothed_minus_raw"] = r["smoothed_drift_pct"] - r["raw_drift_pct"]
    out: dict = {}
    for name, rs in group_records(records).items():
        g = {key: spread([abs(r[key]) if absolute else r[key] for r in rs]) for key, _, absolute in METRICS}
        g["logs"] = len(rs)
        g["frames"] = int(sum(r["frames"] for r in rs))
        g["steps"] = {s: int(sum(r["steps"][s] for r in rs)) for s in STATUSES}
        g["normalised"] = pool_normalised(rs)
        out[name] = g
    out["failed"] = [{"name": r.get("name", f"{r['layout']}_s{r['seed']}"), "reason": r.get("reason")}
                     for r in records if r.get("status") != "ok"]
    return out


def _normalised_cell(status: str, v: dict, sep: str) -> str:
    """``status x / y / theta, nees (n)``; a gap link's ``x / y, nees of 2 (n)``."""
    if status == GAP_LINK:
        return f"{status} {v['rms'][0]:.2f}{sep}{v['rms'][1]:.2f}, {v['nees']:.1f} of 2 ({v['n']})"
    return f"{status} {v['rms'][0]:.2f}{sep}{v['rms'][1]:.2f}{sep}{v['rms'][2]:.2f}, {v['nees']:.1f} ({v['n']})"


def format_summary(summary: dict) -> str:
    lines = []
    head = f"{'layout':<11}{'logs':>5}{'frames':>8}  " + "  ".join(f"{label:>26}" for _, label, _ in METRICS)
    lines.append(head)
    lines.append(f"{'':<24}  " + "  ".join(f"{'median / p90 / worst':>26}" for _ in METRICS))
    for name, g in summary.items():
        if name == "failed":
            continue
        cells = "  ".join(f"{g[k]['median']:>8.2f} /{g[k]['p90']:>7.2f} /{g[k]['worst']:>7.2f}" for k, _, _ in METRICS)
        lines.append(f"{name:<11}{g['logs']:>5}{g['frames']:>8}  {cells}")
    lines.append("")
    lines.append(f"{'layout':<11}" + "".join(f"{s:>10}" for s in STATUSES)
                 + "   normalised step error RMS x / y / theta, mean e^T C^-1 e (3 if honest) (n)")
    for name, g in summary.items():
        if name == "failed":
            continue
        norm = "  ".join(_normalised_cell(s, v, "/") for s, v in sorted(g["normalised"].items()))
        lines.append(f"{name:<11}" + "".join(f"{g['steps'][s]:>10}" for s in STATUSES) + "   " + norm)
    for f in summary.get("failed", []):
        lines.append(f"FAILED {f['name']}: {f['reason']}")
    return "\n".join(lines)


def format_markdown(summary: dict, records: list[dict], command: str) -> str:
    out = [f"`{command}`", "", "| layout | logs | " + " | ".join(label + " (median / p90 / worst)" for _, label, _ in METRICS)
           + " |", "|" + " --- |" * (2 + len(METRICS))]
    for name, g in summary.items():
        if name == "failed":
            continue
        out.append(f"| {name} | {g['logs']} | " + " | ".join(
            f"{g[k]['median']:.2f} / {g[k]['p90']:.2f} / {g[k]['worst']:.2f}" for k, _, _ in METRICS) + " |")
    out += ["", "| layout | " + " | ".join(STATUSES)
            + " | normalised RMS x / y / theta, mean e^T C^-1 e (3 if honest) (steps) |",
            "|" + " --- |" * (2 + len(STATUSES))]
    for name, g in summary.items():
        if name == "failed":
            continue
        norm = "; ".join(_normalised_cell(s, v, " / ") for s, v in sorted(g["normalised"].items()))
        out.append(f"| {name} | " + " | ".join(str(g["steps"][s]) for s in STATUSES) + f" | {norm} |")
    out += ["", "| log | frames | path m | texture | raw drift % | raw yaw | smoothed drift % | smoothed yaw | frames M |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in sorted(records, key=lambda r: (r["layout"], r["seed"])):
        if r.get("status") != "ok":
            out.append(f"| {r.get('name', r['seed'])} | failed: {r.get('reason')} | | | | | | | |")
            continue
        out.append(f"| {r['name']} | {r['frames']} | {r['path_m']:.1f} | {r['scene']['texture']} | "
                   f"{r['raw_drift_pct']:.2f} | {r['raw_yaw_deg']:+.2f} | {r['smoothed_drift_pct']:.2f} | "
                   f"{r['smoothed_yaw_deg']:+.2f} | {r['manhattan_frames']} |")
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------ command
def main(args: argparse.Namespace) -> int:
    import sys

    from planar_vo.core.errors import InputError
    from planar_vo.io.atomic import write_text_atomic

    seeds = parse_seeds(args.seeds)
    layouts = [s.strip() for s in args.layouts.split(",") if s.strip()]
    bad = [lay for lay in layouts if lay not in LAYOUTS]
    if bad:
        raise InputError(f"--layouts: {', '.join(bad)} unknown; use {', '.join(LAYOUTS)}")
    if args.workers < 1:
        raise InputError("--workers must be at least 1")
    Path(args.cache).mkdir(parents=True, exist_ok=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    jobs = plan(seeds, layouts, args.long)
    print(f"planar-vo bench sweep: {len(jobs)} logs (seeds {seeds[0]}-{seeds[-1]}, {', '.join(layouts)}"
          f"{', speed dips' if args.speed_dips else ''}), {args.workers} workers, cache {args.cache}", flush=True)
    records: list[dict] = []
    t0 = time.perf_counter()
    try:
        with ProcessPoolExecutor(args.workers) as pool:
            futs = [pool.submit(run_one, s, lay, n, args.cache, args.out, args.config, args.speed_dips)
                    for s, lay, n in jobs]
            for f in as_completed(futs):
                r = f.result()
                records.append(r)
                msg = (f"smoothed {r['smoothed_drift_pct']:.2f} % / {r['smoothed_yaw_deg']:+.2f} deg, raw "
                       f"{r['raw_drift_pct']:.2f} % / {r['raw_yaw_deg']:+.2f} deg" if r["status"] == "ok"
                       else f"FAILED: {r['reason']}")
                print(f"[{len(records)}/{len(jobs)} {time.perf_counter() - t0:.0f} s] {r.get('name', r['seed'])}: {msg}",
                      flush=True)
    except KeyboardInterrupt:
        print("interrupted: summarising the logs done so far", file=sys.stderr)
    summary = summarise(records)
    text = format_summary(summary)
    print()
    print(text)
    command = "planar-vo bench sweep " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "planar-vo bench sweep"
    write_text_atomic(Path(args.out) / "sweep.json",
                      json.dumps({"command": command, "summary": summary, "logs": records}, indent=1, default=float) + "\n")
    write_text_atomic(Path(args.out) / "sweep.md", format_markdown(summary, records, command))
    print(f"\nwrote {args.out}/sweep.json, {args.out}/sweep.md")
    return 0 if not summary["failed"] else 1
