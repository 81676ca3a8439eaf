"""`planar-vo evaluate` agrees with evo's own command-line tools on ATE and RPE.

The same files are given to ``evo_ape`` / ``evo_rpe`` (installed with evo, run from this
environment) with the options the metrics module documents; their full-precision results
(``--save_results``) must equal ``evaluation.json`` to 1e-6, and the printed ATE row must
show evo's RMSE.
"""
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from planar_vo.core import geometry as g
from planar_vo.cli import main
from planar_vo.io.trajectory import write_tum_trajectory
from planar_vo.core.types import Trajectory

EVO_BIN = Path(sys.executable).parent


def _cam_poses(se2: np.ndarray) -> np.ndarray:
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = g.mount_rotation(0.17, 0.03)
    T_base_cam[2, 3] = 0.8
    return g.base_poses_to_cam_matrices(se2, T_base_cam)


def _l_turn(n: int) -> np.ndarray:
    """(n, 3) x, y, theta: 4 m straight, a quarter turn of 1 m radius, 3 m on."""
    s = np.linspace(0.0, 4.0 + np.pi / 2 + 3.0, n)
    out = np.zeros((n, 3))
    for i, si in enumerate(s):
        if si <= 4.0:
            out[i] = [si, 0.0, 0.0]
        elif si <= 4.0 + np.pi / 2:
            a = si - 4.0
            out[i] = [4.0 + np.sin(a), 1.0 - np.cos(a), a]
        else:
            out[i] = [5.0, 1.0 + si - 4.0 - np.pi / 2, np.pi / 2]
    return out


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A run folder whose raw and smoothed trajectories drift and jitter against a known truth."""
    rng = np.random.default_rng(12)
    d = tmp_path_factory.mktemp("evo")
    n = 120
    stamps = 100.0 + 0.1 * np.arange(n)
    truth = _l_turn(n)
    write_tum_trajectory(d / "gt.tum", Trajectory(stamps, _cam_poses(truth)))
    keep = np.sort(rng.choice(n, n - 7, replace=False))  # a few frames without a pose
    for name, drift, jitter in (("raw", 0.03, 0.01), ("smoothed", 0.01, 0.004)):
        est = truth + rng.normal(0.0, jitter, truth.shape)
        est[:, 2] += np.linspace(0.0, drift, n)
        est[:, 0] += np.linspace(0.0, 5 * drift, n)
        # stamps 4 ms off the truth's, within the 20 ms association tolerance
        write_tum_trajectory(d / f"{name}.tum", Trajectory(stamps[keep] + 0.004, _cam_poses(est)[keep]))
    return d


def _evo(tool: str, args: list[str], tmp: Path) -> dict:
    out = tmp / f"{tool}-{len(list(tmp.glob('*.zip')))}.zip"
    subprocess.run([str(EVO_BIN / tool), "tum", *args, "--t_max_diff", "0.02", "--save_results", str(out),
                    "--no_warnings"], check=True, capture_output=True, text=True)
    with zipfile.ZipFile(out) as z:
        return json.loads(z.read("stats.json"))


def test_evaluate_matches_evo_ape_and_rpe(run_dir, tmp_path, capsys):
    assert main(["evaluate", str(run_dir), "--gt", str(run_dir / "gt.tum")]) == 0
    printed = capsys.readouterr().out
    ev = json.loads((run_dir / "evaluation.json").read_text())
    gt = str(run_dir / "gt.tum")
    for name in ("raw", "smoothed"):
        est = str(run_dir / f"{name}.tum")
        ape = _evo("evo_ape", [gt, est, "-a"], tmp_path)
        rpe_args = [gt, est, "-d", "1", "-u", "m", "-t", "0.1", "--all_pairs", "--pairs_from_reference"]
        rpe_t = _evo("evo_rpe", rpe_args + ["-r", "trans_part"], tmp_path)
        rpe_r = _evo("evo_rpe", rpe_args + ["-r", "angle_deg"], tmp_path)
        assert ev[name]["matched"] == 113
        assert ev[name]["ate_alignment"] == "se3"
        assert ev[name]["ate_rmse_m"] == pytest.approx(ape["rmse"], abs=1e-6)
        assert ev[name]["rpe_trans_per_m"] == pytest.approx(rpe_t["mean"], abs=1e-6)  # delta 1 m
        assert ev[name]["rpe_rot_deg_per_m"] == pytest.approx(rpe_r["mean"], abs=1e-6)
        assert ape["rmse"] > 1e-3  # the trajectories do differ: the comparison is not trivial
    row = next(line for line in printed.splitlines() if line.startswith("ATE RMSE"))
    assert row.split()[-2:] == [f"{ev['raw']['ate_rmse_m']:.3f}", f"{ev['smoothed']['ate_rmse_m']:.3f}"]
