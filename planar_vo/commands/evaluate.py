"""Compare a run's raw and smoothed trajectories with ground truth (ATE, RPE, drift, yaw)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", help="folder written by 'planar-vo run'")
    p.add_argument("--gt", help="ground truth: TUM file or MCAP carrying /ground_truth "
                                "(default: the run's log, or LOG.gt.tum beside it)")
    p.add_argument("--json", help="also write the figures here (default: RUN_DIR/evaluation.json)")
    p.add_argument("--max-dt", type=float, default=0.02, help="timestamp association tolerance [s]")


def main(args: argparse.Namespace) -> int:
    from planar_vo.evaluation import evaluate_run, format_table, load_ground_truth
    from planar_vo.io.atomic import write_text_atomic

    gt = load_ground_truth(args.gt) if args.gt else None
    result = evaluate_run(args.run_dir, gt, max_dt=args.max_dt)
    print(format_table(result))
    out = Path(args.json) if args.json else Path(args.run_dir) / "evaluation.json"
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0
