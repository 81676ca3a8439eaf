"""io -> frontend -> backend -> io: the ``planar-vo run`` pipeline.

``run(log_path, out_dir, config)`` streams the log frame by frame through the
front-end (:class:`planar_vo.frontend.PlanarOdometry`) and the back-end
(:class:`planar_vo.backend.PlanarPoseGraph`, or iSAM2 with ``solver: online``), then
writes the run folder:

``raw.tum`` / ``smoothed.tum``  camera optical-frame poses ``T_odom_cam``, one line per
                                colour frame with a pose, stamped with its colour stamp;
``poses.mcap``                  both trajectories and the frame tree (ROS 2 messages for ROS logs,
                                Foxglove schemas otherwise: ``output.poses_format``);
``report.json``                 counts, statuses, wall and CPU time per stage, frames per second;
``steps.csv``                   the front-end's step into every frame, with its covariance;
``gap_links.csv``               motions into the frames of a gap of unmeasured steps, measured
                                after it (frontend/gapresection.py), when there were any;
``config.yaml``                 the resolved configuration;
``trajectory.png``              raw, smoothed and ground truth (when known), from above.

An interrupt (Ctrl-C) or a truncated log stops the loop; what was computed so far is
still written and the returned report says ``partial``.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from threadpoolctl import threadpool_limits

from planar_vo.backend.graph import IncrementalPlanarPoseGraph, PlanarPoseGraph
from planar_vo.config import RunConfig, dump_config
from planar_vo.core.errors import InputError, PartialResult
from planar_vo.core.geometry import base_poses_to_cam_matrices, mount_angles, se2_to_matrix
from planar_vo.core.types import Trajectory
from planar_vo.frontend.odometry import PlanarOdometry
from planar_vo.loops import LoopCloser
from planar_vo.io.atomic import write_text_atomic
from planar_vo.io.cliargs import open_log_with_overrides
from planar_vo.io.trajectory import poses_format_for, read_tum_trajectory, write_poses_mcap, write_tum_trajectory
from planar_vo.planarity_verdict import frame_summary, is_levelled, planarity_report
from planar_vo.plotting import PlotProcess
from planar_vo.prefetch import Prefetcher, ProcessPrefetcher, process_prefetch_available
from planar_vo.progress import Progress
from planar_vo.wheel_fusion import (motion_with_wheel_odometry, wheel_steps_for_run, wheel_trajectory,
                                    write_wheel_outputs)


@dataclass
class RunResult:
    out_dir: Path
    report: dict
    partial: bool = False
    stop_reason: str | None = None
    files: dict = field(default_factory=dict)


def open_input(log_path: str | Path, config: RunConfig):
    """Open an MCAP log or TUM folder with the topic/intrinsics overrides of ``config``."""
    c = config.input
    intrinsics = (c.fx, c.fy, c.cx, c.cy) if c.fx is not None else None
    return open_log_with_overrides(log_path, color_topic=c.color_topic, depth_topic=c.depth_topic,
                                   info_topic=c.info_topic, sync_tolerance=c.sync_tolerance_s,
                                   intrinsics=intrinsics)


def _trajectory(stamps, poses_base, T_base_cam, frame_id="odom"):
    return Trajectory(np.asarray(stamps), base_poses_to_cam_matrices(poses_base, T_base_cam),
                      frame_id=frame_id, child_frame_id="camera_optical_frame")


def run(log_path: str | Path, out_dir: str | Path, config: RunConfig | None = None, *,
        progress: bool = True, gt_path: str | Path | None = None) -> RunResult:
    """Run the whole job on one log; see the module docstring for the outputs.

    Threads: the main thread runs the front-end and back-end; a reader decodes the next
    frames and tracks their corners (:meth:`PlanarOdometry.track`), in a forked process
    on Linux (``input.reader``), else in a thread; a side thread loads the output
    stage's modules meanwhile. The log is read once: the summary in the report
    comes from the same pass (``summary()`` after a complete ``frames()`` pass). The
    kernels underneath (OpenCV, BLAS) get one thread each for the run: the parallelism
    is the pipeline's, and on 2 cores more threads only compete with it (the previous
    settings are restored afterwards). Results do not depend on any of this.

    BLAS: the front-end's calls are all small (dot products over ~10^4 samples, 3x3
    solves): threads cannot pay for their start-up there, and idle OpenBLAS workers spin,
    competing with the decoding thread for the cores (on a loaded 2-core machine the
    default made the plane detector ~10x slower). threadpoolctl limits every BLAS loaded
    (numpy's and OpenCV's OpenBLAS).
    """
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
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


def _prepare_outputs(config: RunConfig, poses_format: str, plot: bool = True) -> float:
    """Import the output stage's modules (matplotlib alone takes ~0.5 s; ``plot=False``:
    not matplotlib, a :class:`PlotProcess` draws the plot) while the frames are processed,
    so that the end of the run does not wait for them; returns the CPU seconds this took.
    ``poses_format``: ``poses.mcap``'s schemas (``foxglove`` or ``ros2``): only that
    family's modules (each takes ~0.15-0.3 s of CPU)."""
    c0 = time.thread_time()
    try:
        if config.output.poses_mcap and poses_format == "foxglove":
            import foxglove_schemas_protobuf.FrameTransforms_pb2  # noqa: F401
            import foxglove_schemas_protobuf.PoseInFrame_pb2  # noqa: F401
            import foxglove_schemas_protobuf.PosesInFrame_pb2  # noqa: F401
            import mcap_protobuf.writer  # noqa: F401
        elif config.output.poses_mcap:
            import rosbags.rosbag2  # noqa: F401

            from planar_vo.io import rosmsg
            rosmsg.typestore(rosmsg.CDR)  # ROS 2 poses.mcap: the type store is built once
        if config.output.plot and plot:
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
    """The paper's flow: open the log, level, per frame track -> estimate -> add to the
    graph, solve, report, write."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clock = _Stopwatch()
    prepared = _OutputImports(config)
    try:
        with open_input(log_path, config) as log:
            log.set_color_mode("gray")  # the odometry and loop closure read intensity only
            prepared.for_log(log)
            odometry, graph = _level(log, config)
            wheel = wheel_steps_for_run(log, config)  # the robot's wheel odometry, when the log has it
            closer = _loop_closer(log, odometry, graph, config)
            loop = _process_frames(log, odometry, graph, wheel, closer, config, clock, progress, prepared.start)
            stats = dict(log.stats)  # before the summary, which may read the log again
            with clock.stage("summary"):
                # After a pass over the whole log this reads nothing: the pass recorded what it needs.
                log_summary = _safe_summary(log)
            gt = log.ground_truth
            log_format = getattr(log, "format", "")
        if not loop.stamps:
            raise InputError(f"{log_path}: no colour/depth frame pairs could be read"
                             + (f" ({loop.stop_reason})" if loop.stop_reason else "")
                             + "; check the topics with 'planar-vo info'")
        with clock.stage("optimize"):
            raw, smoothed = _solve(graph, config)
            no_loops = _solve_without_closures(graph, closer)
        if gt_path is not None:
            gt = read_tum_trajectory(gt_path)
        T_base_cam = np.asarray(odometry.mount.T_base_cam, dtype=float)
        clock.cpu["outputs_import_background"] = prepared.result()
        with clock.stage("write"):
            wheel_traj = wheel_trajectory(loop.stamps, wheel.odometry, T_base_cam) if wheel else None
            loops_section = closer.report() if closer is not None else {"enabled": False}
            files = _write_outputs(out, config, loop.stamps, raw, smoothed, T_base_cam, gt, log_format, wheel_traj,
                                   closures=closer.accepted() if closer is not None else [], plotter=prepared.plotter)
            files.update(_write_no_loops(out, loop.stamps, no_loops, T_base_cam))
            files["steps"] = _write_steps(out / "steps.csv", loop.steps)
            if loop.gap_links:
                files["gap_links"] = _write_gap_links(out / "gap_links.csv", loop.gap_links)
            wheel_section, wheel_files = write_wheel_outputs(out, wheel, wheel_traj, getattr(graph, "stats", {}))
            files.update(wheel_files)
        if prepared.plotter is not None:
            clock.cpu["plot_process"] = prepared.plotter.cpu_s
        clock.finish()
        report = _report(log_path, log_summary, stats, loop, odometry, graph, config, clock, wheel_section)
        report["loop_closure"] = _jsonable(loops_section)
        write_text_atomic(out / "report.json", json.dumps(report, indent=2) + "\n")
        files["report"] = str(out / "report.json")
        return RunResult(out, report, loop.partial, loop.stop_reason, files)
    finally:
        prepared.close()  # the plot process, if the run stopped before the plot


class _Stopwatch:
    """Wall and CPU seconds per stage of a run (CPU: thread time, comparable on a loaded machine)."""

    def __init__(self):
        self.t_start, self.cpu_start = time.perf_counter(), time.process_time()
        self.wall: Counter = Counter()
        self.cpu: Counter = Counter()
        self.wall_total = 0.0

    @contextlib.contextmanager
    def stage(self, name: str):
        t0, c0 = time.perf_counter(), time.thread_time()
        yield
        self.wall[name] += time.perf_counter() - t0
        self.cpu[name] += time.thread_time() - c0

    def finish(self) -> None:
        self.wall_total = time.perf_counter() - self.t_start
        # all threads, OpenCV's workers included, and the reader's and plot's processes (when there are)
        self.cpu["process"] = (time.process_time() - self.cpu_start + self.cpu.get("reader_process", 0.0)
                               + self.cpu.get("plot_process", 0.0))


class _OutputImports:
    """:func:`_prepare_outputs` in a side thread, started by :meth:`start` (or by
    :meth:`result`, which returns its CPU seconds).

    The run starts it once the odometry has seen the first frames ahead (``_shown_ahead``):
    imports hold the GIL, and while the main thread waits for those frames they only slow
    the reader that decodes them (on the demo, 0.6 s until the first frame was processed
    with them alongside, 0.2 s without).
    """

    def __init__(self, config: RunConfig):
        self._config, self._future = config, None
        self._format = config.output.poses_format
        #: the process drawing trajectory.png (where the platform forks), else None
        self.plotter: PlotProcess | None = None

    def for_log(self, log) -> None:
        """Prepare ``poses.mcap``'s schemas for ``log`` (``output.poses_format: auto``)."""
        if self._config.output.poses_format == "auto":
            self._format = poses_format_for(getattr(log, "format", ""))

    def start(self) -> None:
        if self._future is None:
            if self._config.output.plot and process_prefetch_available():
                # forked before the side thread starts: a fork copies no thread, and a
                # module lock an importing thread held would stay held in the child
                self.plotter = PlotProcess()
            side = ThreadPoolExecutor(1, thread_name_prefix="planar-vo-outputs")
            self._future = side.submit(_prepare_outputs, self._config, self._format, self.plotter is None)
            side.shutdown(wait=False)

    def result(self) -> float:
        self.start()
        return self._future.result()

    def close(self) -> None:
        """End the plot process if the run stopped before handing it the plot."""
        if self.plotter is not None:
            self.plotter.close()


