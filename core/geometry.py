"""Frames, signs and small rigid-body helpers, pinned once for the whole project.

Frames
------
``cam``  camera optical frame: x right, y down, z forward (ROS ``*_optical_frame``).
``lev``  levelled camera frame: origin at the camera centre, the camera's pitch and
         roll removed, so y points along gravity (down), x right and z forward in
         the horizontal plane; it keeps the camera's heading.
``base`` robot ``base_link`` (REP 103): x forward, y left, z up, on the floor.
``odom`` / ``world``: fixed, z up; ``odom`` coincides with ``base`` at the first frame.

Naming: ``R_a_b`` / ``T_a_b`` map coordinates in frame ``b`` to frame ``a``
(``X_a = R_a_b @ X_b + t_a_b``); equivalently they are the pose of ``b`` in ``a``.

Mount angles (REP 103, intrinsic Z-Y-X about base axes)
-------------------------------------------------------
``R_base_cam = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll) @ R_BASE_OPTICAL``.
``pitch > 0`` tilts the camera to look down at the floor, ``roll > 0`` turns the
image's right side down (about the forward axis), ``yaw > 0`` turns it left.

Planar motion between levelled frames
--------------------------------------
A step from view 1 to view 2 is ``X_lev2 = R_y(yaw) @ X_lev1 + t`` with
``R_y(yaw) = [[cos, 0, sin], [0, 1, 0], [-sin, 0, cos]]`` and ``t[1] = 0``.
With this sign, ``yaw`` equals the robot's REP 103 yaw increment (turning left is
positive): a point straight ahead moves to the right (+x) in view 2.

SE(2) poses are ``(x, y, theta)`` float64 arrays, ``theta`` in radians, matching
``gtsam.Pose2`` and its tangent order ``[x, y, theta]``.
"""
from __future__ import annotations

import math

import numpy as np

#: Optical frame of an untilted, forward-looking camera expressed in ``base``:
#: columns are the optical x (right -> -y_base), y (down -> -z_base), z (forward -> +x_base).
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def wrap_angle(a):
    """Wrap angle(s) to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def wrap_quarter(a):
    """Wrap angle(s) to [-pi/4, pi/4): the Manhattan 90-degree ambiguity."""
    return (np.asarray(a) + np.pi / 4.0) % (np.pi / 2.0) - np.pi / 4.0


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Right-handed rotation about y. In ``lev`` (y down) this is ``R_y(yaw)`` above."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def mount_rotation(pitch: float, roll: float, yaw: float = 0.0) -> np.ndarray:
    """``R_base_cam`` (3, 3) of a camera mounted with REP 103 angles (radians)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll) @ R_BASE_OPTICAL


