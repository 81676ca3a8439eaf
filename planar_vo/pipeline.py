"""io -> frontend -> backend -> io: the ``planar-vo run`` pipeline.

``run(log_path, out_dir, config)`` streams the log frame by frame through the
front-end (:class:`planar_vo.frontend.PlanarOdometry`) and the back-end
(:class:`planar_vo.backend.PlanarPoseGraph`, or iSAM2 with ``solver: online``), then
writes the run folder:

``raw.tum`` / ``smoothed.tum``  camera optical-frame poses ``T_odom_cam``, one line per
                                colour frame with a pose, stamped with its colour stamp;
``poses.mcap``                  both trajectories and the frame tree (Foxglove schemas);
``report.json``                 counts, statuses, wall and CPU time per stage, frames per second;
``config.yaml``                 the resolved configuration;
``trajectory.png``              raw, smoothed and ground truth (when known), from above.

An interrupt (Ctrl-C) or a truncated log stops the loop; what was computed so far is
still written and the returned report says ``partial``.
"""
from __future__ import annotations

import contextlib
import ctypes
import json
import math
import sys
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
from planar_vo.wheel_fusion import motion_with_wheel_odometry, wheel_steps_for_run, write_wheel_outputs


@dataclass
class RunResult:
    out_dir: Path
    report: dict
    partial: bool = False
    stop_reason: str | None = None
    files: dict = field(default_factory=dict)




#: ``(set, get)`` thread-count entry points of the OpenBLAS builds found in the wild: the
#: plain library (OpenCV's wheels) and the symbol-prefixed one of numpy/scipy wheels.
_OPENBLAS_SYMBOLS = (("openblas_set_num_threads", "openblas_get_num_threads"),
                     ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
                     ("openblas_set_num_threads64_", "openblas_get_num_threads64_"))


def _loaded_openblas() -> list[tuple]:
    """``(set, get)`` ctypes functions of every OpenBLAS loaded in this process (Linux)."""
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.rsplit("/", 1)[-1].lower()})
    except OSError:  # not Linux: leave the libraries as they are
        return []
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)  # already mapped: this only takes a handle
        except OSError:
            continue
        for set_name, get_name in _OPENBLAS_SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                setter.argtypes, setter.restype, getter.restype = [ctypes.c_int], None, ctypes.c_int
                found.append((setter, getter))
                break
    return found


@contextlib.contextmanager
def blas_threads(n: int = 1):
    """Run the body with at most ``n`` OpenBLAS threads, restoring the previous counts.

    The front-end's BLAS calls are all small (dot products over ~10^4 samples, 3x3
    solves): threads cannot pay for their start-up there, and idle OpenBLAS workers
    spin, competing with the decoding thread for the cores. On a loaded 2-core machine
    the default (one BLAS thread per core) made the plane detector ~10x slower.
    """
    if "numpy" not in sys.modules:
        import numpy  # noqa: F401 - load its BLAS so that it can be limited
    libs = _loaded_openblas()
    before = [get() for _, get in libs]
    for set_, _ in libs:
        set_(n)
    try:
        yield
    finally:
        for (set_, _), k in zip(libs, before):
            set_(k)


def open_input(log_path: str | Path, config: RunConfig):
    """Open an MCAP log or TUM folder with the topic/intrinsics overrides of ``config``."""
    from planar_vo.io import open_log
    from planar_vo.io.types import CameraIntrinsics

    c = config.input
    log = open_log(log_path, color_topic=c.color_topic, depth_topic=c.depth_topic,
                   info_topic=c.info_topic, sync_tolerance=c.sync_tolerance_s)
    if c.fx is not None:
        try:
            w, h = log.image_size  # the override is for the images as they are
            log.set_intrinsics(CameraIntrinsics(w, h, c.fx, c.fy, c.cx, c.cy))
        except BaseException:
            log.close()
            raise
    return log


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
    """Run the whole job on one log; see the module docstring for the outputs.

    Threads: the main thread runs the front-end and back-end; a reader thread decodes the
    next frames and tracks their corners (:meth:`PlanarOdometry.track`); a third loads
    the output stage's modules meanwhile. The log is read once: the summary in the report
    comes from the same pass (``summary()`` after a complete ``frames()`` pass). The
    kernels underneath (OpenCV, OpenBLAS) get one thread each for the run: the parallelism
    is the pipeline's, and on 2 cores more threads only compete with it (the previous
    settings are restored afterwards). Results do not depend on any of this.
    """
    import cv2

    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with blas_threads(1):
            return _run(log_path, out_dir, config or RunConfig(), progress=progress, gt_path=gt_path)
    finally:
        cv2.setNumThreads(cv_threads)