def _level(log, config: RunConfig):
    """The front-end, levelled with the log's mount (or the configured one, or the floor),
    and the pose graph."""
    odometry = PlanarOdometry(log.intrinsics, log.mount, config.frontend)
    graph = IncrementalPlanarPoseGraph(config.backend) if config.solver == "online" else PlanarPoseGraph(config.backend)
    return odometry, graph


#: report.json ``memory_mb_by_frame``: the process's resident memory every this many frames
#: (flat on a long log when nothing grows with it but the graph's few numbers per pose).
MEMORY_EVERY = 250


def _resident_mb() -> float:
    """The process's current resident set size (MB): /proc on Linux, else the peak."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError, IndexError):
        import resource
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass
class _FrameLoop:
    """What the per-frame loop collected: colour stamps of the frames with a pose, step
    statuses, the planarity evidence, ``steps.csv`` rows, and why it stopped early."""

    stamps: list = field(default_factory=list)
    statuses: Counter = field(default_factory=Counter)
    frame_infos: list = field(default_factory=list)
    steps: list = field(default_factory=list)
    partial: bool = False
    stop_reason: str | None = None
    memory: list = field(default_factory=list)  # (frames so far, resident MB) every MEMORY_EVERY frames
    gap_links: list = field(default_factory=list)  # ``gap_links.csv`` rows
    yaw_guessed: int = 0  # partial steps whose yaw is the guess's

    def add(self, frame, result) -> None:
        self.stamps.append(frame.stamp)
        if len(self.stamps) % MEMORY_EVERY == 0:
            self.memory.append([len(self.stamps), round(_resident_mb(), 1)])
        self.statuses[result.step.status if result.step is not None else "first"] += 1
        part = result.diagnostics.partial if result.diagnostics is not None else None
        if part is not None and part.get("yaw") == "guess":
            self.yaw_guessed += 1  # a partial step whose translation alone was measured
        self.frame_infos.append(frame_summary(result))
        if result.step is not None:
            self.steps.append(_step_row(result))
        for link in result.gap_links:
            self.gap_links.append(_gap_link_row(self.stamps, link))

    def counts(self) -> dict:
        return {k: v for k, v in self.statuses.items() if k != "first"}


def _loop_closer(log, odometry, graph, config: RunConfig) -> LoopCloser | None:
    """The run's loop closer (None when ``loops.enabled`` is off)."""
    if not config.loops.enabled:
        return None
    # in the background: the keyframe's ORB and matching overlap the next frame's front-end
    return LoopCloser(log.intrinsics, odometry.mount.T_base_cam, config.loops, config.places, graph,
                      frontend=config.frontend, background=True)


