"""``planar-vo run`` end to end: frames per second, CPU per stage, peak memory.

``planar-vo bench run LOG [LOG ...] [--frames N] [--repeat N] [--config YAML] [--online] [--json PATH]``

Each run is the whole job of ``planar-vo run`` (:func:`planar_vo.pipeline.run`: MCAP
reading, decoding and corner tracking in the reader, front-end, back-end, optimisation,
the log summary and every output file) in a fresh Python process, so that its peak RSS is
its own. Printed per log and run: frames per second end to end (wall clock, the figure
``planar-vo run`` prints), the run's CPU milliseconds per frame (all threads, the reader
process's included) and the main process's peak RSS (the reader process's is printed
with the medians); then the median over the runs of the CPU milliseconds per frame of
every stage -- the front-end's own stages in CPU time of the main thread -- and the load
average. On a machine shared with other jobs, wall-clock fps depends on the load; CPU
times do not (much), so both are shown.

Results must not depend on speed work: the runs of one invocation are checked against
each other, and ``--reference DIR`` checks them against the runs an earlier invocation
kept with ``--keep DIR`` (raw.tum and smoothed.tum, largest difference at most
:data:`RESULT_TOLERANCE`; the command exits with 1 otherwise).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TARGET_FPS = 30.0
#: Largest difference (stamps in s, pose matrix entries) between runs taken as "the same result".
RESULT_TOLERANCE = 1e-9
TRAJECTORIES = ("raw.tum", "smoothed.tum")
_CHILD_FLAG = "--_child"

#: Stages of report.json ``cpu_ms_per_frame`` in print order, with their labels.
STAGES = (("outputs_import_background", "output-stage imports (side thread)"),
          ("read_decode_background", "read + decode (reader)"),
          ("track_background", "corner tracking (reader)"),
          ("reader_process", "reader process (input.reader: process)"),
          ("plot_process", "plot process (imports, trajectory.png)"),
          ("frontend", "front-end (main thread)"),
          ("frontend.planes", "  planes"),
          ("frontend.manhattan", "  manhattan"),
          ("frontend.features", "  features (tracking: reader)"),
          ("frontend.estimate", "  estimate"),
          ("backend", "back-end add_frame"),
          ("loops", "loop closure: keyframes, candidates, verification"),
          ("summary", "log summary for the report (once)"),
          ("optimize", "optimize (once)"),
          ("write", "write outputs (once)"),
          ("process", "whole run, all threads and processes"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="+", metavar="LOG", help="MCAP logs or TUM RGB-D folders")
    parser.add_argument("--repeat", type=int, default=3, metavar="N",
                        help="runs per log, each in a fresh process (default 3)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="use the first N frames of each log (default: all)")
    parser.add_argument("--config", default=None, metavar="YAML", help="planar-vo run configuration")
    parser.add_argument("--online", action="store_true", help="iSAM2 per frame instead of batch LM")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write all figures as JSON")
    parser.add_argument("--keep", default=None, metavar="DIR",
                        help="keep the run folders as DIR/<log name>/run<i> (default: removed)")
    parser.add_argument("--reference", default=None, metavar="DIR",
                        help="a --keep folder of an earlier benchmark: check that raw.tum and smoothed.tum "
                             f"are unchanged (largest difference <= {RESULT_TOLERANCE:g}); exit 1 if not")


# ------------------------------------------------------------------------ child

def _child(log: str, out: str, config: str | None, online: bool, frames: int | None) -> dict:
    """One run in this (fresh) process; the figures as a JSON-able dict."""
    import resource
    import time

    from planar_vo.config import load_config
    from planar_vo.frontend.odometry import PlanarOdometry
    from planar_vo.pipeline import run

    # The front-end's per-stage figures in CPU time of the main thread (the pipeline's own
    # per-stage CPU figures do not depend on this).
    PlanarOdometry.clock = staticmethod(time.thread_time)
    overrides: dict = {"solver": "online"} if online else {}
    if frames is not None:
        overrides["input"] = {"stop": frames}
    cfg = load_config(config, overrides)
    load0 = os.getloadavg()[0]
    res = run(log, out, cfg, progress=False)
    r = res.report
    cpu = dict(r["cpu_ms_per_frame"])
    for k, v in r["timings_ms_per_frame"].items():
        if k.startswith("frontend.") and k != "frontend.total":
            cpu[k] = v
    return {"frames": r["frames"]["with_pose"], "fps": r["fps"], "wall_time_s": r["wall_time_s"],
            "cpu_ms_per_frame": cpu, "wall_ms_per_frame": r["timings_ms_per_frame"],
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            # the reader process (input.reader: process), joined by the run: its own peak
            "reader_peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0,
            "load_average": [load0, os.getloadavg()[0]], "partial": r["partial"],
            "image_size": [r["input"].get("width"), r["input"].get("height")]}


def _run_child(log: Path, out: Path, args: argparse.Namespace) -> dict:
    cmd = [sys.executable, "-m", "planar_vo.bench.run", _CHILD_FLAG, str(log), str(out)]
    if args.config:
        cmd += ["--config", args.config]
    if args.online:
        cmd.append("--online")
    if args.frames is not None:
        cmd += ["--frames", str(args.frames)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        if proc.returncode == 2:  # bad input, said in one line by the child
            from planar_vo.core.errors import InputError

            raise InputError(tail)
        raise RuntimeError(f"{log}: the run failed: {tail}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------ parent

def _median(values):
    v = sorted(x for x in values if x is not None)
    if not v:
        return None
    m = len(v) // 2
    return v[m] if len(v) % 2 else 0.5 * (v[m - 1] + v[m])


def trajectory_difference(a: Path, b: Path) -> float:
    """Largest absolute difference between the trajectories of two run folders: stamps (s)
    and pose matrix entries of raw.tum and smoothed.tum; inf if they do not pair up."""
    from planar_vo.io.trajectory import read_tum_trajectory

    worst = 0.0
    for name in TRAJECTORIES:
        ta, tb = read_tum_trajectory(a / name), read_tum_trajectory(b / name)
        if len(ta) != len(tb):
            return math.inf
        worst = max(worst, float(np.abs(ta.stamps - tb.stamps).max(initial=0.0)),
                    float(np.abs(ta.poses - tb.poses).max(initial=0.0)))
    return worst


def bench_log(log: Path, args: argparse.Namespace) -> dict:
    """All runs of one log, their medians and how their trajectories compare."""
    runs = []
    keep = Path(args.keep) / log.stem if args.keep else None
    with tempfile.TemporaryDirectory(prefix="planar-vo-bench-run-") as tmp:
        base = keep or Path(tmp)
        for i in range(args.repeat):
            runs.append(_run_child(log, base / f"run{i}", args))
        # The runs of one invocation must agree (threads must not change results) ...
        results = {"between_runs": max((trajectory_difference(base / "run0", base / f"run{i}")
                                        for i in range(1, args.repeat)), default=0.0)}
        # ... and with an earlier benchmark's runs, when given.
        if args.reference:
            ref = Path(args.reference) / log.stem / "run0"
            results["vs_reference"] = trajectory_difference(ref, base / "run0")
    keys = {k for r in runs for k in r["cpu_ms_per_frame"]}
    return {"log": str(log), "frames": runs[0]["frames"], "image_size": runs[0]["image_size"], "runs": runs,
            "trajectory_difference": results,
            "median": {"fps": _median([r["fps"] for r in runs]),
                       "peak_rss_mb": _median([r["peak_rss_mb"] for r in runs]),
                       "reader_peak_rss_mb": _median([r.get("reader_peak_rss_mb") for r in runs]),
                       "cpu_ms_per_frame": {k: _median([r["cpu_ms_per_frame"].get(k) for r in runs])
                                            for k in sorted(keys)}}}


def format_log(res: dict) -> str:
    w, h = res["image_size"]
    lines = [f"{res['log']}: {res['frames']} frames, {w}x{h}",
             f"  {'run':>4} {'fps (wall)':>11} {'wall s':>8} {'CPU ms/frame':>13} {'peak RSS MB':>12} {'load avg':>13}"]
    for i, r in enumerate(res["runs"], 1):
        la = r["load_average"]
        lines.append(f"  {i:>4} {r['fps']:>11.1f} {r['wall_time_s']:>8.2f} {r['cpu_ms_per_frame']['process']:>13.1f} "
                     f"{r['peak_rss_mb']:>12.0f} {la[0]:>6.2f}->{la[1]:<5.2f}")
    med = res["median"]
    cpu = med["cpu_ms_per_frame"]
    lines.append(f"  CPU ms per frame, median of {len(res['runs'])} runs (once-per-run stages spread over the frames):")
    for key, label in STAGES:
        if cpu.get(key) is not None:
            lines.append(f"    {label:<36}{cpu[key]:>8.2f}")
    # The threads overlap: with a core each, the slowest one sets the pace.
    main = sum(cpu.get(k) or 0.0 for k in ("frontend", "backend", "loops", "summary", "optimize", "write"))
    reader = cpu.get("reader_process") or sum(cpu.get(k) or 0.0 for k in ("read_decode_background",
                                                                           "track_background"))
    side = cpu.get("outputs_import_background") or 0.0
    lines.append(f"    {'main thread (front-end to write)':<36}{main:>8.2f}")
    diff = res["trajectory_difference"]
    same = all(v <= RESULT_TOLERANCE for v in diff.values())
    lines.append("  trajectories: " + ", ".join(f"{k.replace('_', ' ')} max |diff| {v:.3g}" for k, v in diff.items())
                 + f" ({'the same' if same else 'DIFFERENT'} within {RESULT_TOLERANCE:g})")
    fps = med["fps"]
    lines.append(f"  end to end: {fps:.1f} frames/s median (target >= {TARGET_FPS:g}: "
                 f"{'met' if fps >= TARGET_FPS else 'NOT met'}); CPU-bound pace with a free core per thread "
                 f"{1000.0 / max(main, reader, side, 1e-9):.0f} frames/s; peak RSS {med['peak_rss_mb']:.0f} MB"
                 + (f" (reader process {med['reader_peak_rss_mb']:.0f} MB, partly the same pages)"
                    if med.get("reader_peak_rss_mb") else ""))
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from planar_vo.core.errors import InputError

    logs = [Path(p) for p in args.logs]
    for p in logs:
        if not p.exists():
            raise InputError(f"{p}: no such log (pass MCAP files or TUM RGB-D folders)")
    if args.repeat < 1:
        raise InputError(f"--repeat must be >= 1, got {args.repeat}")
    if args.frames is not None and args.frames < 2:
        raise InputError(f"--frames must be >= 2, got {args.frames}")
    if args.json and not Path(args.json).resolve().parent.is_dir():
        raise InputError(f"--json {args.json}: folder {Path(args.json).parent} does not exist")
    if args.reference:
        for p in logs:
            ref = Path(args.reference) / p.stem / "run0"
            if not all((ref / name).is_file() for name in TRAJECTORIES):
                raise InputError(f"--reference {args.reference}: no {ref}/raw.tum and smoothed.tum; "
                                 "make it with --keep on an earlier benchmark of the same logs")
    import cv2

    env = {"cpu_count": os.cpu_count(), "load_average": os.getloadavg()[0],
           "opencv_threads": cv2.getNumThreads(), "python": sys.version.split()[0]}
    print(f"planar-vo bench run: {env['cpu_count']} CPUs, load average {env['load_average']:.2f}, "
          f"OpenCV threads {env['opencv_threads']}; {args.repeat} run(s) per log, each a fresh process "
          f"running the whole of 'planar-vo run'", flush=True)
    results = []
    for log in logs:
        res = bench_log(log, args)
        results.append(res)
        print()
        print(format_log(res), flush=True)
    if args.json:
        from planar_vo.io.atomic import write_text_atomic

        write_text_atomic(args.json, json.dumps({"environment": env, "logs": results}, indent=2) + "\n")
        print(f"\nwrote {args.json}")
    if args.keep:
        print(f"\nrun folders kept in {args.keep}/<log name>/run<i>")
    changed = any(v > RESULT_TOLERANCE for r in results for v in r["trajectory_difference"].values())
    return 1 if changed else 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == _CHILD_FLAG:
        p = argparse.ArgumentParser(prog="planar-vo bench run (child)")
        p.add_argument("log")
        p.add_argument("out")
        p.add_argument("--config", default=None)
        p.add_argument("--online", action="store_true")
        p.add_argument("--frames", type=int, default=None)
        a = p.parse_args(sys.argv[2:])
        from planar_vo.core.errors import InputError

        try:
            print(json.dumps(_child(a.log, a.out, a.config, a.online, a.frames)))
        except InputError as exc:  # the user's input, not a defect: one line, exit 2
            print(exc, file=sys.stderr)
            sys.exit(2)
        sys.exit(0)
    sys.exit(2)
