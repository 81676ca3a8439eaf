"""Benchmarks that print figures: solvers, frontend, backend, closures, io, peers, run, sweep, compare, batch, wheel, places, loops."""
from __future__ import annotations

import argparse
import importlib

#: bench name -> (module, help)
BENCHES: dict[str, tuple[str, str]] = {
    "solvers": ("planar_vo.bench.solvers", "the paper's synthetic experiment (Sec. 3.1): 2-point vs 5-point"),
    "frontend": ("planar_vo.bench.frontend", "front-end time per 960x540 frame pair, per stage"),
    "backend": ("planar_vo.bench.backend", "10,000-pose graph: batch LM and iSAM2 timings"),
    "closures": ("planar_vo.bench.closures", "loop closures on simulated rings: drift, false closures, batch vs iSAM2"),
    "io": ("planar_vo.bench.io", "peak memory while streaming a >= 1 GB log"),
    "peers": ("planar_vo.bench.peers", "planar-vo next to Open3D and OpenCV RGB-D odometry"),
    "run": ("planar_vo.bench.run", "planar-vo run end to end: frames per second, CPU per stage, peak memory"),
    "sweep": ("planar_vo.bench.sweep", "accuracy over randomized scenes: drift and yaw distributions per layout"),
    "compare": ("planar_vo.bench.compare", "two sweeps over the same seeds, before -> after: per layout and per log"),
    "batch": ("planar_vo.bench.batch", "planar-vo batch with 1 and 2 workers against planar-vo run one log after another"),
    "wheel": ("planar_vo.bench.wheel", "wheel odometry fusion over randomized scenes: with and without it"),
    "places": ("planar_vo.bench.places", "place recognition and loop-closure verification on a rendered corridor ring"),
    "loops": ("planar_vo.bench.loops", "loop closure on building rings: drift, revisits closed, closure errors, cost"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench", metavar="WHAT")
    for name, (module, help_text) in BENCHES.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_bench_module=module)
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        mod.add_arguments(p)


def main(args: argparse.Namespace) -> int:
    if not getattr(args, "bench", None):
        print("usage: planar-vo bench {" + ",".join(BENCHES) + "} ...")
        return 2
    return int(importlib.import_module(args._bench_module).main(args) or 0)