#: Frames the odometry sees before it processes the first (PlanarOdometry.look_ahead): the
#: plane detector needs ten to learn the sensor's range (planes._RANGE_MIN_FRAMES).
LOOK_AHEAD_FRAMES = 10


def _shown_ahead(frames, odometry: PlanarOdometry, then=None, n: int = LOOK_AHEAD_FRAMES):
    """``frames``, unchanged, after the odometry has seen the first ``n`` of them
    (:meth:`PlanarOdometry.look_ahead`); ``then()``, if given, runs right after that. A log
    cut short within them still yields the frames read before the cut, then raises."""
    it = iter(frames)
    first, cut = [], None
    try:
        for frame in it:
            first.append(frame)
            if len(first) == n:
                break
    except PartialResult as exc:
        cut = exc
    odometry.look_ahead(first)
    if then is not None:
        then()
    first.reverse()
    while first:  # dropped as they go: the run holds no frame longer than without this
        yield first.pop()
    if cut is not None:
        raise cut
    yield from it


def _reader(log, odometry, c):
    """``(reader, ahead)``: the producer of decoded, tracked frames of the ``input`` range
    ``c`` and its tracking stage (:class:`_TrackAhead`).

    ``input.reader: process`` (where the platform can fork): a child process decodes and
    tracks on its copy of the odometry, with an interpreter lock of its own, and hands
    each frame's corners over (``take_tracked`` -> ``give_tracked``) with what the log
    recorded so far (``pass_state``); at the end, the log's final pass state and the
    tracking's time come back too. (A second thread in the child, decoding while it
    tracks, was slower on 2 cores: 0.93-0.97 of one thread's frames/s, three runs each.)
    Otherwise a thread of this process decodes and tracks.
    """
    ahead = _TrackAhead(log.frames(start=c.start, stop=c.stop, stride=c.stride), odometry)
    if c.reader == "process" and process_prefetch_available():
        size = log.intrinsics.width * log.intrinsics.height
        try:
            return ProcessPrefetcher(
                ahead, depth=4, slot_bytes=8 * size + (1 << 20),  # BGR + float32 depth + the corners
                pack=lambda frame: (frame, odometry.take_tracked(frame), log.pass_state()),
                unpack=lambda item: _handed_over(odometry, log, *item),
                finish=lambda: _pass_done(log, ahead),
                child_init=log.reopen), ahead
        except OSError:  # no shared memory or semaphores here (e.g. a container without /dev/shm)
            pass
    return Prefetcher(ahead, depth=4), ahead


