"""Top-view trajectory plot (matplotlib, off-screen). Written atomically."""
from __future__ import annotations

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