class _TrackAhead:
    """Frames of ``frames``, each passed through ``odometry.track`` first; counts the time
    that took (wall and CPU of the calling thread)."""

    def __init__(self, frames, odometry):
        self._frames = frames
        self._odometry = odometry
        self.wall_s = 0.0
        self.cpu_s = 0.0

    def __iter__(self):
        try:
            for frame in self._frames:
                t0, c0 = time.perf_counter(), time.thread_time()
                self._odometry.track(frame)
                self.wall_s += time.perf_counter() - t0
                self.cpu_s += time.thread_time() - c0
                yield frame
        finally:
            close = getattr(self._frames, "close", None)
            if close is not None:
                close()


def _prepare_outputs(config: RunConfig) -> float:
    """Import the output stage's modules (matplotlib alone takes ~0.5 s) while the frames
    are processed, so that the end of the run does not wait for them; returns the CPU
    seconds this took."""
    c0 = time.thread_time()
    try:
        if config.output.poses_mcap:
            import foxglove_schemas_protobuf.FrameTransforms_pb2  # noqa: F401
            import foxglove_schemas_protobuf.PoseInFrame_pb2  # noqa: F401
            import foxglove_schemas_protobuf.PosesInFrame_pb2  # noqa: F401
            import mcap_protobuf.writer  # noqa: F401

            import planar_vo.io.trajectory  # noqa: F401
        if config.output.plot:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot  # noqa: F401

            import planar_vo.plotting  # noqa: F401
    except Exception:  # noqa: BLE001 - only a head start; the output stage imports them itself
        pass
    return time.thread_time() - c0


def _total_frames(n_log: int | None, c) -> int | None:
    """Frames the run will process of a log of ``n_log`` pairs (for the progress bar)."""
    if n_log is None:
        return None
    stop = n_log if c.stop is None else min(c.stop, n_log)
    return max(0, math.ceil((stop - c.start) / c.stride))


