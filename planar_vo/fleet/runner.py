"""Scheduling a fleet's logs on Ray: local by default, a cluster by address; resumable.

Each log is one Ray task (:func:`planar_vo.fleet.task.run_log`) declaring one CPU and
:data:`TASK_MEMORY_MB`, run in a fresh worker process (``max_calls=1``: a run's memory is
its own and dies with it) and never retried by Ray (a re-run of the batch retries what
failed). A log whose folder holds a ``batch.json`` of a finished run with the same content
hash, configuration and planar-vo version is skipped without starting a task.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from planar_vo import __version__
from planar_vo.core.errors import InputError
from planar_vo.fleet.logs import content_hash, find_logs, result_names
from planar_vo.fleet.task import FINISHED, run_log

#: Memory a task declares to Ray: ``planar-vo run`` peaks at ~200 MB on a 300-frame qhd
#: log (README, ``bench run``) and a Ray worker adds ~100 MB; twice that leaves headroom.
TASK_MEMORY_MB = 600
#: Files that must exist for a finished run to count as complete.
REQUIRED = ("raw.tum", "smoothed.tum", "report.json", "config.yaml")
INSTALL_HINT = "Ray is not installed; pip install 'planar-vo[fleet]'"


@dataclass
class Job:
    log: Path
    name: str
    out_dir: Path
    key: dict = field(default_factory=dict)
    record: dict | None = None
    skipped: bool = False


@dataclass
class BatchResult:
    jobs: list[Job]
    interrupted: bool
    ray: dict
    wall_s: float
    run_s: float


def is_loopback(address: str | None) -> bool:
    """True for no address (a local Ray) or one on this machine's loopback interface."""
    if not address:
        return True
    host = address.split("://")[-1].rsplit(":", 1)[0].strip("[]")
    return host == "localhost" or host == "::1" or host.startswith("127.")


