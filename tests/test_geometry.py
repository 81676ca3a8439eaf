"""The pinned frames and signs of planar_vo.core.geometry, proven on simulated points."""
import math

import numpy as np
import pytest

from planar_vo.core import geometry as g


def test_mount_angles_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        p, r, y = rng.uniform(-0.5, 0.5, 3)
        assert np.allclose(g.mount_angles(g.mount_rotation(p, r, y)), (p, r, y), atol=1e-12)


def test_positive_pitch_looks_down():
    R_base_cam = g.mount_rotation(math.radians(10), 0.0)
    optical_axis_in_base = R_base_cam[:, 2]
    assert optical_axis_in_base[2] < 0 and optical_axis_in_base[0] > 0


def test_levelling_puts_gravity_on_plus_y():
    rng = np.random.default_rng(1)
    for _ in range(20):
        p, r = rng.uniform(-0.4, 0.4, 2)
        R_base_cam = g.mount_rotation(p, r, rng.uniform(-1, 1))
        down_cam = R_base_cam.T @ np.array([0.0, 0.0, -1.0])
        assert np.allclose(g.levelling_rotation(p, r) @ down_cam, [0, 1, 0], atol=1e-12)
        assert np.allclose(g.tilt_from_gravity(down_cam), (p, r), atol=1e-12)


def test_levelled_yaw_is_rep103_yaw_increment():
    """A robot turning left by psi sees static points move by X2 = R_y(psi) X1 + t."""
    rng = np.random.default_rng(2)
    pose1 = np.array([1.0, -2.0, 0.3])
    step = np.array([0.4, 0.1, 0.2])  # base2 in base1: forward, a bit left, turning left
    pose2 = g.se2_compose(pose1, step)
    m = np.array([0.1, 0.0, 0.0])  # camera 10 cm ahead of base, no mount yaw
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = g.mount_rotation(0.17, 0.03)
    T_base_cam[:3, 3] = [m[0], m[1], 0.8]
    R_lev_cam = g.levelling_rotation(0.17, 0.03)
    X_world = rng.uniform(-3, 3, (10, 3)) + [5, 0, 1]
    lev = []
    for pose in (pose1, pose2):
        T_world_cam = g.se2_to_matrix(pose) @ T_base_cam
        X_cam = (np.linalg.inv(T_world_cam) @ np.c_[X_world, np.ones(10)].T)[:3].T
        lev.append(X_cam @ R_lev_cam.T)
    yaw, t = g.pose_to_levelled_motion(g.base_step_to_lev_step(step, g.mount_se2(T_base_cam)))
    assert yaw == pytest.approx(0.2)
    assert abs(t[1]) < 1e-12
    assert np.allclose(lev[1], lev[0] @ g.rot_y(yaw).T + t, atol=1e-9)
    # and back to base
    back = g.lev_step_to_base_step(g.levelled_motion_to_pose(yaw, t), g.mount_se2(T_base_cam))
    assert np.allclose(back, step, atol=1e-12)


def test_se2_algebra():
    a, b = np.array([1.0, 2.0, 0.5]), np.array([-0.3, 0.7, -1.2])
    assert np.allclose(g.se2_between(a, g.se2_compose(a, b)), b)
    assert np.allclose(g.se2_compose(a, g.se2_inverse(a)), 0, atol=1e-12)
    Ta, Tb = g.se2_to_matrix(a), g.se2_to_matrix(b)
    assert np.allclose(g.se2_to_matrix(g.se2_compose(a, b)), Ta @ Tb)
    poses = g.se2_chain([b, b])
    assert np.allclose(poses[2], g.se2_compose(b, b))


def test_quaternion_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[3] >= 0 else -q
        assert np.allclose(g.quat_from_matrix(g.matrix_from_quat(q)), q, atol=1e-12)
    T = g.matrix_from_pose7([1, 2, 3, 0, 0, math.sin(0.2), math.cos(0.2)])
    assert np.allclose(g.pose7_from_matrix(T)[:3], [1, 2, 3])
    assert g.yaw_of_cam(g.se2_to_matrix([0, 0, 0.4]) @ np.block([[g.R_BASE_OPTICAL, np.zeros((3, 1))], [0, 0, 0, 1]])) == pytest.approx(0.4)