def _pass_done(log, ahead: _TrackAhead) -> dict:
    """What the reader process hands back when its pass is done: the log's pass state,
    with the ground truth read meanwhile (the process has nothing else left to do, and the
    report's summary would read it on the main thread; a failure here is left to that
    read), and the tracking's time."""
    try:
        log.ground_truth  # noqa: B018 - read and cached for pass_state
    except Exception:  # noqa: BLE001 - the main thread's summary reads it again and reports
        pass
    return {"log": log.pass_state(), "track": (ahead.wall_s, ahead.cpu_s)}


def _handed_over(odometry, log, frame, tracked, pass_state):
    """``frame`` with its corners given to ``odometry`` and the log's pass state as of it
    (counts of skipped frames: what a run stopped early reports)."""
    odometry.give_tracked(frame, tracked)
    log.restore_pass_state(pass_state)
    return frame


def _flush_closer(closer: LoopCloser, timings, cpu) -> None:
    """The last keyframe's closures into the graph, before it is solved; the loop closer's
    worker-thread CPU joins its stage's."""
    t0, c0 = time.perf_counter(), time.thread_time()
    closer.flush()
    timings["loops"] += time.perf_counter() - t0
    cpu["loops"] += time.thread_time() - c0 + closer.background_cpu_s


def _process_frames(log, odometry, graph, wheel, closer, config: RunConfig, clock: _Stopwatch,
                    progress: bool, ahead_seen=None) -> _FrameLoop:
    """Per frame: track (reader) -> estimate (front-end) -> add to the graph (with
    the wheel odometry's step over the same interval when ``wheel`` is given) -> offer it to
    the loop closer (keyframes, candidates, verification, closure factors). ``ahead_seen()``
    runs once the odometry has seen the first frames ahead (``_shown_ahead``).

    The reader (:func:`_reader`) decodes each frame and tracks its corners
    (PlanarOdometry.track) while the main thread works on earlier frames.
    """
    c = config.input
    loop = _FrameLoop()
    bar = Progress(_total_frames(log.expected_frames(), c), enabled=progress)
    reader, ahead = _reader(log, odometry, c)
    if ahead_seen is not None and isinstance(reader, ProcessPrefetcher):
        # the reader does not share this process's interpreter lock: what waits for the
        # first frames may run while they are decoded
        ahead_seen()
        ahead_seen = None
    timings, cpu = clock.wall, clock.cpu
    t_wait = time.perf_counter()
    try:
        with reader:
            for frame in _shown_ahead(reader, odometry, ahead_seen):
                t0, c0 = time.perf_counter(), time.thread_time()
                timings["read_wait"] += t0 - t_wait
                result = odometry.process(frame)
                t1, c1 = time.perf_counter(), time.thread_time()
                timings["frontend"] += t1 - t0
                cpu["frontend"] += c1 - c0
                for k, v in result.timings.items():
                    timings[f"frontend.{k}"] += v
                graph.add_frame(result, odometry=wheel.step(frame.stamp, result) if wheel else None)
                t2, c2 = time.perf_counter(), time.thread_time()
                timings["backend"] += t2 - t1
                cpu["backend"] += c2 - c1
                if closer is not None:
                    closer.offer(frame, result, odometry.levelling.R_lev_cam)
                t_wait = time.perf_counter()
                timings["loops"] += t_wait - t2
                cpu["loops"] += time.thread_time() - c2
                loop.add(frame, result)
                bar.update(len(loop.stamps), **loop.counts())
    except KeyboardInterrupt:
        loop.partial, loop.stop_reason = True, "interrupted by the user (Ctrl-C)"
    except PartialResult as exc:
        loop.partial, loop.stop_reason = True, str(exc)
    if closer is not None:
        _flush_closer(closer, timings, cpu)
    if isinstance(reader, ProcessPrefetcher):
        if reader.finished is not None:
            log.restore_pass_state(reader.finished["log"])
            ahead.wall_s, ahead.cpu_s = reader.finished["track"]
        cpu["reader_process"] += reader.cpu_s  # its own CPU, not the parent process's
    timings["read_decode_background"] += reader.busy_s - ahead.wall_s
    cpu["read_decode_background"] += reader.busy_cpu_s - ahead.cpu_s
    timings["track_background"] += ahead.wall_s
    cpu["track_background"] += ahead.cpu_s
    bar.close(len(loop.stamps), **loop.counts())
    return loop


