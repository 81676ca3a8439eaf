"""Run the whole job on the shipped sample: log in, trajectories, evaluation and plot out."""
from __future__ import annotations

import argparse
from pathlib import Path

DATA_DIR = Path(__file__).resolve().parents[2] / "data"
SAMPLE = DATA_DIR / "corridor_lturn.mcap"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="runs/demo", help="run folder (default: runs/demo)")
    p.add_argument("--log", default=str(SAMPLE), help="log to use (default: the shipped sample)")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def main(args: argparse.Namespace) -> int:
    from planar_vo.commands.run import print_summary
    from planar_vo.config import load_config
    from planar_vo.errors import InputError
    from planar_vo.evaluation import evaluate_run, format_table
    from planar_vo.pipeline import run

    log = Path(args.log)
    if not log.exists():
        raise InputError(f"{log}: sample log not found; run from a full clone of planar-vo or pass --log")
    print(f"planar-vo demo: {log.name} -> {args.out}")
    result = run(log, args.out, load_config(), progress=not args.quiet)
    print_summary(result)
    print()
    ev = evaluate_run(args.out)
    print(format_table(ev))
    import json

    (Path(args.out) / "evaluation.json").write_text(json.dumps(ev, indent=2) + "\n")
    print(f"\nplot: {Path(args.out) / 'trajectory.png'}")
    return 3 if result.partial else 0