def _run(log_path, out_dir, config: RunConfig, *, progress, gt_path) -> RunResult:
    from concurrent.futures import ThreadPoolExecutor

    from planar_vo.backend.graph import IncrementalPlanarPoseGraph, PlanarPoseGraph
    from planar_vo.frontend.odometry import PlanarOdometry

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    timings = Counter()
    cpu = Counter()  # CPU seconds per stage (thread time), comparable on a loaded machine

    side = ThreadPoolExecutor(1, thread_name_prefix="planar-vo-outputs")
    prepared = side.submit(_prepare_outputs, config)
    side.shutdown(wait=False)
    with open_input(log_path, config) as log:
        intr = log.intrinsics
        mount = resolve_mount(log.mount, config)
        odo = PlanarOdometry(intr, mount, config.frontend)
        graph = IncrementalPlanarPoseGraph(config.backend) if config.solver == "online" else PlanarPoseGraph(config.backend)
        wheel = wheel_steps_for_run(log, config)
        c = config.input
        bar = Progress(_total_frames(log.expected_frames(), c), enabled=progress)
        stamps: list[float] = []
        statuses = Counter()
        frame_infos = []
        steps: list[list] = []
        stop_reason = None
        partial = False
        # The reader thread decodes each frame and tracks its corners (PlanarOdometry.track),
        # both GIL-free for the most part, while the main thread works on earlier frames.
        ahead = _TrackAhead(log.frames(start=c.start, stop=c.stop, stride=c.stride), odo)
        reader = Prefetcher(ahead, depth=4)
        t_wait = time.perf_counter()
        try:
            with reader:
                for frame in reader:
                    t0, c0 = time.perf_counter(), time.thread_time()
                    timings["read_wait"] += t0 - t_wait
                    result = odo.process(frame)
                    t1, c1 = time.perf_counter(), time.thread_time()
                    timings["frontend"] += t1 - t0
                    cpu["frontend"] += c1 - c0
                    for k, v in result.timings.items():
                        timings[f"frontend.{k}"] += v
                    graph.add_frame(result, odometry=wheel.step(frame.stamp, result) if wheel else None)
                    t_wait = time.perf_counter()
                    timings["backend"] += t_wait - t1
                    cpu["backend"] += time.thread_time() - c1
                    stamps.append(frame.stamp)
                    statuses[result.step.status if result.step is not None else "first"] += 1
                    frame_infos.append(_frame_summary(result))
                    if result.step is not None:
                        steps.append(_step_row(result))
                    bar.update(len(stamps), **{k: v for k, v in statuses.items() if k != "first"})
        except KeyboardInterrupt:
            partial, stop_reason = True, "interrupted by the user (Ctrl-C)"
        except PartialResult as exc:
            partial, stop_reason = True, str(exc)
        timings["read_decode_background"] += reader.busy_s - ahead.wall_s
        cpu["read_decode_background"] += reader.busy_cpu_s - ahead.cpu_s
        timings["track_background"] += ahead.wall_s
        cpu["track_background"] += ahead.cpu_s
        bar.close(len(stamps), **{k: v for k, v in statuses.items() if k != "first"})
        stats = dict(log.stats)
        # After a pass over the whole log this reads nothing: the pass recorded what it needs.
        t0, c0 = time.perf_counter(), time.thread_time()
        log_summary = _safe_summary(log)
        timings["summary"] += time.perf_counter() - t0
        cpu["summary"] += time.thread_time() - c0
        gt = log.ground_truth

    if not stamps:
        raise InputError(f"{log_path}: no colour/depth frame pairs could be read"
                         + (f" ({stop_reason})" if stop_reason else "")
                         + "; check the topics with 'planar-vo info'")

    t0, c0 = time.perf_counter(), time.thread_time()
    raw = graph.raw_poses()
    smoothed = graph.estimate() if config.solver == "online" else graph.optimize()
    timings["optimize"] += time.perf_counter() - t0
    cpu["optimize"] += time.thread_time() - c0

    if gt_path is not None:
        from planar_vo.io.trajectory import read_tum_trajectory
        gt = read_tum_trajectory(gt_path)

    T_base_cam = np.asarray(odo.mount.T_base_cam, dtype=float)
    cpu["outputs_import_background"] = prepared.result()
    t0, c0 = time.perf_counter(), time.thread_time()
    files = _write_outputs(out, config, stamps, raw, smoothed, T_base_cam, gt)
    files["steps"] = _write_steps(out / "steps.csv", steps)
    wheel_section, wheel_files = write_wheel_outputs(out, wheel, stamps, T_base_cam, getattr(graph, "stats", {}))
    files.update(wheel_files)
    timings["write"] += time.perf_counter() - t0
    cpu["write"] += time.thread_time() - c0
    wall = time.perf_counter() - t_start
    cpu["process"] = time.process_time() - cpu_start  # all threads, OpenCV's workers included

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
            "partial": statuses.get("partial", 0),
            "bridged": statuses.get("bridged", 0),
            "failed": len(stats.get("corrupt", [])),
            "failed_frames": [{"frame": str(k), "reason": str(r)} for k, r in stats.get("corrupt", [])],
        },
        "motion": motion_with_wheel_odometry(motion_report(statuses), wheel_section),
        "mount": _mount_report(odo.mount),
        "planarity": _planarity_report(frame_infos, levelled=_is_levelled(mount, frame_infos)),
        "backend": _jsonable(getattr(graph, "stats", {})),
        "wheel_odometry": _jsonable(wheel_section),
        "manhattan_frames": [list(map(_jsonable, m)) for m in graph.manhattan_frames()],
        "timings_s": {k: round(v, 4) for k, v in sorted(timings.items())},
        "timings_ms_per_frame": {k: round(1000 * v / n, 3) for k, v in sorted(timings.items())},
        "cpu_ms_per_frame": {k: round(1000 * v / n, 3) for k, v in sorted(cpu.items())},
        "wall_time_s": round(wall, 3),
        "fps": round(n / wall, 2) if wall > 0 else None,
        "fps_excluding_writing": round(n / max(wall - timings["write"], 1e-9), 2),
        "solver": config.solver,
    }
    _atomic_text(out / "report.json", json.dumps(report, indent=2) + "\n")
    files["report"] = str(out / "report.json")
    return RunResult(out, report, partial, stop_reason, files)