def _solve(graph, config: RunConfig):
    """``(raw, smoothed)`` (N, 3) base_link poses: the chained steps and the graph's solution."""
    raw = graph.raw_poses()
    smoothed = graph.estimate() if config.solver == "online" else graph.optimize()
    return raw, smoothed


def _report(log_path, log_summary, stats, loop: _FrameLoop, odometry, graph, config, clock: _Stopwatch,
            wheel_section: dict) -> dict:
    """``report.json``: counts, verdicts, back-end statistics and time per stage."""
    n = len(loop.stamps)
    timings, cpu, wall = clock.wall, clock.cpu, clock.wall_total
    return {
        "log": str(log_path),
        "input": log_summary,
        "partial": loop.partial,
        "stop_reason": loop.stop_reason,
        "frames": _frame_counts(loop, stats),
        "motion": motion_with_wheel_odometry(motion_report(loop.statuses, loop.yaw_guessed), wheel_section),
        "mount": _mount_report(odometry.mount),
        "planarity": planarity_report(loop.frame_infos, levelled=is_levelled(odometry.levelling, loop.frame_infos)),
        "backend": _jsonable(getattr(graph, "stats", {})),
        "wheel_odometry": _jsonable(wheel_section),
        "manhattan_frames": [list(map(_jsonable, m)) for m in graph.manhattan_frames()],
        "timings_s": {k: round(v, 4) for k, v in sorted(timings.items())},
        "timings_ms_per_frame": {k: round(1000 * v / n, 3) for k, v in sorted(timings.items())},
        "cpu_ms_per_frame": {k: round(1000 * v / n, 3) for k, v in sorted(cpu.items())},
        "wall_time_s": round(wall, 3),
        "fps": round(n / wall, 2) if wall > 0 else None,
        "fps_excluding_writing": round(n / max(wall - timings["write"], 1e-9), 2),
        "memory_mb_by_frame": loop.memory,
        "solver": config.solver,
    }


