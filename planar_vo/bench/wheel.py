"""Wheel odometry fusion over randomized scenes: ``planar-vo bench wheel --seeds A-B``.

``planar-vo bench wheel --seeds 2000-2002 [--layouts loop,straight] [--textures none,low,medium]
[--cache DIR] [--out DIR] [--config FILE] [--frames N]``

For every seed, layout and texture, a randomized log (:func:`randomized_config`, its texture
then set to the one asked for) is rendered with synthetic wheel odometry (the default
:class:`planar_vo.io.wheel_odom.WheelOdomModel`: +2 % scale, +3 % wheelbase, 0.5 deg/m heading
drift, seeded with the log) and run three times with ``planar-vo run``'s code path: without
the odometry (``--no-wheel-odom``), with it in batch, and with it online (iSAM2). Printed per
log: end-point drift (% of path) and final yaw error (deg) of raw, smoothed without odometry,
smoothed with it (batch / online) and the odometry alone; ``OUT/wheel.json`` keeps them all.
Tune on one range of seeds, report on another.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

VARIANTS = (("vision", {"backend": {"wheel_odom": False}}), ("fused", {}), ("online", {"solver": "online"}))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", required=True, metavar="A-B", help="inclusive seed range, e.g. 2000-2002")
    parser.add_argument("--layouts", default="loop,straight", help="comma-separated (default: loop,straight)")
    parser.add_argument("--textures", default="none,low,medium", help="comma-separated (default: none,low,medium)")
    parser.add_argument("--frames", type=int, default=None, help="at least this many frames (default: the sweep's)")
    parser.add_argument("--cache", default="runs/wheel_cache", help="rendered logs, reused (default runs/wheel_cache)")
    parser.add_argument("--out", default="runs/wheel", help="run folders and wheel.json (default runs/wheel)")
    parser.add_argument("--config", default=None, help="run configuration YAML (as planar-vo run --config)")


def _render(seed: int, layout: str, texture: str, frames, cache: Path) -> tuple[Path, object]:
    from planar_vo.bench.sweep import log_name
    from planar_vo.sim.synth import write_synth_log
    from planar_vo.sim.synth_random import randomized_config
    from planar_vo.io.wheel_odom import WheelOdomModel

    cfg = replace(randomized_config(seed, layout, n_frames=frames), texture=texture)
    name = log_name(cfg) + f"_{texture}_odom"
    log = cache / f"{name}.mcap"
    if not (log.exists() and (cache / f"{name}.gt.tum").exists()):
        tmp = cache / f"{name}.part.mcap"
        paths = write_synth_log(cfg, tmp, progress=False, wheel_odom=WheelOdomModel(seed=seed))
        os.replace(paths["ground_truth"], cache / f"{name}.gt.tum")
        os.replace(tmp, log)
    return log, cfg


def run_one(seed: int, layout: str, texture: str, frames, cache: Path, out: Path, config_path) -> dict:
    """Render (or reuse) one log, run the three variants, evaluate; a dict of figures."""
    from planar_vo.config import load_config
    from planar_vo.evaluation import evaluate_run
    from planar_vo.io.trajectory import read_tum_trajectory
    from planar_vo.pipeline import run

    rec: dict = {"seed": seed, "layout": layout, "texture": texture}
    t0 = time.perf_counter()
    log, cfg = _render(seed, layout, texture, frames, cache)
    rec.update(log=log.name, frames=cfg.n_frames, render_s=round(time.perf_counter() - t0, 1))
    gt = read_tum_trajectory(str(log)[:-5] + ".gt.tum")
    for name, ov in VARIANTS:
        config = load_config(config_path, {"output": {"plot": False, "poses_mcap": False}, **ov})
        run_dir = out / log.stem / name
        result = run(log, run_dir, config, progress=False)
        ev = evaluate_run(run_dir, gt)
        rec[f"{name}_motion"] = result.report.get("motion", {}).get("verdict")
        keys = [("raw", "raw"), (name, "smoothed")] + ([("wheel", "wheel_odom")] if "wheel_odom" in ev else [])
        for key, col in keys:
            rec[f"{key}_drift_pct"] = ev[col]["endpoint_drift_pct"]
            rec[f"{key}_yaw_deg"] = ev[col]["final_yaw_error_deg"]
        rec["path_m"] = ev["smoothed"]["path_length_m"]
    return rec


COLS = ("raw", "vision", "fused", "online", "wheel")


def format_rows(recs: list[dict]) -> str:
    head = "| log | frames | path m | " + " | ".join(f"{c} drift % / yaw deg" for c in COLS) + " |"
    lines = [head, "|" + " --- |" * (3 + len(COLS))]
    for r in recs:
        cells = [f"{r[f'{c}_drift_pct']:.2f} / {r[f'{c}_yaw_deg']:+.2f}" if f"{c}_drift_pct" in r else "n/a"
                 for c in COLS]
        lines.append(f"| {r['layout']} s{r['seed']} {r['texture']} | {r['frames']} | {r['path_m']:.1f} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from planar_vo.bench.sweep import parse_seeds

    cache, out = Path(args.cache), Path(args.out)
    cache.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    recs = []
    for seed in parse_seeds(args.seeds):
        for layout in args.layouts.split(","):
            for texture in args.textures.split(","):
                try:
                    recs.append(run_one(seed, layout, texture, args.frames, cache, out, args.config))
                except Exception as exc:  # noqa: BLE001 - one log's failure must not stop the bench
                    print(f"| {layout} s{seed} {texture} | failed: {type(exc).__name__}: {exc} |", flush=True)
                    continue
                print(format_rows(recs[-1:]).splitlines()[-1], flush=True)
                (out / "wheel.json").write_text(json.dumps(recs, indent=2) + "\n")
    print(format_rows(recs))
    return 0
