"""io -> frontend -> backend -> io: the ``planar-vo run`` pipeline.

``run(log_path, out_dir, config)`` streams the log frame by frame through the
front-end (:class:`planar_vo.frontend.PlanarOdometry`) and the back-end
(:class:`planar_vo.backend.PlanarPoseGraph`, or iSAM2 with ``solver: online``), then
writes the run folder:

``raw.tum`` / ``smoothed.tum``  camera optical-frame poses ``T_odom_cam``, one line per
                                colour frame with a pose, stamped with its colour stamp;
``poses.mcap``                  both trajectories and the frame tree (Foxglove schemas);
``report.json``                 counts, statuses, timings per stage, frames per second;
``config.yaml``                 the resolved configuration;
``trajectory.png``              raw, smoothed and ground truth (when known), from above.

An interrupt (Ctrl-C) or a truncated log stops the loop; what was computed so far is
still written and the returned report says ``partial``.
"""
from __future__ import annotations

import json
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from planar_vo.config import RunConfig, dump_config
from planar_vo.errors import InputError, PartialResult
from planar_vo.geometry import base_poses_to_cam_matrices, mount_angles, mount_rotation, se2_to_matrix
from planar_vo.prefetch import Prefetcher
from planar_vo.progress import Progress


@dataclass
class RunResult:
    out_dir: Path
    report: dict
    partial: bool = False
    stop_reason: str | None = None
    files: dict = field(default_factory=dict)




def open_input(log_path: str | Path, config: RunConfig):
    """Open an MCAP log or TUM folder with the topic/intrinsics overrides of ``config``."""
    from planar_vo.io import open_log
    from planar_vo.io.types import CameraIntrinsics

    c = config.input
    intr = None
    if c.fx is not None:
        # Width/height are filled from the first image by the reader when 0.
        intr = CameraIntrinsics(0, 0, c.fx, c.fy, c.cx, c.cy)
    return open_log(log_path, color_topic=c.color_topic, depth_topic=c.depth_topic,
                    info_topic=c.info_topic, intrinsics=intr, sync_tolerance=c.sync_tolerance_s)


def resolve_mount(log_mount, config: RunConfig):
    """The mount to use: config tilt (with the log's or configured height) > log's /tf_static > None."""
    from planar_vo.io.types import Mount

    m = config.mount
    if m.pitch_deg is None:
        if log_mount is not None and m.height_m is not None:
            T = np.array(log_mount.T_base_cam, dtype=float)
            T[2, 3] = m.height_m
            return Mount(T, log_mount.parent_frame, log_mount.child_frame)
        return log_mount
    T = np.eye(4)
    yaw = 0.0
    if log_mount is not None:
        T[:3, 3] = np.asarray(log_mount.T_base_cam)[:3, 3]
        yaw = mount_angles(np.asarray(log_mount.T_base_cam)[:3, :3])[2]
    T[:3, :3] = mount_rotation(math.radians(m.pitch_deg), math.radians(m.roll_deg), yaw)
    if m.height_m is not None:
        T[2, 3] = m.height_m
    elif log_mount is None:
        T[2, 3] = float("nan")  # unknown: the front-end measures it from the floor
    return Mount(T)


def _trajectory(stamps, poses_base, T_base_cam, frame_id="odom"):
    from planar_vo.io.types import Trajectory

    return Trajectory(np.asarray(stamps), base_poses_to_cam_matrices(poses_base, T_base_cam),
                      frame_id=frame_id, child_frame_id="camera_optical_frame")


