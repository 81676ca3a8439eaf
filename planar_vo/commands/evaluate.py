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
    p.add_argument("--per-frame", metavar="CSV",
                   help="also write each trajectory's error per frame (along, left of and above the "
                        "ground-truth heading, and yaw; first poses aligned) here")


def main(args: argparse.Namespace) -> int:
    from planar_vo.evaluation import (evaluate_run, find_ground_truth, format_per_frame_csv, format_table,
                                      load_ground_truth, per_frame_run)
    from planar_vo.io.atomic import write_text_atomic

    # found once: the table and the per-frame errors read the same ground truth
    gt = load_ground_truth(args.gt) if args.gt else find_ground_truth(Path(args.run_dir))
    result = evaluate_run(args.run_dir, gt, max_dt=args.max_dt)
    print(format_table(result))
    out = Path(args.json) if args.json else Path(args.run_dir) / "evaluation.json"
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    if args.per_frame:
        per_frame = per_frame_run(args.run_dir, gt, max_dt=args.max_dt)
        write_text_atomic(args.per_frame, format_per_frame_csv(per_frame))
        print(f"wrote {args.per_frame} (errors per frame: {', '.join(per_frame)})")
    return 0