def mount_angles(R_base_cam: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`mount_rotation`: ``(pitch, roll, yaw)`` in radians."""
    M = np.asarray(R_base_cam, dtype=float) @ R_BASE_OPTICAL.T  # = Rz Ry Rx
    pitch = math.asin(max(-1.0, min(1.0, -M[2, 0])))
    roll = math.atan2(M[2, 1], M[2, 2])
    yaw = math.atan2(M[1, 0], M[0, 0])
    return pitch, roll, yaw


def levelling_rotation(pitch: float, roll: float) -> np.ndarray:
    """``R_lev_cam`` (3, 3): removes the mount pitch and roll, keeps the heading.

    ``X_lev = R_lev_cam @ X_cam``; afterwards gravity is +y in ``lev``.
    """
    return R_BASE_OPTICAL.T @ rot_y(pitch) @ rot_x(roll) @ R_BASE_OPTICAL


def tilt_from_gravity(g_cam: np.ndarray) -> tuple[float, float]:
    """Mount ``(pitch, roll)`` from the gravity direction (down) seen in ``cam``.

    ``g_cam`` is any non-zero (3,) vector pointing down, e.g. minus the floor normal.
    """
    g = np.asarray(g_cam, dtype=float)
    g = g / np.linalg.norm(g)
    # In base, down is -z; in cam it is R_cam_base @ (0, 0, -1). With R_BASE_OPTICAL
    # absorbed this reads g = R_BASE_OPTICAL^T Rx(-roll) Ry(-pitch) (0, 0, -1).
    gb = R_BASE_OPTICAL @ g  # = Rx(roll)^T Ry(pitch)^T (0,0,-1)
    # Ry(p)^T (0,0,-1) = (sin p, 0, -cos p); Rx(r)^T (a,0,b) = (a, b sin r, b cos r)
    pitch = math.atan2(gb[0], math.hypot(gb[1], gb[2]))
    roll = math.atan2(-gb[1], -gb[2])
    return pitch, roll


# ----------------------------------------------------------------------------- SE(2)

def largest_sigma(cov) -> float:
    """Standard deviation along the most uncertain direction of a (2, 2) covariance."""
    return math.sqrt(max(float(np.linalg.eigvalsh(np.asarray(cov, dtype=float))[-1]), 0.0))


def se2_compose(a, b) -> np.ndarray:
    """``a * b`` for SE(2) poses ``(x, y, theta)``."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = math.cos(at), math.sin(at)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, float(wrap_angle(at + bt))])


def se2_inverse(a) -> np.ndarray:
    x, y, t = a
    c, s = math.cos(t), math.sin(t)
    return np.array([-c * x - s * y, s * x - c * y, float(wrap_angle(-t))])


def se2_between(a, b) -> np.ndarray:
    """``a^-1 * b``: pose of ``b`` in the frame of ``a``."""
    return se2_compose(se2_inverse(a), b)


def se2_chain(steps) -> np.ndarray:
    """Chain relative steps (M, 3) into poses (M + 1, 3) starting at the origin."""
    poses = [np.zeros(3)]
    for s in steps:
        poses.append(se2_compose(poses[-1], s))
    return np.array(poses)


def se2_to_matrix(p) -> np.ndarray:
    """SE(2) ``(x, y, theta)`` lifted to a (4, 4) SE(3) matrix in a z-up frame (z = 0)."""
    x, y, t = p
    T = np.eye(4)
    T[:3, :3] = rot_z(t)
    T[0, 3], T[1, 3] = x, y
    return T


# ------------------------------------------------- levelled planar motion <-> base SE(2)

def levelled_motion_to_pose(yaw: float, t) -> np.ndarray:
    """Planar motion ``X_lev2 = R_y(yaw) X_lev1 + t`` as the SE(2) pose of lev2 in lev1.

    The 2-D frame of ``lev`` is REP 103-like: x = z_lev (forward), y = -x_lev (left).
    """
    t = np.asarray(t, dtype=float)
    c = -rot_y(yaw).T @ t  # lev2 origin in lev1
    return np.array([c[2], -c[0], float(wrap_angle(yaw))])


def pose_to_levelled_motion(p) -> tuple[float, np.ndarray]:
    """Inverse of :func:`levelled_motion_to_pose`: ``(yaw, t)`` with t (3,)."""
    x, y, yaw = p
    c = np.array([-y, 0.0, x])
    return float(yaw), -rot_y(yaw) @ c


def mount_se2(T_base_cam: np.ndarray) -> np.ndarray:
    """Planar part ``(x, y, yaw)`` of the camera mount: pose of ``lev`` in ``base``."""
    _, _, yaw = mount_angles(np.asarray(T_base_cam)[:3, :3])
    return np.array([T_base_cam[0, 3], T_base_cam[1, 3], yaw])


def lev_step_to_base_step(p_lev1_lev2, m_base_lev) -> np.ndarray:
    """Conjugate a levelled-camera SE(2) step into a base_link step ``T_base1_base2``."""
    return se2_compose(se2_compose(m_base_lev, p_lev1_lev2), se2_inverse(m_base_lev))


def base_step_to_lev_step(p_base1_base2, m_base_lev) -> np.ndarray:
    return se2_compose(se2_compose(se2_inverse(m_base_lev), p_base1_base2), m_base_lev)


def base_poses_to_cam_matrices(poses_odom_base: np.ndarray, T_base_cam: np.ndarray) -> np.ndarray:
    """Camera optical poses ``T_odom_cam`` (N, 4, 4) from base poses (N, 3) and the mount."""
    return np.stack([se2_to_matrix(p) @ T_base_cam for p in np.asarray(poses_odom_base)])


# ----------------------------------------------------------------------- quaternions

def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(qx, qy, qz, qw)`` (TUM / ROS order) of a (3, 3) rotation, qw >= 0."""
    R = np.asarray(R, dtype=float)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quat(q) -> np.ndarray:
    """(3, 3) rotation from ``(qx, qy, qz, qw)``; the quaternion is normalised first."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_from_pose7(p) -> np.ndarray:
    """(4, 4) from ``(tx, ty, tz, qx, qy, qz, qw)``."""
    T = np.eye(4)
    T[:3, :3] = matrix_from_quat(p[3:7])
    T[:3, 3] = p[:3]
    return T


def pose7_from_matrix(T) -> np.ndarray:
    """``(tx, ty, tz, qx, qy, qz, qw)`` from a (4, 4) matrix."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[:3, 3], quat_from_matrix(T[:3, :3])])


def yaw_of_cam(T_world_cam: np.ndarray) -> float:
    """Heading (about world z, REP 103) of a camera's optical axis projected on the floor."""
    z = np.asarray(T_world_cam)[:3, 2]
    return math.atan2(z[1], z[0])
