"""Smoothed error over each gap of a sweep: runs of at least ``--min`` partial or bridged steps.

    python docs/bench/gap_errors.py CACHE SWEEP_A SWEEP_B ... [--min 3]

For every log of ``SWEEP_A`` (a ``planar-vo bench sweep --out`` folder) and every run of
weak steps in its ``steps.csv``, the base_link motion from the frame before the run to its
last frame, from each sweep's ``smoothed.tum``, against the ground truth in ``CACHE``
(``LOG.gt.tum`` beside ``LOG.mcap``); prints each gap's translation error (mm) per sweep and
their RMS / median / sum. The gaps are those of the first sweep (the front-end's steps are
the same when only the back-end changed).
"""
import argparse
import csv
import itertools
import math
from pathlib import Path

import numpy as np

from planar_vo.core.geometry import se2_between
from planar_vo.io.opener import open_log
from planar_vo.io.trajectory import read_tum_trajectory
from planar_vo.io.wheel_odom import planar_pose


def base_poses(tum: Path, T_base_cam: np.ndarray) -> np.ndarray:
    """(N, 3) base_link ``(x, y, yaw)`` of a TUM file of camera poses."""
    inv = np.linalg.inv(T_base_cam)
    return np.array([planar_pose(P @ inv) for P in read_tum_trajectory(tum).poses])


def gaps(steps_csv: Path, min_len: int) -> list[tuple[int, int]]:
    """(frame before, last frame) of every run of at least ``min_len`` weak steps."""
    rows = list(csv.DictReader(open(steps_csv)))
    out = []
    for weak, grp in itertools.groupby(rows, key=lambda r: r["status"] in ("partial", "bridged")):
        grp = list(grp)
        if weak and len(grp) >= min_len:
            out.append((int(grp[0]["index"]) - 1, int(grp[-1]["index"])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("cache", type=Path)
    ap.add_argument("sweeps", type=Path, nargs="+")
    ap.add_argument("--min", type=int, default=3)
    a = ap.parse_args()
    errs = {s: [] for s in a.sweeps}
    for run in sorted(p for p in a.sweeps[0].iterdir() if (p / "steps.csv").exists()):
        log = a.cache / f"{run.name}.mcap"
        if not log.exists() or not all((s / run.name / "smoothed.tum").exists() for s in a.sweeps):
            continue
        with open_log(log) as opened:
            T_bc = np.asarray(opened.mount.T_base_cam)
        G = base_poses(log.with_suffix(".gt.tum"), T_bc)
        est = {s: base_poses(s / run.name / "smoothed.tum", T_bc) for s in a.sweeps}
        for i, j in gaps(run / "steps.csv", a.min):
            truth = se2_between(G[i], G[j])[:2]
            e = [float(np.linalg.norm(se2_between(est[s][i], est[s][j])[:2] - truth)) for s in a.sweeps]
            for s, v in zip(a.sweeps, e):
                errs[s].append(v)
            print(f"{run.name:32s} frames {i}-{j} ({j - i} steps, {np.linalg.norm(truth):.2f} m): "
                  + " ".join(f"{1e3 * v:7.1f}" for v in e) + " mm")
    for s in a.sweeps:
        e = np.array(errs[s])
        print(f"{s}: {len(e)} gaps, RMS {1e3 * math.sqrt(float(np.mean(e ** 2))):.1f} mm, "
              f"median {1e3 * float(np.median(e)):.1f} mm, sum {1e3 * float(e.sum()):.0f} mm")


if __name__ == "__main__":
    main()
