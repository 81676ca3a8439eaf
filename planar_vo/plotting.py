"""Top-view trajectory plot (matplotlib, off-screen). Written atomically.

:class:`PlotProcess` draws it in a forked process that imports matplotlib while the run's
frames are processed: the import takes ~0.85 s of CPU, which in a thread of the run's own
process holds the interpreter lock the front-end needs.
"""
from __future__ import annotations

import multiprocessing
import signal
import time
from pathlib import Path

import numpy as np

from planar_vo.io.trajectory import associate_stamps

_STYLES = {"raw": dict(color="tab:orange", lw=1.2, ls="--"), "smoothed": dict(color="tab:blue", lw=1.8),
           "ground truth": dict(color="k", lw=1.0, alpha=0.7),
           "wheel odometry": dict(color="tab:green", lw=1.2, ls=":")}


def plot_trajectories(path: str | Path, trajectories: dict, ground_truth=None, title: str | None = None,
                      closures=None) -> None:
    """Plot camera positions seen from above (x forward, y left of the first frame).

    ``trajectories``: name -> Trajectory (``T_odom_cam``), drawn in order and labelled by
    name (``raw``, ``smoothed`` and ``wheel odometry`` have their own styles); the first
    one's start is marked. ``ground_truth``: Trajectory in
    its own world frame; it is brought into ``odom`` by aligning its pose at the first
    estimated stamp with the first estimated pose, so the plot shows drift as it grew.
    ``closures``: optional (M, 2, 3) endpoints of loop closures in ``odom``, drawn as lines.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    first = next(iter(trajectories.values()))
    if ground_truth is not None and len(ground_truth) and len(first):
        ia, ib = associate_stamps(first.stamps, ground_truth.stamps, 0.05)
        if len(ia):
            A = first.poses[ia[0]] @ np.linalg.inv(ground_truth.poses[ib[0]])
            P = (A[:3, :3] @ ground_truth.positions.T).T + A[:3, 3]
            ax.plot(P[:, 0], P[:, 1], label="ground truth", **_STYLES["ground truth"])
    for name, traj in trajectories.items():
        P = traj.positions
        ax.plot(P[:, 0], P[:, 1], label=name, **_STYLES.get(name, {}))
    for k, (a, b) in enumerate(np.asarray(closures if closures is not None else []).reshape(-1, 2, 3)):
        ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="#e7298a", lw=0.8, alpha=0.7,
                label="loop closures" if k == 0 else None)
    if len(first):
        ax.plot(*first.positions[0, :2], "go", ms=6, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m] (odom)")
    ax.set_ylabel("y [m] (odom)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)


class PlotProcess:
    """:func:`plot_trajectories` in a forked child that imports matplotlib as soon as it
    starts (POSIX ``fork``; see :func:`planar_vo.prefetch.process_prefetch_available`).

    :meth:`submit` hands it one plot (the arguments travel pickled) and returns at once;
    :meth:`wait` returns True once the file is written, False when the child could not
    write it (it died, or the plot raised: then the caller draws it itself, and sees the
    error); ``cpu_s`` is then the child's CPU seconds. :meth:`close` ends a child that got
    nothing to draw. The child ignores Ctrl-C (the run's to handle) and exits when the
    run's end of the pipe closes.
    """

    def __init__(self) -> None:
        ctx = multiprocessing.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_plot_child, args=(child, self._conn), name="planar-vo-plot", daemon=True)
        self._proc.start()
        child.close()
        self._submitted = False
        self.cpu_s = 0.0

    def submit(self, *args, **kwargs) -> None:
        try:
            self._conn.send((args, kwargs))
            self._submitted = True
        except (OSError, ValueError):  # the child is gone: wait() says so
            pass

    def wait(self) -> bool:
        ok = False
        if self._submitted:
            try:
                error, self.cpu_s = self._conn.recv()
                ok = error is None
            except (EOFError, OSError):
                ok = False
        self.close()
        return ok

    def close(self) -> None:
        self._conn.close()
        if not self._submitted:
            self._proc.kill()  # nothing to draw: no need to wait for its imports
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(timeout=5.0)


def _plot_child(conn, parent_end) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent_end.close()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401 - the import is the point: done before the plot is due

    try:
        args, kwargs = conn.recv()
    except (EOFError, OSError):
        return  # the run ended without a plot
    try:
        plot_trajectories(*args, **kwargs)
        error = None
    except BaseException as exc:  # noqa: BLE001 - the parent draws it again and sees the error
        error = f"{type(exc).__name__}: {exc}"
    conn.send((error, time.process_time()))
