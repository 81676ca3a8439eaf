"""Run the whole job on the shipped sample: log in, trajectories, evaluation and plot out.

The sample is a synthetic Kinect v2 corridor log with an L turn, shipped as the recipe
``data/demo_corridor_lturn.yaml`` and rendered deterministically on first use (a rendered
log is ~160 MB, too large to commit); ``--log`` runs the demo on any other log instead.
"""
from __future__ import annotations

import argparse
import json
from importlib import resources
from pathlib import Path

#: data/demo_corridor_lturn.yaml in the repository, installed as package data of planar_vo.data
RECIPE_NAME = "demo_corridor_lturn.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="runs/demo", help="run folder (default: runs/demo)")
    p.add_argument("--log", help="run on this log instead of the shipped sample")
    p.add_argument("--samples", default="runs/samples", help="where the rendered sample is kept")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def sample_log(samples_dir: Path, progress: bool = True) -> Path:
    """The demo log, rendered from the recipe unless an up-to-date copy exists."""
    import yaml

    from planar_vo.configtools import from_dict
    from planar_vo.sim.synth import SynthConfig, open3d, write_synth_log

    text = resources.files("planar_vo.data").joinpath(RECIPE_NAME).read_text()
    cfg = from_dict(SynthConfig, yaml.safe_load(text))
    out = samples_dir / f"{Path(RECIPE_NAME).stem}.mcap"
    recipe_copy = samples_dir / RECIPE_NAME
    if (out.exists() and out.with_suffix(".gt.tum").exists() and recipe_copy.exists()
            and recipe_copy.read_text() == text):
        return out
    open3d()  # the renderer is the workshop's: say how to install it before anything else
    samples_dir.mkdir(parents=True, exist_ok=True)
    print(f"rendering the sample log {out} from the recipe {RECIPE_NAME} (first run only)")
    write_synth_log(cfg, out, progress=progress)
    recipe_copy.write_text(text)  # the rendered log is current for exactly this recipe
    return out


def main(args: argparse.Namespace) -> int:
    from planar_vo.commands.run import exit_code, print_summary
    from planar_vo.config import load_config
    from planar_vo.core.errors import InputError
    from planar_vo.evaluation import evaluate_run, format_table
    from planar_vo.pipeline import run

    if args.log:
        log = Path(args.log)
        if not log.exists():
            raise InputError(f"{log}: log not found; pass an MCAP file or TUM folder to --log")
    else:
        log = sample_log(Path(args.samples), progress=not args.quiet)
    print(f"planar-vo demo: {log} -> {args.out}")
    result = run(log, args.out, load_config(), progress=not args.quiet)
    print_summary(result)
    print()
    ev = evaluate_run(args.out)
    print(format_table(ev))
    path = Path(args.out) / "evaluation.json"
    path.write_text(json.dumps(ev, indent=2) + "\n")
    print(f"\nplot: {Path(args.out) / 'trajectory.png'}   figures: {path}")
    return exit_code(result)
