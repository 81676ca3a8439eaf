"""Run a fleet's logs (MCAP files, TUM folders, folders of them) as one Ray task per log, resumably, with one summary.

Local Ray by default (started and stopped here, loopback only, no dashboard), or an
existing cluster with ``--address``. Ray is the optional extra ``planar-vo[fleet]``.
"""
from __future__ import annotations

import argparse
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG_OR_FOLDER",
                   help="MCAP logs, TUM RGB-D folders, or folders searched recursively for them")
    p.add_argument("--out", required=True, help="results folder: one run folder per log plus summary.{csv,json,md}")
    p.add_argument("--address", help="an existing Ray cluster (e.g. 10.0.0.5:6379 or auto); default: local Ray")
    p.add_argument("--workers", type=int, help="logs run at once (default: the CPUs Ray has)")
    p.add_argument("--config", help="YAML configuration, as 'planar-vo run --config'")
    p.add_argument("--gt-from-logs", action="store_true",
                   help="evaluate each log against the ground truth it carries (/ground_truth, TUM groundtruth.txt) "
                        "or LOG.gt.tum beside it, and draw it")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def main(args: argparse.Namespace) -> int:
    from planar_vo.config import load_config
    from planar_vo.fleet.runner import exit_code, run_batch

    config = load_config(args.config)
    result = run_batch(args.logs, args.out, config, address=args.address, workers=args.workers,
                       gt_from_logs=args.gt_from_logs, progress=not args.quiet)
    print_summary(result, args.out)
    return exit_code(result)


def print_summary(result, out: str) -> None:
    jobs = result.jobs
    counts: dict[str, int] = {}
    for j in jobs:
        s = (j.record or {}).get("status", "not_run")
        counts[s] = counts.get(s, 0) + 1
    frames = sum(int((j.record or {}).get("frames") or 0) for j in jobs if not j.skipped)
    print(f"logs: {len(jobs)} (" + ", ".join(f"{s} {n}" for s, n in sorted(counts.items()))
          + f"; skipped {sum(j.skipped for j in jobs)} finished before)")
    print(f"frames run: {frames} in {result.run_s:.1f} s ({frames / result.run_s if result.run_s > 0 else 0:.1f} "
          f"frames/s over the fleet); Ray {result.ray.get('mode')}, start {result.ray.get('start_s', 0):.1f} s")
    for j in jobs:
        rec = j.record or {}
        if rec.get("status") not in ("ok", None) and rec.get("reason"):
            print(f"{rec['status']}: {j.name} ({j.log}): {rec['reason']}", file=sys.stderr)
    if result.interrupted:
        print("interrupted: finished logs are kept; run the same command again to continue", file=sys.stderr)
    print(f"wrote {out}/: summary.csv, summary.json, summary.md and one folder per log")
