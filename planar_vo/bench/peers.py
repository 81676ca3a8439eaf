"""planar-vo next to Open3D and OpenCV RGB-D odometry on the same logs.

``planar-vo bench peers LOG [LOG ...] [--gt GT] [--frames N] [--json PATH]``

For each log, one pass decodes the frames and hands each one to every peer in turn
(:func:`planar_vo.bench.peer_methods.track`; nothing is cached, so long logs are fine); planar-vo
runs through its own pipeline (:func:`planar_vo.pipeline.run`) in the same process,
without plot and poses.mcap. Per method: ATE RMSE, end-point drift (% of path), final
yaw error, milliseconds per frame of the method's own processing (decoding excluded)
and failures. Also planar-vo's end-to-end frames per second (decoding included), and
the two ratios the project targets: planar-vo end-to-end fps / Open3D tensor fps
(>= 3x) and best peer drift / planar-vo drift (>= 5x).

Ground truth: ``--gt`` (TUM file or MCAP with /ground_truth), else the log's own
/ground_truth, else ``LOG.gt.tum`` beside the log; without any, only timings and
failures are shown.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from planar_vo.core.errors import InputError, PlanarVOError

PLANAR_VO = "planar_vo"
#: table order; the peers' names are the keys of planar_vo.bench.peer_methods.PEER_METHODS
ALL_METHODS = (PLANAR_VO, "open3d_legacy", "open3d_tensor", "opencv")
TENSOR = "open3d_tensor"
TARGET_SPEEDUP = 3.0
TARGET_DRIFT_RATIO = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="+", metavar="LOG", help="MCAP logs or TUM RGB-D folders")
    parser.add_argument("--gt", action="append", default=None, metavar="GT",
                        help="ground truth (TUM file or MCAP); once, or once per LOG in order")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="use the first N frames of each log (default: all)")
    parser.add_argument("--methods", nargs="+", choices=ALL_METHODS, default=list(ALL_METHODS),
                        metavar="M", help=f"methods to run (default: all of {' '.join(ALL_METHODS)})")
    parser.add_argument("--init", choices=("identity", "constant_velocity"), default="constant_velocity",
                        help="initial guess of each Open3D step (default: constant_velocity, "
                             "the previous step; OpenCV takes no guess)")
    parser.add_argument("--depth-max", type=float, default=4.5, metavar="M",
                        help="depth truncation for the peers, metres (default 4.5)")
    parser.add_argument("--config", default=None, metavar="YAML", help="planar-vo run configuration")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write all figures as JSON")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="keep planar-vo's run folders and the peers' TUM trajectories here "
                             "(DIR/<log name>/); default: a temporary folder, removed")


# ------------------------------------------------------------------------ helpers

def _ground_truth(log_path: Path, log, gt_arg: str | None):
    """Trajectory or None: ``--gt`` > the log's /ground_truth > ``LOG.gt.tum``; and where from."""
    from planar_vo.evaluation import ground_truth_for_log, load_ground_truth

    if gt_arg is not None:
        return load_ground_truth(gt_arg), str(gt_arg)
    return ground_truth_for_log(log_path, log)


def _errors(stamps, poses, gt) -> dict:
    from planar_vo.metrics import trajectory_errors

    if gt is None:
        return {}
    return trajectory_errors(stamps, poses, gt.stamps, gt.poses).as_dict()


def _align_to_gt(poses: np.ndarray, stamps: np.ndarray, gt) -> np.ndarray:
    """Peer poses re-based so that the first matched pose equals ground truth (for plots)."""
    from planar_vo.io.trajectory import associate_stamps

    if gt is None:
        return poses
    ia, ib = associate_stamps(stamps, gt.stamps)
    if not len(ia):
        return poses
    A = gt.poses[ib[0]] @ np.linalg.inv(poses[ia[0]])
    return A @ poses