#: Below this share of steps with a measured translation the run is not a trajectory.
MIN_MEASURED_FRACTION = 0.5
#: Below this share the run is degraded (a warning, not a failure).
GOOD_MEASURED_FRACTION = 0.9


def motion_report(statuses: Counter) -> dict:
    """How much of the motion was measured: steps whose translation came from an
    estimator (direction-plus-point, 2-point), steps with only the yaw (partial), steps
    with neither (bridged), and a verdict a user can act on."""
    n = sum(v for k, v in statuses.items() if k != "first")
    full = statuses.get("dpp", 0) + statuses.get("2pt", 0)
    yaw = full + statuses.get("partial", 0)
    rep = {"steps": n, "translation_measured": full, "yaw_measured": yaw}
    frac = full / n if n else 1.0
    if frac >= GOOD_MEASURED_FRACTION:
        rep["verdict"] = "estimated"
        rep["message"] = f"translation measured in {full} of {n} steps"
    else:
        rep["verdict"] = "not_estimated" if frac < MIN_MEASURED_FRACTION else "degraded"
        rep["message"] = (f"translation measured in only {full} of {n} steps ({100 * frac:.0f} %; "
                          f"yaw in {yaw}): the rest is a constant-velocity guess"
                          + (", so the trajectory is NOT an estimate of the motion (too little texture or "
                             "depth?)" if rep["verdict"] == "not_estimated" else ""))
    return rep


STEPS_HEADER = "index,stamp,status,x,y,theta,sigma_x,sigma_y,sigma_theta,inliers"


def _step_row(result) -> list:
    """One ``steps.csv`` row: the front-end's base_link step ``T_base_prev_base_curr``
    (x, y m; theta rad) into this frame and the sigmas of its stated covariance."""
    st = result.step
    with np.errstate(all="ignore"):
        sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(st.information)), 0.0))
    return [result.index, result.stamp, st.status, *map(float, st.pose), *map(float, sd), int(st.inliers)]


def _write_steps(path: Path, rows: list[list]) -> str:
    lines = [STEPS_HEADER]
    for r in rows:
        lines.append(f"{r[0]},{r[1]:.6f},{r[2]}," + ",".join(f"{v:.9g}" for v in r[3:9]) + f",{r[9]}")
    _atomic_text(path, "\n".join(lines) + "\n")
    return str(path)


def _frame_summary(result) -> dict:
    info = result.info or {}
    lev = info.get("levelling") or {}
    oop = info.get("out_of_plane")
    return {
        "floor_normal_cam": lev.get("floor_normal_cam"),
        "camera_height_m": lev.get("camera_height_m"),
        "motion_6dof": (oop["R"], oop["t"]) if oop else None,
    }


#: Beyond these the motion is not planar: camera height (m) and tilt (deg) ranges, p5-p95.
PLANAR_HEIGHT_RANGE_M = 0.05
PLANAR_TILT_RANGE_DEG = 3.0


def _spread(values) -> float:
    v = np.asarray(values, dtype=float)
    return float(np.percentile(v, 95) - np.percentile(v, 5)) if len(v) else float("nan")


MOTION_WINDOW = 100


def _chain(steps) -> tuple[np.ndarray, np.ndarray]:
    """Camera positions (n+1, 3) and y axes (n+1, 3) in the first levelled frame from steps
    ``(R, t)`` with ``X2 = R X1 + t`` (None: no fit, taken as no motion)."""
    T = np.eye(4)
    pos, yax = [T[:3, 3].copy()], [T[:3, 1].copy()]
    for m in steps:
        if m is not None:
            T21 = np.eye(4)
            T21[:3, :3], T21[:3, 3] = np.asarray(m[0]), np.asarray(m[1])
            T = T @ np.linalg.inv(T21)
        pos.append(T[:3, 3].copy())
        yax.append(T[:3, 1].copy())
    return np.array(pos), np.array(yax)


