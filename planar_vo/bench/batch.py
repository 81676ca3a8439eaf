"""``planar-vo batch`` against a shell loop of ``planar-vo run``: wall time of N logs, one run.

``planar-vo bench batch [LOG ...] [--logs N] [--frames F] [--cache DIR] [--json PATH]``

Times, in one invocation and on the same logs: (1) ``planar-vo run`` on each log one after
another, each a fresh process (what a shell loop does); (2) ``planar-vo batch --workers 1``;
(3) ``planar-vo batch --workers 2`` -- each batch starting and stopping its own local Ray,
whose start-up is shown apart. Prints the wall times, their ratios, the load average, and
checks that the three give the same raw.tum and smoothed.tum (largest difference <= 1e-9;
exit 1 otherwise). Without LOGs, N synthetic qhd logs of F frames are rendered into the cache
once (layouts straight and lturn alternating, seeds 1..N).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LAYOUTS = ("straight", "lturn")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="*", metavar="LOG", help="MCAP logs or TUM folders (default: rendered)")
    parser.add_argument("--logs", dest="n_logs", type=int, default=4, metavar="N",
                        help="synthetic logs to render when no LOG is given (default 4)")
    parser.add_argument("--frames", type=int, default=150, help="frames per synthetic log (default 150)")
    parser.add_argument("--cache", default="runs/bench_batch_cache", help="rendered logs, reused")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the figures as JSON")


def _exe() -> str:
    here = Path(sys.executable).with_name("planar-vo")
    return str(here) if here.exists() else (shutil.which("planar-vo") or "planar-vo")


def rendered_logs(n: int, frames: int, cache: Path) -> list[Path]:
    """``n`` synthetic logs in ``cache`` (rendered once, reused)."""
    from planar_vo.sim.synth import SynthConfig, write_synth_log

    cache.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(n):
        layout = LAYOUTS[i % len(LAYOUTS)]
        path = cache / f"{layout}_s{i + 1}_n{frames}.mcap"
        if not path.exists():
            print(f"rendering {path} ({frames} frames)", flush=True)
            tmp = cache / f".{path.name}.part.mcap"
            paths = write_synth_log(SynthConfig(layout=layout, seed=i + 1, n_frames=frames), tmp, progress=False)
            os.replace(paths["ground_truth"], path.with_suffix(".gt.tum"))
            os.replace(tmp, path)
        out.append(path)
    return out


def _timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 4):  # 4: finished, motion not estimated (still a result)
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()[-300:]}")
    return wall


def measure(logs: list[Path], work: Path) -> dict:
    """Wall seconds of the sequential loop and of batch with 1 and 2 workers, and each
    batch's Ray start-up; the run folders stay in ``work``."""
    from planar_vo.fleet.logs import result_names

    names = result_names(logs)
    out: dict = {"logs": [str(p) for p in logs]}
    t_seq = 0.0
    for log in logs:
        t_seq += _timed([_exe(), "run", str(log), "--out", str(work / "seq" / names[log]), "--quiet"])
    out["sequential_run_s"] = round(t_seq, 2)
    # the largest peak RSS of the children so far: the `planar-vo run` processes
    out["run_peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1)
    for w in (1, 2):
        res = work / f"batch{w}"
        wall = _timed([_exe(), "batch", *map(str, logs), "--out", str(res), "--workers", str(w), "--quiet"])
        doc = json.loads((res / "summary.json").read_text())
        summary = doc["totals"]
        out[f"batch{w}"] = {"wall_s": round(wall, 2), "ray_start_s": summary["ray"]["start_s"],
                            "frames": summary["frames_run"],
                            "task_peak_rss_mb": max(r["peak_rss_mb"] or 0 for r in doc["logs"])}
    out["frames"] = out["batch1"]["frames"]
    out["max_difference"] = _max_difference(work, [names[p] for p in logs])
    return out


def _max_difference(work: Path, names: list[str]) -> float:
    import numpy as np

    from planar_vo.io.trajectory import read_tum_trajectory

    worst = 0.0
    for name in names:
        for traj in ("raw.tum", "smoothed.tum"):
            a = read_tum_trajectory(work / "seq" / name / traj)
            for w in (1, 2):
                b = read_tum_trajectory(work / f"batch{w}" / name / traj)
                if len(a) != len(b):
                    return float("inf")
                worst = max(worst, float(np.max(np.abs(a.poses - b.poses))), float(np.max(np.abs(a.stamps - b.stamps))))
    return worst


def format_figures(f: dict) -> str:
    seq = f["sequential_run_s"]
    lines = [f"{len(f['logs'])} logs, {f['frames']} frames; load average before {f['load_before']}, after {f['load_after']}",
             f"{'mode':<34}{'wall s':>9}{'Ray start s':>13}{'frames/s':>10}{'loop / this':>13}"]
    lines.append(f"{'planar-vo run, one after another':<34}{seq:>9.1f}{'':>13}{f['frames'] / seq:>10.1f}{1.0:>13.2f}")
    for w in (1, 2):
        b = f[f"batch{w}"]
        lines.append(f"{f'planar-vo batch --workers {w}':<34}{b['wall_s']:>9.1f}{b['ray_start_s']:>13.1f}"
                     f"{f['frames'] / b['wall_s']:>10.1f}{seq / b['wall_s']:>13.2f}")
    b1, b2 = f["batch1"], f["batch2"]
    lines.append(f"2 workers against 1: {b1['wall_s'] / b2['wall_s']:.2f}x on the wall clock, "
                 f"{(b1['wall_s'] - b1['ray_start_s']) / (b2['wall_s'] - b2['ray_start_s']):.2f}x without Ray's start-up")
    lines.append(f"peak memory: planar-vo run {f['run_peak_rss_mb']:.0f} MB, a batch task (Ray worker) "
                 f"{max(b1['task_peak_rss_mb'], b2['task_peak_rss_mb']):.0f} MB (largest over the logs)")
    lines.append(f"results: largest difference between the three {f['max_difference']:.3g} "
                 f"({'identical' if f['max_difference'] <= 1e-9 else 'DIFFERENT'})")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from planar_vo.core.errors import InputError

    if args.logs:
        logs = [Path(p).resolve() for p in args.logs]
    elif args.n_logs < 1 or args.frames < 1:
        raise InputError("--logs and --frames must be at least 1")
    else:
        logs = rendered_logs(args.n_logs, args.frames, Path(args.cache).resolve())
    with tempfile.TemporaryDirectory(prefix="planar-vo-bench-batch-") as tmp:
        load_before = ", ".join(f"{v:.1f}" for v in os.getloadavg())
        figures = measure(logs, Path(tmp))
    figures["load_before"], figures["load_after"] = load_before, ", ".join(f"{v:.1f}" for v in os.getloadavg())
    figures["cpus"] = os.cpu_count()
    print(format_figures(figures))
    if args.json:
        from planar_vo.io.atomic import write_text_atomic
        write_text_atomic(args.json, json.dumps(figures, indent=2) + "\n")
    return 0 if figures["max_difference"] <= 1e-9 else 1