def _run_planar_vo(log_path: Path, out_dir: Path, config, gt) -> dict:
    from planar_vo.io.trajectory import read_tum_trajectory
    from planar_vo.pipeline import run

    res = run(log_path, out_dir, config, progress=False)
    rep = res.report
    n = rep["frames"]["with_pose"]
    t = rep["timings_s"]
    # The method's own processing wherever it runs: corner tracking runs in the reader.
    own = t.get("frontend", 0.0) + t.get("backend", 0.0) + t.get("track_background", 0.0)
    fr = rep["frames"]
    failures = int(fr.get("bridged", 0)) + int(fr.get("failed", 0))
    rows = {}
    for kind, label, extra in (("raw", "planar-vo raw", 0.0), ("smoothed", "planar-vo smoothed", t.get("optimize", 0.0))):
        traj = read_tum_trajectory(out_dir / f"{kind}.tum")
        rows[f"{PLANAR_VO}_{kind}"] = {
            "label": label, "frames": n, "failures": failures,
            "ms_per_frame": 1000.0 * (own + extra) / n if n else math.nan,
            "errors": _errors(traj.stamps, traj.poses, gt),
        }
    e2e = {"fps": rep.get("fps"), "wall_time_s": rep.get("wall_time_s"),
           # decoding runs in a prefetch thread in newer pipelines (overlapping the estimation)
           "decode_ms_per_frame": 1000.0 * t.get("read_decode_background", t.get("read", 0.0)) / n if n else math.nan,
           "decode_wait_ms_per_frame": 1000.0 * t.get("read_wait", t.get("read", 0.0)) / n if n else math.nan,
           "frames_bridged": fr.get("bridged", 0), "frames_failed": fr.get("failed", 0),
           "partial": rep.get("partial", False), "run_dir": str(out_dir)}
    return {"rows": rows, "end_to_end": e2e}


def compare_log(log_path, *, gt_arg: str | None = None, frames: int | None = None,
                methods=ALL_METHODS, init: str = "constant_velocity", depth_max_m: float = 4.5,
                config=None, out_dir: str | Path | None = None, progress: bool = True) -> dict:
    """All figures for one log as a JSON-able dict (see :func:`format_table`)."""
    from planar_vo.config import load_config
    from planar_vo.io.trajectory import write_tum_trajectory
    from planar_vo.core.types import Trajectory
    from planar_vo.metrics import planarity
    from planar_vo.bench.peer_methods import PeerOptions, PeerTracker, make_method
    from planar_vo.pipeline import open_input
    from planar_vo.progress import Progress

    log_path = Path(log_path)
    overrides = {"output": {"plot": False, "poses_mcap": False}}
    if frames is not None:
        overrides["input"] = {"stop": int(frames)}
    config = load_config(config, overrides)
    options = PeerOptions(depth_max_m=depth_max_m, init=init)
    peers = [m for m in methods if m != PLANAR_VO]
    result: dict = {"log": str(log_path), "methods": {}}

    keep = out_dir is not None
    base = Path(out_dir) / log_path.stem if keep else Path(tempfile.mkdtemp(prefix="planar-vo-peers-"))
    base.mkdir(parents=True, exist_ok=True)
    try:
        with open_input(log_path, config) as log:
            gt, gt_source = _ground_truth(log_path, log, gt_arg)
            intr = log.intrinsics
        result["ground_truth"] = None if gt is None else {"source": gt_source, "poses": len(gt),
                                                          **planarity(gt.poses)}
        result["intrinsics"] = {"width": intr.width, "height": intr.height, "fx": intr.fx, "fy": intr.fy,
                                "cx": intr.cx, "cy": intr.cy}

        # planar-vo first, in its own pass over the log (its own decoding, timed by the pipeline).
        if PLANAR_VO in methods:
            try:
                pv = _run_planar_vo(log_path, base / "planar_vo", config, gt)
            except PlanarVOError:
                raise
            except Exception as exc:  # noqa: BLE001 - report it and still show the peers
                result["planar_vo_error"] = f"{type(exc).__name__}: {exc}"
            else:
                result["methods"].update(pv["rows"])
                result["planar_vo_end_to_end"] = pv["end_to_end"]
                if not keep:
                    result["planar_vo_end_to_end"].pop("run_dir")

        # One pass for all peers: each frame is decoded once and handed to each in turn.
        trackers = [PeerTracker(make_method(m, intr, options)) for m in peers]
        if peers:
            with open_input(log_path, config) as log:
                c = config.input
                try:
                    n_log = log.summary().frame_count
                    n_total = n_log if frames is None else min(frames, n_log)
                except Exception:  # noqa: BLE001 - only for the progress line
                    n_total = None
                bar = Progress(n_total, label=f"{log_path.name}: peers, frames", enabled=progress)
                t_pass = time.perf_counter()
                n, size = 0, None
                for frame in log.frames(start=c.start, stop=c.stop, stride=c.stride):
                    size = frame.depth.shape[::-1]
                    for t in trackers:
                        t.add(frame)
                    n += 1
                    bar.update(n)
                t_pass = time.perf_counter() - t_pass
                bar.close(n)
            own = sum(t.run.time_s for t in trackers)
            result["frames"] = n
            result["image_size"] = list(size) if size else None
            result["peer_pass"] = {"wall_time_s": t_pass,
                                   "decode_ms_per_frame": 1000.0 * (t_pass - own) / n if n else math.nan}

        for t in trackers:
            r = t.run
            stamps, poses = r.arrays()
            result["methods"][r.name] = {
                "label": r.label, "frames": r.frames, "failures": len(r.failures),
                "failed_frames": {str(k): v for k, v in r.reasons.items()},
                "ms_per_frame": r.ms_per_frame, "errors": _errors(stamps, poses, gt),
                "settings": t.method.settings(),
            }
            if keep:
                traj = Trajectory(stamps, _align_to_gt(poses, stamps, gt))
                write_tum_trajectory(base / f"{r.name}.tum", traj,
                                     header=f"{r.label} on {log_path.name} (planar-vo bench peers)")
    finally:
        if not keep:
            import shutil

            shutil.rmtree(base, ignore_errors=True)
    result["ratios"] = _ratios(result)
    return result


