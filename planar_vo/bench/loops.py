"""Loop closure on building rings: ``planar-vo bench loops --seeds A-B``.

``planar-vo bench loops --seeds 5000-5001 [--layout building] [--laps 1.5] [--lap-m 40]
[--speed 0.4] [--rate 10] [--cache DIR] [--out DIR] [--no-online]``

For every seed a randomized log of ``--layout`` (default the building ring: corridors
round a block, repeating doors and posters; scene, texture, mount, wobble and sensor
drawn from the seed as in ``bench sweep``, speed and rate fixed so that the frame count
stays renderable) driven ``--laps`` laps is rendered into the cache (reused), then run end
to end with loop closure in batch and online (iSAM2), and compared with its ground truth
(the batch run also writes the solution without closures). Printed per log and as median / worst over logs:

* raw, smoothed-without-loops and smoothed end-point drift (% of path) and ATE (m);
* revisited keyframes (ground truth: :func:`planar_vo.sim.revisits.revisit_pairs`) and the
  share of them that a kept closure joins to an earlier keyframe;
* every kept closure's error against the ground-truth relative pose (m, deg), worst;
* batch against online: largest distance between the two smoothed trajectories (m);
* the online run's frames per second end to end, and loop closure's cost in
  milliseconds per frame (wall and CPU, from ``report.json``).

Everything also goes to ``OUT/loops_LAYOUT_SEEDS.json``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", required=True, metavar="A-B", help="inclusive seed range, e.g. 5000-5001")
    parser.add_argument("--layout", default="building", help="synth layout (default building)")
    parser.add_argument("--laps", type=float, default=1.5, help="laps driven (default 1.5)")
    parser.add_argument("--lap-m", type=float, default=40.0, help="lap length in m (default 40)")
    parser.add_argument("--speed", type=float, default=0.4, help="cruise speed m/s (default 0.4)")
    parser.add_argument("--rate", type=float, default=10.0, help="frame rate Hz (default 10)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="N frames (default: what the laps of --lap-m need at --speed and --rate)")
    parser.add_argument("--cache", default="runs/loops_cache", help="rendered logs, reused (default runs/loops_cache)")
    parser.add_argument("--out", default="runs/loops", help="run folders and loops_LAYOUT_SEEDS.json (default runs/loops)")
    parser.add_argument("--no-online", action="store_true", help="skip the online (iSAM2) run")
    parser.add_argument("--config", default=None, help="run configuration YAML (as planar-vo run --config)")


def _log_for(seed: int, args) -> tuple[Path, object]:
    """Render (or reuse) the randomized log of ``seed`` at ``--speed`` and ``--rate``, with
    the frames for ``--laps`` laps of ``--lap-m``; ``(log path, SynthConfig)``."""
    from dataclasses import replace

    from planar_vo.bench.sweep import log_name
    from planar_vo.sim.synth import frames_for_laps, write_synth_log
    from planar_vo.sim.synth_random import randomized_config

    cfg = randomized_config(seed, args.layout)
    n = args.frames or frames_for_laps(args.laps, args.lap_m, args.speed, args.rate)
    cfg = replace(cfg, speed=args.speed, rate_hz=args.rate, n_frames=n, laps=args.laps)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    name = log_name(cfg)
    log = cache / f"{name}.mcap"
    if not (log.exists() and (cache / f"{name}.gt.tum").exists()):
        tmp = cache / f"{name}.part.mcap"
        paths = write_synth_log(cfg, tmp, progress=True)
        os.replace(paths["ground_truth"], cache / f"{name}.gt.tum")
        os.replace(tmp, log)
    return log, cfg


def _base_poses(gt, stamps: np.ndarray, T_base_cam: np.ndarray) -> np.ndarray:
    """(N, 3) ground-truth ``T_world_base`` (x, y, yaw) at ``stamps`` (nearest GT pose)."""
    from planar_vo.sim.revisits import base_poses_from_cam

    idx = np.searchsorted(gt.stamps, stamps).clip(1, len(gt.stamps) - 1)
    idx = np.where(np.abs(gt.stamps[idx - 1] - stamps) < np.abs(gt.stamps[idx] - stamps), idx - 1, idx)
    return base_poses_from_cam(gt.poses[idx], T_base_cam)


def closure_errors(closures: list[dict], gt_base: np.ndarray) -> list[dict]:
    """Each kept closure's translation (m) and yaw (deg) error against the ground-truth
    relative pose of its two frames (``gt_base``: (N, 3) per pose index)."""
    from planar_vo.sim.revisits import closure_error

    out = []
    for c in closures:
        error_m, error_deg = closure_error(gt_base, c["a"], c["b"], c["pose"])
        out.append({"a": c["a"], "b": c["b"], "error_m": error_m, "error_deg": error_deg})
    return out


def revisits_closed(report: dict, gt_base: np.ndarray) -> dict:
    """Revisited keyframes (ground truth) and how many a kept closure joins to an earlier one."""
    from planar_vo.sim.revisits import revisit_pairs

    lc = report["loop_closure"]
    kfs = np.asarray(lc["keyframe_frames"], dtype=int)
    pairs = revisit_pairs(gt_base, kfs)
    revisiting = sorted({b for _, b in pairs})
    closed_b = {c["b"] for c in lc["list"] if c["verdict"] == "accepted"}
    closed = [b for b in revisiting if b in closed_b]
    return {"revisiting_keyframes": len(revisiting), "closed": len(closed),
            "closed_pct": 100.0 * len(closed) / len(revisiting) if revisiting else float("nan")}


def _run(log: Path, run_dir: Path, config_path: str | None, overrides: dict) -> dict:
    from planar_vo.config import load_config
    from planar_vo.pipeline import run

    config = load_config(config_path, {"output": {"poses_mcap": False}, **overrides})
    return run(log, run_dir, config, progress=False).report


def evaluate_log(seed: int, args) -> dict:
    """Render/reuse, run three ways and compare one log; a dict for the summary."""
    from planar_vo.evaluation import evaluate_run
    from planar_vo.io.trajectory import read_tum_trajectory
    from planar_vo.sim.synth import synth_mount

    log, cfg = _log_for(seed, args)
    gt = read_tum_trajectory(str(log)[:-5] + ".gt.tum")
    out = Path(args.out) / log.stem
    rep = _run(log, out / "batch", args.config, {})
    rec = {"seed": seed, "log": log.name, "frames": rep["frames"]["with_pose"], "texture": cfg.texture}
    ev = evaluate_run(out / "batch", gt)
    for k in ("raw", "smoothed_no_loops", "smoothed"):
        if k in ev:
            rec[f"{k}_drift_pct"], rec[f"{k}_ate_m"] = ev[k]["endpoint_drift_pct"], ev[k]["ate_rmse_m"]
    rec["path_m"] = ev["smoothed"]["path_length_m"]
    rec["smoothed_end_error_m"] = ev["smoothed"]["endpoint_drift_m"]
    stamps = np.loadtxt(out / "batch" / "smoothed.tum", usecols=0, ndmin=1)
    gt_base = _base_poses(gt, stamps, np.asarray(synth_mount(cfg).T_base_cam))
    kept = [c for c in rep["loop_closure"]["list"] if c["verdict"] == "accepted"]
    errs = closure_errors(kept, gt_base)
    rec.update(revisits_closed(rep, gt_base), kept=len(kept),
               candidates=rep["loop_closure"]["candidates"], removed=rep["loop_closure"]["removed_by_graph"],
               closure_error_m_worst=max((e["error_m"] for e in errs), default=float("nan")),
               closure_error_deg_worst=max((e["error_deg"] for e in errs), default=float("nan")),
               loops_ms_per_frame=rep["timings_ms_per_frame"].get("loops"),
               loops_cpu_ms_per_frame=rep["cpu_ms_per_frame"].get("loops"), batch_fps=rep["fps"])
    if not args.no_online:
        rep_on = _run(log, out / "online", args.config, {"solver": "online"})
        a = np.loadtxt(out / "batch" / "smoothed.tum", usecols=(1, 2, 3), ndmin=2)
        b = np.loadtxt(out / "online" / "smoothed.tum", usecols=(1, 2, 3), ndmin=2)
        rec.update(online_fps=rep_on["fps"], batch_vs_online_m=float(np.linalg.norm(a - b, axis=1).max()),
                   online_loops_ms_per_frame=rep_on["timings_ms_per_frame"].get("loops"))
    return rec


COLUMNS = (("texture", "texture", "{}"), ("frames", "frames", "{:d}"), ("path_m", "path m", "{:.1f}"), ("raw_drift_pct", "raw %", "{:.2f}"),
           ("smoothed_no_loops_drift_pct", "no loops %", "{:.2f}"), ("smoothed_drift_pct", "smoothed %", "{:.3f}"),
           ("smoothed_end_error_m", "end error m", "{:.3f}"), ("smoothed_ate_m", "ATE m", "{:.3f}"), ("closed_pct", "revisits closed %", "{:.0f}"),
           ("kept", "kept", "{:d}"), ("removed", "removed", "{:d}"),
           ("closure_error_m_worst", "worst closure m", "{:.3f}"),
           ("closure_error_deg_worst", "worst closure deg", "{:.2f}"),
           ("batch_vs_online_m", "batch-online m", "{:.4f}"), ("online_fps", "online fps", "{:.1f}"),
           ("loops_cpu_ms_per_frame", "loops cpu ms/frame", "{:.2f}"))


def format_table(records: list[dict]) -> str:
    cols = [c for c in COLUMNS if any(c[0] in r for r in records)]
    lines = ["| seed | " + " | ".join(h for _, h, _ in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for r in records:
        cells = [(f.format(r[k]) if isinstance(r.get(k), (int, float, str)) else "n/a") for k, _, f in cols]
        lines.append(f"| {r['seed']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: Summary rows: key, label, whether larger is worse (else smaller is worse).
SUMMARY = (("smoothed_drift_pct", "smoothed drift %", True), ("smoothed_end_error_m", "smoothed end error m", True),
           ("smoothed_ate_m", "smoothed ATE m", True), ("closed_pct", "revisits closed %", False),
           ("closure_error_m_worst", "worst closure error m", True),
           ("closure_error_deg_worst", "worst closure error deg", True),
           ("batch_vs_online_m", "batch - online m", True), ("online_fps", "online fps", False),
           ("loops_cpu_ms_per_frame", "loop closure CPU ms/frame", True))


def summary(records: list[dict]) -> str:
    """Median and worst over the logs of the figures the issue's targets name."""
    lines = ["| over logs | median | worst |", "|---|---|---|"]
    for key, label, larger_worse in SUMMARY:
        v = np.array([r[key] for r in records if isinstance(r.get(key), (int, float)) and math.isfinite(r[key])])
        if len(v):
            worst = v.max() if larger_worse else v.min()
            lines.append(f"| {label} | {np.median(v):.4g} | {worst:.4g} |")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from planar_vo.bench.sweep import parse_seeds
    from planar_vo.io.atomic import write_text_atomic

    records = []
    for seed in parse_seeds(args.seeds):
        rec = evaluate_log(seed, args)
        records.append(rec)
        print(format_table([rec]).splitlines()[-1], flush=True)
    print(format_table(records))
    print(summary(records))
    Path(args.out).mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(args.out) / f"loops_{args.layout}_{args.seeds}.json", json.dumps(records, indent=2) + "\n")
    return 0