def _planarity_report(frame_infos: list[dict], levelled: bool) -> dict:
    """Is the motion planar? Two independent pieces of evidence, both from the data.

    * floor: on a planar robot the floor normal in the camera frame and the camera height
      stay fixed (handheld cameras change both, or show no floor at all);
    * motion (decides when the floor was not seen): the per-step 6-DoF fits
      (:mod:`planar_vo.frontend.planarity`) chained over windows of ``MOTION_WINDOW`` steps in
      the levelled frame must keep their height and vertical axis. Without a mount or a floor
      the estimator assumes a level camera, and so does this test.
    """
    n = len(frame_infos)
    rep: dict = {"frames": n}
    verdicts = []
    normals = [np.asarray(f["floor_normal_cam"], float) for f in frame_infos if f.get("floor_normal_cam") is not None]
    heights = [float(f["camera_height_m"]) for f in frame_infos if f.get("camera_height_m") is not None]
    rep["floor_seen_frames"] = len(normals)
    if len(normals) >= max(3, 0.2 * n):
        N = np.stack(normals)
        mean = N.mean(0) / np.linalg.norm(N.mean(0))
        tilt = _spread(np.degrees(np.arccos(np.clip(N @ mean, -1, 1))))
        h = _spread(heights)
        rep["floor"] = {"tilt_range_deg": round(tilt, 3), "height_range_m": round(h, 4)}
        verdicts.append(tilt < PLANAR_TILT_RANGE_DEG and h < PLANAR_HEIGHT_RANGE_M)

    # Chained 6-DoF steps random-walk (a few cm and degrees over hundreds of frames), so
    # they are judged over windows of at most MOTION_WINDOW steps, and only when the floor,
    # far more precise, was not seen.
    steps = [f.get("motion_6dof") for f in frame_infos[1:]]
    fitted = sum(m is not None for m in steps)
    if fitted >= max(3, 0.5 * len(steps)):
        heights, tilts = [], []
        w = MOTION_WINDOW
        for a in range(0, max(1, len(steps) - w // 2), w // 2):
            P, Y = _chain(steps[a:a + w])
            heights.append(_spread(P[:, 1]))
            tilts.append(_spread(np.degrees(np.arccos(np.clip(Y[:, 1], -1, 1)))))
        height, tilt = max(heights), max(tilts)
        rep["motion"] = {"steps_fitted": fitted, "window_steps": w, "height_range_m": round(height, 4),
                         "tilt_range_deg": round(tilt, 3), "gravity": "measured" if levelled else "assumed"}
        if not verdicts:
            verdicts.append(tilt < PLANAR_TILT_RANGE_DEG and height < PLANAR_HEIGHT_RANGE_M)

    if not verdicts:
        rep["verdict"] = "unverified"
        rep["message"] = (f"the floor was seen in {len(normals)} of {n} frames and the motion could not be "
                          "fitted: planar motion is unverified and the planar model may not hold")
    elif all(verdicts):
        rep["verdict"] = "planar"
        rep["message"] = "camera height and tilt stay constant: consistent with planar motion"
    else:
        worst = rep.get("floor") or rep.get("motion")
        rep["verdict"] = "not_planar"
        rep["message"] = (f"the camera's height varies by {worst['height_range_m']:.2f} m and its tilt by "
                          f"{worst['tilt_range_deg']:.1f} deg: the motion is NOT planar (handheld?), so the "
                          "planar estimates are approximations"
                          + ("" if levelled else "; no floor and no mount: the camera was assumed level, "
                             "give --pitch-deg/--roll-deg if it is a tilted robot camera"))
    return rep


def _is_levelled(mount, frame_infos) -> bool:
    """True when gravity is known: a mount tilt was given, or the floor was seen."""
    if mount is not None and np.all(np.isfinite(np.asarray(mount.T_base_cam)[:3, :3])):
        return True
    return any(f.get("floor_normal_cam") is not None for f in frame_infos)


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