def _frame_counts(loop: _FrameLoop, stats: dict) -> dict:
    n, statuses = len(loop.stamps), loop.statuses
    return {
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
    }


#: Below this share of steps with a measured translation the run is not a trajectory.
MIN_MEASURED_FRACTION = 0.5
#: Below this share the run is degraded (a warning, not a failure).
GOOD_MEASURED_FRACTION = 0.9


def motion_report(statuses: Counter, yaw_guessed: int = 0) -> dict:
    """How much of the motion was measured: steps whose translation came from an
    estimator (direction-plus-point, 2-point), steps with part of it (partial:
    ``yaw_guessed`` of them measured some of the translation but not the yaw), steps with
    neither (bridged), and a verdict a user can act on."""
    n = sum(v for k, v in statuses.items() if k != "first")
    full = statuses.get("dpp", 0) + statuses.get("2pt", 0)
    yaw = full + statuses.get("partial", 0) - yaw_guessed
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


STEPS_HEADER = ("index,stamp,status,x,y,theta,sigma_x,sigma_y,sigma_theta,inliers,keyframe_lag,"
                "rho_xy,rho_xtheta,rho_ytheta")


def _step_row(result) -> list:
    """One ``steps.csv`` row: the front-end's base_link step ``T_base_prev_base_curr``
    (x, y m; theta rad) into this frame, the sigmas of its stated covariance, its inliers,
    how many frames back the keyframe it was measured against is (1: the previous frame),
    and the covariance's correlation coefficients (x-y, x-theta, y-theta): with the sigmas
    they give the whole (3, 3) covariance back."""
    st = result.step
    with np.errstate(all="ignore"):
        cov = np.linalg.inv(st.information)
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        rho = [float(cov[i, j] / (sd[i] * sd[j])) if sd[i] * sd[j] > 0 else 0.0 for i, j in ((0, 1), (0, 2), (1, 2))]
    lag = st.keyframe.lag if st.keyframe is not None else 1
    return [result.index, result.stamp, st.status, *map(float, st.pose), *map(float, sd), int(st.inliers), lag, *rho]


GAP_LINKS_HEADER = "from_stamp,to_stamp,x,y,theta,sigma_x,sigma_y,rho_xy"


def _gap_link_row(stamps: list, link) -> list:
    """One ``gap_links.csv`` row of a :class:`~planar_vo.core.steps.GapLink` taken at the
    last of ``stamps``: the colour stamps of its two frames, the base_link motion
    ``T_base_from_base_to`` (x, y m; theta rad), the sigmas of its translation and their
    correlation. Its yaw is the walls', stated in the steps; the link states none."""
    n = len(stamps) - 1
    with np.errstate(all="ignore"):
        cov = np.linalg.inv(link.information)[:2, :2]
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        rho = float(cov[0, 1] / (sd[0] * sd[1])) if sd[0] * sd[1] > 0 else 0.0
    return [stamps[n - link.lag_from], stamps[n - link.lag_to], *map(float, link.pose), *map(float, sd), rho]


def _write_gap_links(path: Path, rows: list[list]) -> str:
    lines = [GAP_LINKS_HEADER] + [f"{r[0]:.6f},{r[1]:.6f}," + ",".join(f"{v:.9g}" for v in r[2:7]) + f",{r[7]:.6f}"
                                  for r in rows]
    write_text_atomic(path, "\n".join(lines) + "\n")
    return str(path)


