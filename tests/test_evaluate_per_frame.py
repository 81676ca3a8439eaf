"""`planar-vo evaluate --per-frame`: each frame's error along, left of and above the
ground-truth heading, and in yaw, recovered exactly from trajectories built with known errors."""
import csv
import math

import numpy as np
import pytest

from planar_vo.cli import main
from planar_vo.core import geometry as g
from planar_vo.core.types import Trajectory
from planar_vo.io.trajectory import write_tum_trajectory
from planar_vo.metrics import per_frame_errors, trajectory_errors


def _truth(n: int) -> np.ndarray:
    """(n, 4, 4) ``T_world_cam`` of a camera pitched 10 deg down and rolled 2 deg on a base
    that drives 3 m along x, then turns left through 90 deg on a 1 m radius."""
    s = np.linspace(0.0, 3.0 + math.pi / 2, n)
    se2 = np.array([[si, 0.0, 0.0] if si <= 3.0 else
                    [3.0 + math.sin(si - 3.0), 1.0 - math.cos(si - 3.0), si - 3.0] for si in s])
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = g.mount_rotation(math.radians(10.0), math.radians(2.0))
    T_base_cam[:3, 3] = [0.2, 0.0, 0.6]
    return g.base_poses_to_cam_matrices(se2, T_base_cam)


def _with_errors(G: np.ndarray, along, left, up, yaw_deg) -> np.ndarray:
    """``G`` (n, 4, 4) moved by the given errors (n,) each: along / left of the camera's
    heading on the floor, up world z, and turned about world z by ``yaw_deg``."""
    E = G.copy()
    for k, T in enumerate(G):
        f = np.array([T[0, 2], T[1, 2], 0.0])
        f /= np.linalg.norm(f)
        lft = np.array([-f[1], f[0], 0.0])
        E[k, :3, 3] = T[:3, 3] + along[k] * f + left[k] * lft + up[k] * np.array([0.0, 0.0, 1.0])
        E[k, :3, :3] = g.rot_z(math.radians(yaw_deg[k])) @ T[:3, :3]
    return E


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(3)
    n = 80
    stamps = 50.0 + 0.1 * np.arange(n)
    G = _truth(n)
    errs = [np.concatenate([[0.0], rng.normal(0.0, s, n - 1)]) for s in (0.05, 0.03, 0.01, 0.8)]
    return stamps, G, errs


def test_per_frame_errors_recover_the_errors_put_in(case):
    stamps, G, (along, left, up, yaw) = case
    E = _with_errors(G, along, left, up, yaw)
    out = per_frame_errors(stamps, E, stamps, G)
    assert np.array_equal(out["stamp"], stamps)
    for key, want in (("along_m", along), ("left_m", left), ("up_m", up), ("yaw_deg", yaw)):
        np.testing.assert_allclose(out[key], want, atol=1e-9, err_msg=key)


def test_per_frame_errors_align_the_first_poses_as_the_end_point_drift(case):
    stamps, G, (along, left, up, yaw) = case
    E = _with_errors(G, along, left, up, yaw)
    W = np.eye(4)  # the estimate in another world frame: the first-pose alignment undoes it
    W[:3, :3] = g.rot_z(1.1) @ g.mount_rotation(0.3, -0.2)
    W[:3, 3] = [4.0, -2.0, 0.5]
    out = per_frame_errors(stamps, W[None] @ E, stamps, G)
    np.testing.assert_allclose(out["along_m"], along, atol=1e-9)
    np.testing.assert_allclose(out["yaw_deg"], yaw, atol=1e-9)
    drift = trajectory_errors(stamps, W[None] @ E, stamps, G)
    last = math.sqrt(out["along_m"][-1] ** 2 + out["left_m"][-1] ** 2 + out["up_m"][-1] ** 2)
    assert last == pytest.approx(drift.endpoint_drift_m, abs=1e-9)
    assert out["yaw_deg"][-1] == pytest.approx(drift.final_yaw_error_deg, abs=1e-9)


def test_per_frame_errors_without_matches_is_none(case):
    stamps, G, _ = case
    assert per_frame_errors(stamps + 100.0, G, stamps, G) is None


def test_evaluate_writes_per_frame_csv(case, tmp_path, capsys):
    stamps, G, (along, left, up, yaw) = case
    run = tmp_path / "run"
    run.mkdir()
    write_tum_trajectory(tmp_path / "gt.tum", Trajectory(stamps, G))
    write_tum_trajectory(run / "raw.tum", Trajectory(stamps, _with_errors(G, along, left, up, yaw)))
    write_tum_trajectory(run / "smoothed.tum", Trajectory(stamps[::2], _with_errors(G, 0.5 * along, left, up, yaw)[::2]))
    out = tmp_path / "errors.csv"
    assert main(["evaluate", str(run), "--gt", str(tmp_path / "gt.tum"), "--per-frame", str(out)]) == 0
    assert f"wrote {out} (errors per frame: raw, smoothed)" in capsys.readouterr().out
    rows = list(csv.DictReader(out.open()))
    assert list(rows[0]) == ["trajectory", "stamp", "along_m", "left_m", "up_m", "yaw_deg"]
    raw = [r for r in rows if r["trajectory"] == "raw"]
    smoothed = [r for r in rows if r["trajectory"] == "smoothed"]
    assert len(raw) == len(stamps) and len(smoothed) == len(stamps[::2])
    # the CSV keeps 6 decimals (metres, degrees)
    np.testing.assert_allclose([float(r["along_m"]) for r in raw], along, atol=1e-6)
    np.testing.assert_allclose([float(r["left_m"]) for r in raw], left, atol=1e-6)
    np.testing.assert_allclose([float(r["along_m"]) for r in smoothed], 0.5 * along[::2], atol=1e-6)
    np.testing.assert_allclose([float(r["yaw_deg"]) for r in smoothed], yaw[::2], atol=1e-6)


def test_evaluate_per_frame_into_a_missing_folder_is_one_line(case, tmp_path, capsys):
    stamps, G, _ = case
    run = tmp_path / "run"
    run.mkdir()
    for name in ("gt", "raw", "smoothed"):
        write_tum_trajectory((tmp_path if name == "gt" else run) / f"{name}.tum", Trajectory(stamps, G))
    code = main(["evaluate", str(run), "--gt", str(tmp_path / "gt.tum"), "--per-frame", str(tmp_path / "no" / "e.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "does not exist" in err[0] and "Traceback" not in err[0]