def run(log_path: str | Path, out_dir: str | Path, config: RunConfig | None = None, *,
        progress: bool = True, gt_path: str | Path | None = None) -> RunResult:
    """Run the whole job on one log; see the module docstring for the outputs."""
    from planar_vo.backend.graph import IncrementalPlanarPoseGraph, PlanarPoseGraph
    from planar_vo.frontend.odometry import PlanarOdometry

    config = config or RunConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    timings = Counter()

    with open_input(log_path, config) as log:
        intr = log.intrinsics
        mount = resolve_mount(log.mount, config)
        odo = PlanarOdometry(intr, mount, config.frontend)
        graph = IncrementalPlanarPoseGraph(config.backend) if config.solver == "online" else PlanarPoseGraph(config.backend)
        c = config.input
        total = None
        try:
            n_log = log.summary().frame_count
            stop = n_log if c.stop is None else min(c.stop, n_log)
            total = max(0, math.ceil((stop - c.start) / c.stride))
        except Exception:  # noqa: BLE001 - the total is only for the progress bar
            total = None
        bar = Progress(total, enabled=progress)
        stamps: list[float] = []
        statuses = Counter()
        frame_infos = []
        stop_reason = None
        partial = False
        reader = Prefetcher(log.frames(start=c.start, stop=c.stop, stride=c.stride), depth=4)
        t_wait = time.perf_counter()
        try:
            with reader:
                for frame in reader:
                    t0 = time.perf_counter()
                    timings["read_wait"] += t0 - t_wait
                    result = odo.process(frame)
                    t1 = time.perf_counter()
                    timings["frontend"] += t1 - t0
                    for k, v in result.timings.items():
                        timings[f"frontend.{k}"] += v
                    graph.add_frame(result)
                    t_wait = time.perf_counter()
                    timings["backend"] += t_wait - t1
                    stamps.append(frame.stamp)
                    statuses[result.step.status if result.step is not None else "first"] += 1
                    frame_infos.append(_frame_summary(result))
                    bar.update(len(stamps), **{k: v for k, v in statuses.items() if k != "first"})
        except KeyboardInterrupt:
            partial, stop_reason = True, "interrupted by the user (Ctrl-C)"
        except PartialResult as exc:
            partial, stop_reason = True, str(exc)
        timings["read_decode_background"] += reader.busy_s
        bar.close(len(stamps), **{k: v for k, v in statuses.items() if k != "first"})
        stats = dict(log.stats)
        gt = log.ground_truth
        log_summary = _safe_summary(log)

    if not stamps:
        raise InputError(f"{log_path}: no colour/depth frame pairs could be read"
                         + (f" ({stop_reason})" if stop_reason else "")
                         + "; check the topics with 'planar-vo info'")

    t0 = time.perf_counter()
    raw = graph.raw_poses()
    smoothed = graph.estimate() if config.solver == "online" else graph.optimize()
    timings["optimize"] += time.perf_counter() - t0

    if gt_path is not None:
        from planar_vo.io.trajectory import read_tum_trajectory
        gt = read_tum_trajectory(gt_path)

    T_base_cam = np.asarray(odo.mount.T_base_cam, dtype=float)
    t0 = time.perf_counter()
    files = _write_outputs(out, config, stamps, raw, smoothed, T_base_cam, gt)
    timings["write"] += time.perf_counter() - t0
    wall = time.perf_counter() - t_start

    n = len(stamps)
    report = {
        "log": str(log_path),
        "input": log_summary,
        "partial": partial,
        "stop_reason": stop_reason,
        "frames": {
            "read": n + len(stats.get("corrupt", [])),
            "paired": stats.get("paired"),
            "unpaired_color": stats.get("unpaired_color"),
            "unpaired_depth": stats.get("unpaired_depth"),
            "with_pose": n,
            "estimated_dpp": statuses.get("dpp", 0),
            "estimated_2pt": statuses.get("2pt", 0),
            "bridged": statuses.get("bridged", 0),
            "failed": len(stats.get("corrupt", [])),
            "failed_frames": [{"frame": str(k), "reason": str(r)} for k, r in stats.get("corrupt", [])],
        },
        "mount": _mount_report(odo.mount),
        "planarity": _planarity_report(frame_infos),
        "backend": _jsonable(getattr(graph, "stats", {})),
        "manhattan_frames": [list(map(_jsonable, m)) for m in graph.manhattan_frames()],
        "timings_s": {k: round(v, 4) for k, v in sorted(timings.items())},
        "timings_ms_per_frame": {k: round(1000 * v / n, 3) for k, v in sorted(timings.items())},
        "wall_time_s": round(wall, 3),
        "fps": round(n / wall, 2) if wall > 0 else None,
        "fps_excluding_writing": round(n / max(wall - timings["write"], 1e-9), 2),
        "solver": config.solver,
    }
    _atomic_text(out / "report.json", json.dumps(report, indent=2) + "\n")
    files["report"] = str(out / "report.json")
    return RunResult(out, report, partial, stop_reason, files)


