"""Trajectory metrics against hand-built trajectories with known errors."""
import math

import numpy as np
import pytest

from planar_vo.core import geometry as g
from planar_vo.io.trajectory import associate_stamps
from planar_vo.metrics import path_length, planarity, trajectory_errors


def _cam_poses(poses_se2, height=0.8):
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = g.mount_rotation(0.17, 0.0)
    T_base_cam[2, 3] = height
    return g.base_poses_to_cam_matrices(poses_se2, T_base_cam)


def test_associate_nearest_unique():
    ia, ib = associate_stamps(np.array([0.0, 0.1, 0.2, 0.5]), np.array([0.005, 0.11, 0.3]), 0.02)
    assert ia.tolist() == [0, 1] and ib.tolist() == [0, 1]


def test_errors_of_known_drift():
    n = 101
    stamps = np.arange(n) * 0.1
    gt = np.stack([np.linspace(0, 10, n), np.zeros(n), np.zeros(n)], 1)  # 10 m straight
    est = gt.copy()
    est[:, 2] = np.linspace(0, math.radians(2.0), n)  # yaw drifts to 2 deg
    # chain the true 0.1 m steps along the drifting heading
    poses = [np.zeros(3)]
    for i in range(1, n):
        poses.append(np.array([poses[-1][0] + 0.1 * math.cos(est[i - 1, 2]),
                               poses[-1][1] + 0.1 * math.sin(est[i - 1, 2]), est[i, 2]]))
    e = trajectory_errors(stamps, _cam_poses(np.array(poses)), stamps, _cam_poses(gt))
    assert e.matched == n
    assert e.path_length_m == pytest.approx(10.0)
    assert e.final_yaw_error_deg == pytest.approx(2.0, abs=1e-9)
    expected_drift = np.linalg.norm(np.array(poses)[-1, :2] - gt[-1, :2])
    assert e.endpoint_drift_pct == pytest.approx(10.0 * expected_drift, rel=1e-9)
    assert 0 < e.ate_rmse_m < expected_drift
    assert e.ate_alignment == "first_pose"  # a straight path leaves the SE(3) alignment undetermined
    perfect = trajectory_errors(stamps, _cam_poses(gt), stamps, _cam_poses(gt))
    assert perfect.ate_rmse_m < 1e-12 and perfect.endpoint_drift_m < 1e-12
    assert perfect.rpe_trans_per_m < 1e-12


def test_planarity_flags_handheld_motion():
    n = 50
    gt = np.stack([np.linspace(0, 5, n), np.zeros(n), np.zeros(n)], 1)
    flat = planarity(_cam_poses(gt))
    assert flat["height_range_m"] < 1e-12 and flat["tilt_range_deg"] < 1e-9
    bumpy = _cam_poses(gt)
    bumpy[:, 2, 3] += np.linspace(0, 0.3, n)
    assert planarity(bumpy)["height_range_m"] == pytest.approx(0.3)
    assert path_length(np.zeros((1, 3))) == 0.0


def test_rpe_is_nan_when_the_path_is_shorter_than_its_segment():
    n = 11
    stamps = np.arange(n) * 0.1
    gt = np.stack([np.linspace(0, 0.5, n), np.zeros(n), np.zeros(n)], 1)  # 0.5 m < the 1 m RPE segment
    e = trajectory_errors(stamps, _cam_poses(gt), stamps, _cam_poses(gt))
    assert e.matched == n and math.isnan(e.rpe_trans_per_m) and math.isnan(e.rpe_rot_deg_per_m)
    assert e.ate_rmse_m < 1e-12