def import_ray(address: str | None):
    """The ``ray`` module, or :class:`InputError` saying how to install it. Without an
    address or with a loopback one, Ray runs on this machine's loopback interface only."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage reports sent anywhere
    local = is_loopback(address)
    if local:
        # Ray binds its servers to the node's address and resolves 127.0.0.1 to the machine's
        # network address; with this it keeps 127.0.0.1 (read when ray is imported, hence
        # set before, and patched if ray was imported already).
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    if address and local and "RAY_AUTH_MODE" not in os.environ and (
            "RAY_AUTH_TOKEN" in os.environ or (Path.home() / ".ray" / "auth_token").is_file()):
        # Ray sends its token to a cluster it finds itself but not to one given by address;
        # one on this machine is found here by address, so do what Ray does for it.
        os.environ["RAY_AUTH_MODE"] = "token"
    try:
        import ray
    except ImportError:
        raise InputError(INSTALL_HINT) from None
    if local:
        with contextlib.suppress(Exception):
            ray._private.ray_constants.ENABLE_RAY_CLUSTER = False
    return ray


# ----------------------------------------------------------------------- planning
def plan(inputs: list[str], out: Path, config_text: str, gt_from_logs: bool) -> list[Job]:
    """One :class:`Job` per log, hashed, with the finished ones marked ``skipped``."""
    logs = find_logs(inputs, exclude=out)
    if not logs:
        raise InputError(f"{', '.join(map(str, inputs))}: no logs found (MCAP files or TUM folders with rgb.txt)")
    names = result_names(logs)
    jobs = [Job(p, names[p], out / names[p]) for p in logs]
    config_sha = hashlib.sha256(config_text.encode()).hexdigest()
    with ThreadPoolExecutor(4) as pool:  # hashing reads files: threads overlap the I/O
        hashes = list(pool.map(_safe_hash, logs))
    for job, h in zip(jobs, hashes):
        job.key = {"log_sha256": h, "config_sha256": config_sha, "planar_vo": __version__,
                   "gt_from_logs": bool(gt_from_logs)}
        previous = finished_record(job.out_dir, job.key)
        if previous is not None:
            job.record, job.skipped = previous, True
    return jobs


def _safe_hash(log: Path) -> str | None:
    try:
        return content_hash(log)
    except (OSError, InputError):
        return None  # the task will report why the log cannot be read


def finished_record(out_dir: Path, key: dict) -> dict | None:
    """The record in ``out_dir/batch.json`` if it is a finished run for ``key``, else None."""
    try:
        saved = json.loads((out_dir / "batch.json").read_text())
    except (OSError, ValueError):
        return None
    if key.get("log_sha256") is None or saved.get("key") != key:
        return None
    rec = saved.get("record") or {}
    if rec.get("status") not in FINISHED or not all((out_dir / f).is_file() for f in REQUIRED):
        return None
    return rec


def save_record(job: Job) -> None:
    """``batch.json`` in the log's result folder: the key it was run for and its record."""
    from planar_vo.io.atomic import write_text_atomic

    job.out_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(job.out_dir / "batch.json", json.dumps(
        {"log": str(job.log), "key": job.key, "record": job.record,
         "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}, indent=2, default=float) + "\n")


# ----------------------------------------------------------------------- Ray
@contextlib.contextmanager
def ray_session(ray, address: str | None, workers: int | None):
    """Ray for the batch: the session this process already has, else a connection to
    ``address``, else a local instance (loopback only, no dashboard) stopped on exit.
    Yields ``{"mode", "start_s", "cpus", "session_dir"}``."""
    info = {"mode": "existing", "start_s": 0.0}
    t0 = time.perf_counter()
    started = False
    if not ray.is_initialized():
        quiet = dict(log_to_driver=False, logging_level=logging.ERROR)
        if address:
            info["mode"] = "cluster"
            check_reachable(address)
            try:
                ctx = ray.init(address=address, **quiet)
            except Exception as exc:  # noqa: BLE001 - ConnectionError, RuntimeError, ...
                raise InputError(f"--address {address}: cannot connect to a Ray cluster "
                                 f"({_first_line(exc)}); start one with 'ray start --head' or leave "
                                 "--address out to run on this machine") from None
        else:
            info["mode"] = "local"
            cpus = os.cpu_count() or 1
            ctx = ray.init(address="local", num_cpus=max(1, min(workers or cpus, cpus)), include_dashboard=False,
                     object_store_memory=100 * 1024 ** 2, **quiet)
        started = True
        info["session_dir"] = ctx.address_info.get("session_dir")
    info["start_s"] = round(time.perf_counter() - t0, 2)
    info["cpus"] = int(ray.cluster_resources().get("CPU", 1))
    try:
        yield info
    finally:
        if started:
            ray.shutdown()


def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast on a ``host:port`` that accepts no connection (``ray.init`` would retry for
    minutes); other forms (``auto``, ``ray://``) are left to Ray."""
    import socket

    host, _, port = address.rpartition(":")
    if "://" in address or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise InputError(f"--address {address}: no Ray cluster answers there ({exc.strerror or exc}); start one "
                         "with 'ray start --head' or leave --address out to run on this machine") from None


def _first_line(exc: BaseException) -> str:
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    return lines[0] if lines else type(exc).__name__


def ray_failure(ray, exc: BaseException) -> str:
    """One line for a task that Ray could not complete (its worker died, ...)."""
    ex = ray.exceptions
    if isinstance(exc, ex.OutOfMemoryError):
        return "out of memory: Ray's memory monitor killed the task (" + _first_line(exc)[:200] + ")"
    if isinstance(exc, ex.WorkerCrashedError):
        return "the worker process died (a crash in native code, or killed by the system, e.g. out of memory)"
    if isinstance(exc, ex.TaskCancelledError):
        return "cancelled"
    if isinstance(exc, ex.RayTaskError):
        cause = getattr(exc, "cause", None)
        return f"task error: {_first_line(cause) if cause is not None else _first_line(exc)}"
    return f"{type(exc).__name__}: {_first_line(exc)[:300]}"


# ----------------------------------------------------------------------- progress
class FleetProgress:
    """One line across the fleet: logs done of all, skipped, failed, running, frames per
    second over the logs finished so far. Redrawn in place on a terminal; elsewhere a line
    per finished log and every 10 s."""

    def __init__(self, total: int, enabled: bool = True, stream=None):
        self.total, self.enabled = total, enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self._last, self._width = 0.0, 0

    def draw(self, jobs: list[Job], running: int, force: bool = False) -> None:
        now = time.perf_counter()
        if not self.enabled or (not force and now - self._last < (0.5 if self.tty else 10.0)):
            return
        self._last = now
        recs = [j for j in jobs if j.record is not None]
        done = sum(r.record.get("status") in FINISHED for r in recs)
        failed = sum(r.record.get("status") == "failed" for r in recs)
        frames = sum(int(j.record.get("frames") or 0) for j in recs if not j.skipped)
        line = (f"batch: {done + failed}/{self.total} logs ({sum(j.skipped for j in jobs)} skipped, "
                f"{failed} failed, {running} running) | {frames / max(now - self.t0, 1e-9):.1f} frames/s "
                f"| {now - self.t0:.0f} s")
        self.stream.write(("\r" + line.ljust(self._width)) if self.tty else line + "\n")
        self._width = len(line)
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()


# ----------------------------------------------------------------------- the batch
def execute(ray, jobs: list[Job], config, gt_from_logs: bool, workers: int, bar: FleetProgress) -> bool:
    """Run the jobs without a record, at most ``workers`` at a time; ``True`` if interrupted.
    Each record is saved to its folder as soon as it arrives, so an interrupt loses only
    the logs still running (their tasks are cancelled, their folders re-run next time)."""
    task = ray.remote(num_cpus=1, memory=TASK_MEMORY_MB * 1024 ** 2, max_calls=1, max_retries=0)(run_log)
    # A task has one CPU (the fleet's parallelism is across logs), and a Ray worker is no
    # process to fork: its reader is a thread (the same results as the reader process).
    config = dataclasses.replace(config, input=dataclasses.replace(config.input, reader="thread"))
    pending = [j for j in jobs if j.record is None]
    running: dict = {}
    try:
        while pending or running:
            while pending and len(running) < workers:
                job = pending.pop(0)
                running[task.remote(str(job.log), str(job.out_dir), config, gt_from_logs)] = job
            done, _ = ray.wait(list(running), num_returns=1, timeout=0.5)
            for ref in done:
                job = running.pop(ref)
                try:
                    job.record = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - Ray's errors for a task it could not finish
                    job.record = {"status": "failed", "reason": ray_failure(ray, exc)}
                save_record(job)
            bar.draw(jobs, len(running), force=bool(done))
    except KeyboardInterrupt:
        for ref, job in running.items():
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
            job.record = {"status": "interrupted", "reason": "interrupted by the user (Ctrl-C) while running"}
        for job in pending:
            job.record = {"status": "interrupted", "reason": "interrupted by the user (Ctrl-C) before it started"}
        return True
    return False


def run_batch(inputs: list[str], out: str | Path, config, *, address: str | None = None,
              workers: int | None = None, gt_from_logs: bool = False, progress: bool = True) -> BatchResult:
    """Plan, skip what is finished, run the rest on Ray, write the summary into ``out``."""
    from planar_vo.config import dump_config
    from planar_vo.fleet.summary import write_summary

    if workers is not None and workers < 1:
        raise InputError(f"--workers {workers}: must be at least 1")
    ray = import_ray(address)
    t0 = time.perf_counter()
    out = Path(out).resolve()
    jobs = plan(inputs, out, dump_config(config), gt_from_logs)
    out.mkdir(parents=True, exist_ok=True)
    bar = FleetProgress(len(jobs), enabled=progress)
    info = {"mode": "not started (every log finished before)", "start_s": 0.0}
    interrupted = False
    t_run = time.perf_counter()
    to_run = any(j.record is None for j in jobs)
    if to_run:
        with ray_session(ray, address, workers) as info:
            bar.t0 = t_run = time.perf_counter()
            interrupted = execute(ray, jobs, config, gt_from_logs, workers or info["cpus"], bar)
    bar.draw(jobs, 0, force=bar.tty or not to_run)  # elsewhere the last log's line was the last
    bar.close()
    result = BatchResult(jobs, interrupted, info, time.perf_counter() - t0, time.perf_counter() - t_run)
    write_summary(out, result)
    return result


#: Exit codes of ``planar-vo batch`` (README): every log ok; some finished but partial or
#: not estimated; bad input (the command's own); interrupted; some logs failed.
EXIT_OK, EXIT_NOT_ALL_ESTIMATED, EXIT_INTERRUPTED, EXIT_FAILED = 0, 4, 3, 5


def exit_code(result: BatchResult) -> int:
    statuses = [j.record.get("status") for j in result.jobs if j.record]
    if result.interrupted:
        return EXIT_INTERRUPTED
    if any(s not in FINISHED for s in statuses):
        return EXIT_FAILED
    if any(s != "ok" for s in statuses):
        return EXIT_NOT_ALL_ESTIMATED
    return EXIT_OK