def _frame_summary(result) -> dict:
    info = result.info or {}
    lev = info.get("levelling") or {}
    return {
        "floor_seen": bool(info.get("floor_seen", lev.get("floor_seen", False))),
        "floor_normal_cam": lev.get("floor_normal_cam"),
        "camera_height_m": lev.get("camera_height_m"),
    }


def _planarity_report(frame_infos: list[dict]) -> dict:
    """Is the motion planar? Judged from the floor the front-end measured in each frame.

    On a planar robot the floor normal in the camera frame and the camera height stay
    fixed; a handheld camera changes both (or shows no floor at all).
    """
    normals = [np.asarray(f["floor_normal_cam"], float) for f in frame_infos if f.get("floor_normal_cam") is not None]
    heights = [float(f["camera_height_m"]) for f in frame_infos if f.get("camera_height_m") is not None]
    n = len(frame_infos)
    seen = len(normals)
    rep = {"frames": n, "floor_seen_frames": seen}
    if seen < max(3, 0.2 * n):
        rep.update(verdict="unverified",
                   message=f"the floor was seen in {seen} of {n} frames: planar motion could not be verified "
                           "and the planar model may not hold")
        return rep
    N = np.stack(normals)
    mean = N.mean(0)
    mean /= np.linalg.norm(mean)
    ang = np.degrees(np.arccos(np.clip(N @ mean, -1, 1)))
    spread = float(np.percentile(ang, 95))
    h_range = float(np.percentile(heights, 95) - np.percentile(heights, 5)) if heights else float("nan")
    rep.update(floor_normal_spread_deg_p95=round(spread, 3), camera_height_range_m_p90=round(h_range, 4))
    planar = spread < 3.0 and (not heights or h_range < 0.05)
    rep["verdict"] = "planar" if planar else "not_planar"
    rep["message"] = ("camera tilt and height stay constant: consistent with planar motion" if planar else
                      f"the camera tilt varies by {spread:.1f} deg and its height by {h_range:.2f} m: "
                      "the motion is NOT planar, so the planar estimates are approximations")
    return rep


def _mount_report(mount) -> dict:
    T = np.asarray(mount.T_base_cam, dtype=float)
    pitch, roll, yaw = mount_angles(T[:3, :3])
    return {"pitch_deg": round(math.degrees(pitch), 4), "roll_deg": round(math.degrees(roll), 4),
            "yaw_deg": round(math.degrees(yaw), 4), "xyz_m": [round(float(v), 4) for v in T[:3, 3]]}


def _safe_summary(log) -> dict:
    try:
        s = log.summary()
    except Exception:  # noqa: BLE001
        return {}
    return _jsonable(getattr(s, "__dict__", {}))


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    if hasattr(obj, "__dict__"):
        return _jsonable(vars(obj))
    return str(obj)


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _write_outputs(out: Path, config: RunConfig, stamps, raw, smoothed, T_base_cam, gt) -> dict:
    from planar_vo.io.trajectory import write_poses_mcap, write_tum_trajectory

    raw_traj = _trajectory(stamps, raw, T_base_cam)
    smooth_traj = _trajectory(stamps, smoothed, T_base_cam)
    files = {}
    write_tum_trajectory(out / "raw.tum", raw_traj)
    write_tum_trajectory(out / "smoothed.tum", smooth_traj)
    files["raw"], files["smoothed"] = str(out / "raw.tum"), str(out / "smoothed.tum")
    _atomic_text(out / "config.yaml", dump_config(config))
    files["config"] = str(out / "config.yaml")
    if config.output.poses_mcap:
        transforms = [(s, "odom", "base_link", se2_to_matrix(p)) for s, p in zip(stamps, smoothed)]
        transforms.append((stamps[0], "base_link", "camera_optical_frame", T_base_cam))
        write_poses_mcap(out / "poses.mcap", {"raw": raw_traj, "smoothed": smooth_traj}, transforms=transforms)
        files["poses_mcap"] = str(out / "poses.mcap")
    if config.output.plot:
        from planar_vo.plotting import plot_trajectories

        plot_trajectories(out / "trajectory.png", {"raw": raw_traj, "smoothed": smooth_traj}, gt)
        files["plot"] = str(out / "trajectory.png")
    return files