def _ratios(result: dict) -> dict:
    m = result["methods"]
    out: dict = {}
    e2e = result.get("planar_vo_end_to_end")
    if e2e and e2e.get("fps") and TENSOR in m and m[TENSOR]["ms_per_frame"] > 0:
        tensor_fps = 1000.0 / m[TENSOR]["ms_per_frame"]
        out["speedup_vs_open3d_tensor"] = e2e["fps"] / tensor_fps
        out["open3d_tensor_fps"] = tensor_fps
    ours = m.get(f"{PLANAR_VO}_smoothed", {}).get("errors", {}).get("endpoint_drift_pct")
    peer_drift = {k: v["errors"].get("endpoint_drift_pct") for k, v in m.items()
                  if not k.startswith(PLANAR_VO) and v.get("errors")}
    peer_drift = {k: v for k, v in peer_drift.items() if v is not None and math.isfinite(v)}
    if ours is not None and math.isfinite(ours) and peer_drift:
        best = min(peer_drift, key=peer_drift.get)
        out["best_peer"] = best
        out["drift_ratio_best_peer_over_planar_vo"] = peer_drift[best] / ours if ours > 0 else math.inf
    return out


# ------------------------------------------------------------------------ output

def _cell(v, fmt: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return fmt.format(v)


def format_table(result: dict) -> str:
    """The per-log table of :func:`compare_log`'s result."""
    head = f"{Path(result['log']).name}"
    n = result.get("frames")
    if n is None:
        n = next((r["frames"] for r in result["methods"].values()), None)
    if n is not None:
        size = result.get("image_size") or [result["intrinsics"]["width"], result["intrinsics"]["height"]]
        head += f": {n} frames {size[0]}x{size[1]}"
    g = result.get("ground_truth")
    rows = next(iter(result["methods"].values()), {}).get("errors", {}) if result["methods"] else {}
    if g:
        head += f", ground truth {g['poses']} poses"
        if rows.get("path_length_m") is not None:
            head += f", path {rows['path_length_m']:.2f} m"
    else:
        head += ", no ground truth (timings and failures only)"
    if result.get("peer_pass"):
        head += f"; decoding {result['peer_pass']['decode_ms_per_frame']:.1f} ms/frame"
    cols = f"{'method':<28}{'ATE RMSE [m]':>14}{'drift [%]':>11}{'yaw err [deg]':>15}{'ms/frame':>10}{'failures':>10}"
    lines = [head, cols, "-" * len(cols)]
    for name, r in result["methods"].items():
        e = r.get("errors", {})
        lines.append(f"{r['label']:<28}{_cell(e.get('ate_rmse_m'), '{:.4f}'):>14}"
                     f"{_cell(e.get('endpoint_drift_pct'), '{:.2f}'):>11}"
                     f"{_cell(e.get('final_yaw_error_deg'), '{:+.2f}'):>15}"
                     f"{_cell(r.get('ms_per_frame'), '{:.1f}'):>10}{r['failures']:>10d}")
    if result.get("planar_vo_error"):
        lines.append(f"planar-vo FAILED on this log: {result['planar_vo_error']}")
    e2e = result.get("planar_vo_end_to_end")
    if e2e:
        lines.append(f"planar-vo end to end (decoding + estimation + optimisation + writing TUM): "
                     f"{_cell(e2e.get('fps'), '{:.1f}')} fps; its decoding "
                     f"{_cell(e2e.get('decode_ms_per_frame'), '{:.1f}')} ms/frame")
    q = result.get("ratios", {})
    if "speedup_vs_open3d_tensor" in q:
        s = q["speedup_vs_open3d_tensor"]
        lines.append(f"speed: planar-vo end-to-end fps / Open3D tensor fps ({q['open3d_tensor_fps']:.1f}, "
                     f"processing only) = {s:.2f}x (target >= {TARGET_SPEEDUP:g}x: "
                     f"{'met' if s >= TARGET_SPEEDUP else 'NOT met'})")
    if "drift_ratio_best_peer_over_planar_vo" in q:
        d = q["drift_ratio_best_peer_over_planar_vo"]
        label = result["methods"][q["best_peer"]]["label"]
        lines.append(f"drift: best peer ({label}) / planar-vo smoothed = {d:.2f}x "
                     f"(target >= {TARGET_DRIFT_RATIO:g}x: {'met' if d >= TARGET_DRIFT_RATIO else 'NOT met'})")
    return "\n".join(lines)


def environment() -> dict:
    import cv2
    import open3d as o3d

    return {"open3d": o3d.__version__, "opencv": cv2.__version__, "numpy": np.__version__,
            "cpu_count": os.cpu_count(), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
            "opencv_threads": cv2.getNumThreads()}


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def main(args: argparse.Namespace) -> int:
    from planar_vo.io.atomic import write_text_atomic

    logs = [Path(p) for p in args.logs]
    gts = args.gt or []
    if gts and len(gts) != len(logs):
        raise InputError(f"--gt given {len(gts)} times for {len(logs)} logs; give it once per LOG, "
                         "in the same order (or leave it out to use each log's own ground truth)")
    if args.frames is not None and args.frames < 2:
        raise InputError(f"--frames must be >= 2, got {args.frames}")
    if not (args.depth_max > 0):
        raise InputError(f"--depth-max must be > 0 m, got {args.depth_max}")
    for p in logs:
        if not p.exists():
            raise InputError(f"{p}: no such log (pass MCAP files or TUM RGB-D folders)")
    if args.json and not Path(args.json).parent.is_dir():
        raise InputError(f"--json {args.json}: folder {Path(args.json).parent} does not exist")
    methods = [m for m in ALL_METHODS if m in args.methods]

    env = environment()
    print(f"planar-vo bench peers: Open3D {env['open3d']}, OpenCV {env['opencv']}, "
          f"{env['cpu_count']} CPUs, OMP_NUM_THREADS={env['OMP_NUM_THREADS'] or 'unset'}, "
          f"OpenCV threads {env['opencv_threads']}; peers: depth <= {args.depth_max:g} m, "
          f"Open3D init {args.init}")
    results = []
    for i, log in enumerate(logs):
        res = compare_log(log, gt_arg=gts[i] if gts else None, frames=args.frames, methods=methods,
                          init=args.init, depth_max_m=args.depth_max, config=args.config,
                          out_dir=args.out)
        results.append(res)
        print()
        print(format_table(res), flush=True)
    if args.json:
        write_text_atomic(args.json, json.dumps(_jsonable({"environment": env, "logs": results}), indent=2) + "\n")
        print(f"\nwrote {args.json}")
    return 1 if any(r.get("planar_vo_error") for r in results) else 0