def _write_steps(path: Path, rows: list[list]) -> str:
    lines = [STEPS_HEADER]
    for r in rows:
        lines.append(f"{r[0]},{r[1]:.6f},{r[2]}," + ",".join(f"{v:.9g}" for v in r[3:9]) + f",{r[9]},{r[10]},"
                     + ",".join(f"{v:.6f}" for v in r[11:14]))
    write_text_atomic(path, "\n".join(lines) + "\n")
    return str(path)


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


def _write_outputs(out: Path, config: RunConfig, stamps, raw, smoothed, T_base_cam, gt,
                   log_format: str = "", wheel_traj=None, closures=(), plotter: PlotProcess | None = None) -> dict:
    """raw/smoothed.tum, config.yaml, poses.mcap and trajectory.png; ``wheel_traj`` (the wheel
    odometry alone, as in wheel_odom.tum, or None) goes into poses.mcap and the plot too;
    ``closures``: ``(a, b)`` pose indices of the loop closures kept, drawn as lines between
    the two smoothed camera positions; ``plotter``: the process that draws the plot while
    the rest is written (None: drawn here)."""
    raw_traj = _trajectory(stamps, raw, T_base_cam)
    smooth_traj = _trajectory(stamps, smoothed, T_base_cam)
    wheel = {} if wheel_traj is None else {"wheel_odom": wheel_traj}
    files = {}
    plot_args = ((out / "trajectory.png", {"raw": raw_traj, "smoothed": smooth_traj,
                                           **{"wheel odometry": t for t in wheel.values()}}, gt),
                 {"closures": _closure_segments(smooth_traj, closures)}) if config.output.plot else None
    if plot_args is not None and plotter is not None:
        plotter.submit(*plot_args[0], **plot_args[1])
    write_tum_trajectory(out / "raw.tum", raw_traj)
    write_tum_trajectory(out / "smoothed.tum", smooth_traj)
    files["raw"], files["smoothed"] = str(out / "raw.tum"), str(out / "smoothed.tum")
    write_text_atomic(out / "config.yaml", dump_config(config))
    files["config"] = str(out / "config.yaml")
    if config.output.poses_mcap:
        transforms = [(s, "odom", "base_link", se2_to_matrix(p)) for s, p in zip(stamps, smoothed)]
        transforms.append((stamps[0], "base_link", "camera_optical_frame", T_base_cam))
        fmt = config.output.poses_format
        lines = (stamps[-1], "loop_closures", "odom", _closure_segments(smooth_traj, closures)) if closures else None
        write_poses_mcap(out / "poses.mcap", {"raw": raw_traj, "smoothed": smooth_traj, **wheel},
                         transforms=transforms, lines=lines,
                         format=poses_format_for(log_format) if fmt == "auto" else fmt)
        files["poses_mcap"] = str(out / "poses.mcap")
    if plot_args is not None:
        if plotter is None or not plotter.wait():
            from planar_vo.plotting import plot_trajectories

            plot_trajectories(*plot_args[0], **plot_args[1])
        files["plot"] = str(out / "trajectory.png")
    return files


def _closure_segments(traj: Trajectory, closures) -> np.ndarray:
    """(M, 2, 3) camera positions joined by each closure ``(a, b)`` (pose indices)."""
    P = traj.positions
    return np.array([[P[a], P[b]] for a, b in closures], dtype=float).reshape(-1, 2, 3)


def _solve_without_closures(graph, closer) -> np.ndarray | None:
    """(N, 3) ``T_odom_base`` of the same graph without its loop closures (for ``evaluate``'s
    side-by-side), or None when the run closed no loop."""
    if closer is None or not closer.accepted():
        return None
    return graph.solve_without_closures()


def _write_no_loops(out: Path, stamps, poses, T_base_cam) -> dict:
    """``smoothed_no_loops.tum`` when the run closed loops; an older one is removed so that
    a run folder never mixes runs."""
    path = out / "smoothed_no_loops.tum"
    if poses is None:
        path.unlink(missing_ok=True)
        return {}
    write_tum_trajectory(path, _trajectory(stamps, poses, T_base_cam))
    return {"smoothed_no_loops": str(path)}
