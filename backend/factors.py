"""Factor and noise-model construction for the planar pose graph.

Keys: poses are ``X(k)`` (``gtsam.Pose2``, ``T_odom_base`` of frame ``k``); local Manhattan
frames are ``M(j)``; wall landmarks ``W(l)`` (a 1-vector: the wall's offset, see
:func:`wall_residual`).

Manhattan-frame rotation factor
-------------------------------
Frame ``k`` (world heading ``theta_k``) observes local Manhattan frame ``j`` (world heading
``m_j``, defined modulo 90 deg) at yaw ``yaw_obs`` relative to base_link. With the branch
``b`` fixed by data association the factor's residual is

    r = wrap(m_j - theta_k - (yaw_obs + b * pi / 2)),   dr/dtheta_k = -1,   dr/dm_j = +1.

It constrains heading only, which is what makes the paper's drift-free rotation (Sec. 2.1,
Eq. 1: ``R_ij = (R_i^wc)^T R_j^wc`` through a shared Manhattan frame) global: every view of
the same frame, however far apart in time, ties the two headings together.

Two exact implementations are provided:

* ``native`` (default): ``M(j)`` is a ``Pose2`` whose translation is unused, and the factor
  is a ``BetweenFactorPose2(X(k), M(j), Pose2(0, 0, yaw_obs + b*pi/2))`` whose noise model
  has zero information on the translation rows. The rotation row of the Pose2 ``between``
  error is exactly ``wrap(m_j - theta_k - measured)`` whatever the translations (SE(2)
  rotation composes independently of translation) and its Jacobian row is exactly
  ``[0, 0, -1 | 0, 0, 1]``; the translation rows are whitened to zero. Each ``M(j)`` gets a
  prior with information on its translation only, pinning the unused part so the linear
  systems stay full-rank. Everything runs in C++, which the 10,000-pose budget needs.
* ``custom``: ``M(j)`` is a ``Rot2`` and the factor a ``gtsam.CustomFactor`` with the
  analytic Jacobians above (a Python callback per evaluation; 25x slower in batch LM,
  measured by ``planar-vo bench backend``).
"""
from __future__ import annotations

import math
from functools import partial

import gtsam
import numpy as np
from gtsam.symbol_shorthand import M, W, X

from planar_vo.core.errors import ConfigError

__all__ = ["X", "M", "W", "wall_residual", "wall_factor", "robust_noise", "step_noise", "manhattan_factor", "manhattan_anchor",
           "manhattan_residual", "robust_weight", "manhattan_tie", "manhattan_value",
           "constant_velocity_residual", "constant_velocity_factor", "TWO_PI", "HALF_PI"]

TWO_PI = 2.0 * math.pi
HALF_PI = 0.5 * math.pi

_J_POSE = np.array([[0.0, 0.0, -1.0]])
_J_ROT = np.array([[1.0]])


def _kernel(name: str, parameter: float):
    if name == "huber":
        return gtsam.noiseModel.mEstimator.Huber.Create(parameter)
    if name == "cauchy":
        return gtsam.noiseModel.mEstimator.Cauchy.Create(parameter)
    if name == "none":
        return None
    raise ConfigError(f"config key 'backend.robust_kernel': unknown robust kernel {name!r}; use 'huber', 'cauchy' or 'none'")


def robust_noise(base, kernel: str, parameter: float):
    """Wrap a Gaussian noise model in a robust one (``kernel`` 'huber' | 'cauchy' | 'none')."""
    est = _kernel(kernel, parameter)
    return base if est is None else gtsam.noiseModel.Robust.Create(est, base)


def robust_weight(kernel: str, parameter: float, u: float) -> float:
    """IRLS weight of a whitened residual norm ``u`` (1 = full weight)."""
    if kernel == "huber":
        return 1.0 if u <= parameter else parameter / u
    if kernel == "cauchy":
        return 1.0 / (1.0 + (u / parameter) ** 2)
    return 1.0


def step_noise(information: np.ndarray):
    """Gaussian noise model from a (3, 3) information matrix in Pose2 tangent order."""
    return gtsam.noiseModel.Gaussian.Information(information)


def heading_between_factor(i: int, j: int, yaw: float, variance: float, *, kernel: str, parameter: float):
    """``theta_j - theta_i = yaw`` (rad) at ``variance`` (rad^2), nothing on the translation:
    a ``BetweenFactorPose2(X(i), X(j), Pose2(0, 0, yaw))`` whose noise has zero information
    on the translation rows (its rotation row is exact whatever the translations, as for
    the native Manhattan factor above). A heading change measured from a keyframe."""
    noise = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, 1.0 / variance]))
    return gtsam.BetweenFactorPose2(X(i), X(j), gtsam.Pose2(0.0, 0.0, yaw), robust_noise(noise, kernel, parameter))


def manhattan_residual(theta: float, m: float, measured: float) -> float:
    """``wrap(m - theta - measured)`` in [-pi, pi): the rotation factor's residual."""
    return math.remainder(m - theta - measured, TWO_PI)


def _manhattan_error(keys, measured, this, values, H):
    r = math.remainder(values.atRot2(keys[1]).theta() - values.atPose2(keys[0]).theta() - measured,
                       TWO_PI)
    if H is not None:
        H[0] = _J_POSE
        H[1] = _J_ROT
    return np.array([r])


def manhattan_factor(pose: int, frame: int, measured: float, sigma: float, *, kind: str,
                     kernel: str, parameter: float):
    """Rotation factor between ``X(pose)`` and ``M(frame)`` (see module docstring).

    ``measured = yaw_obs + b * pi / 2`` (rad), ``sigma`` its standard deviation (rad).
    """
    if kind == "native":
        base = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, 1.0 / (sigma * sigma)]))
        return gtsam.BetweenFactorPose2(X(pose), M(frame), gtsam.Pose2(0.0, 0.0, measured),
                                        robust_noise(base, kernel, parameter))
    if kind == "custom":
        keys = [X(pose), M(frame)]
        base = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
        return gtsam.CustomFactor(robust_noise(base, kernel, parameter), keys,
                                  partial(_manhattan_error, keys, measured))
    raise ConfigError(f"config key 'backend.manhattan_factor': unknown Manhattan factor kind {kind!r}; use 'native' or 'custom'")


_ANCHOR_NOISE = gtsam.noiseModel.Diagonal.Precisions(np.array([1.0, 1.0, 0.0]))


def manhattan_anchor(frame: int):
    """Prior pinning the unused translation of a native ``M(frame)`` (no information on yaw)."""
    return gtsam.PriorFactorPose2(M(frame), gtsam.Pose2(0.0, 0.0, 0.0), _ANCHOR_NOISE)


def manhattan_tie(a: int, b: int, sigma: float, kind: str):
    """Equality ``m_b = m_a`` (std ``sigma`` rad) between two instances of one Manhattan frame."""
    if kind == "native":
        noise = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, 1.0 / (sigma * sigma)]))
        return gtsam.BetweenFactorPose2(M(a), M(b), gtsam.Pose2(), noise)
    return gtsam.BetweenFactorRot2(M(a), M(b), gtsam.Rot2(0.0), gtsam.noiseModel.Isotropic.Sigma(1, sigma))


def manhattan_value(yaw: float, kind: str):
    """Initial value of ``M(frame)`` with world heading ``yaw`` (rad)."""
    return gtsam.Pose2(0.0, 0.0, yaw) if kind == "native" else gtsam.Rot2(yaw)


# --- constant body-frame velocity (the motion prior of weak steps) --------------------------

_J90 = np.array([[0.0, -1.0], [1.0, 0.0]])  # d/dtheta R(theta) = R(theta) J90


def _rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def constant_velocity_residual(a, b, c, dt1: float, dt2: float, jacobians: bool = False):
    """Change of the base_link velocity between two consecutive steps: (3,) ``[vx, vy]`` in
    m/s and the yaw rate in rad/s.

    ``a, b, c``: (3,) ``T_odom_base`` (x, y, theta) of frames k-2, k-1, k; ``dt1, dt2`` (s):
    the steps' durations. With ``t1 = R_a^T (p_b - p_a)`` (step k-1 in base_link of k-2),
    ``t2 = R_b^T (p_c - p_b)`` and the yaw steps ``d1 = wrap(theta_b - theta_a)``,
    ``d2 = wrap(theta_c - theta_b)`` the residual is ``(t2 / dt2 - t1 / dt1, d2 / dt2 -
    d1 / dt1)``. A wheeled base keeps its body-frame velocity (forward speed, no sideways
    slip, turn rate) from one step to the next unless it accelerates, so this is a
    white-noise-on-acceleration prior. Zero on an arc driven at constant speed.

    With ``jacobians``: also ``(H_a, H_b, H_c)``, (3, 3) each, with respect to GTSAM's Pose2
    tangent ``[dx, dy, dtheta]`` in the body frame (``X (+) xi = X Exp(xi)``, first order
    ``p += R [dx, dy]``, ``theta += dtheta``).
    """
    Ra, Rb = _rot(a[2]), _rot(b[2])
    t1 = Ra.T @ (np.asarray(b[:2]) - a[:2])
    t2 = Rb.T @ (np.asarray(c[:2]) - b[:2])
    d1 = math.remainder(b[2] - a[2], TWO_PI)
    d2 = math.remainder(c[2] - b[2], TWO_PI)
    r = np.array([*(t2 / dt2 - t1 / dt1), d2 / dt2 - d1 / dt1])
    if not jacobians:
        return r
    # d(R^T v)/dtheta = -J90 R^T v; a body-frame shift du of a pose moves its point by R du.
    H_a = np.zeros((3, 3))
    H_b = np.zeros((3, 3))
    H_c = np.zeros((3, 3))
    H_a[:2, :2], H_a[:2, 2], H_a[2, 2] = np.eye(2) / dt1, _J90 @ t1 / dt1, 1.0 / dt1
    H_b[:2, :2] = -np.eye(2) / dt2 - _rot(b[2] - a[2]) / dt1
    H_b[:2, 2], H_b[2, 2] = -_J90 @ t2 / dt2, -1.0 / dt2 - 1.0 / dt1
    H_c[:2, :2], H_c[2, 2] = _rot(c[2] - b[2]) / dt2, 1.0 / dt2
    return r, (H_a, H_b, H_c)


def _pose_vec(values, key) -> np.ndarray:
    p = values.atPose2(key)
    return np.array([p.x(), p.y(), p.theta()])


def _constant_velocity_error(keys, dt1, dt2, expected, this, values, H):
    a, b, c = (_pose_vec(values, k) for k in keys)
    if H is None:
        return constant_velocity_residual(a, b, c, dt1, dt2) - expected
    r, Hs = constant_velocity_residual(a, b, c, dt1, dt2, jacobians=True)
    for i, h in enumerate(Hs):
        H[i] = h
    return r - expected


def constant_velocity_factor(k: int, dt1: float, dt2: float, sigma, sigma_yaw: float, *,
                             kernel: str = "none", parameter: float = 3.0, expected=None):
    """Motion prior on ``X(k-2), X(k-1), X(k)``: the base_link velocity of step k equals that
    of step k-1 within ``sigma`` (m/s; a scalar, or (2,) for base_link x and y) and
    ``sigma_yaw`` (rad/s) (:func:`constant_velocity_residual`); ``expected``: (3,) the
    change it is expected to have instead of none (a base speeding up from rest). A ``gtsam.CustomFactor``
    (Python callback): added only around steps whose motion vision did not measure, where it
    carries the velocity measured before and after a gap. ``kernel``, ``parameter``: a
    robust kernel (:func:`robust_noise`), so that a base braking where its steps were
    measured is not held to the cruise the prior states."""
    keys = [X(k - 2), X(k - 1), X(k)]
    noise = robust_noise(gtsam.noiseModel.Diagonal.Sigmas(np.array([*np.broadcast_to(np.asarray(sigma, float), 2),
                                                                     sigma_yaw])), kernel, parameter)
    expected = np.zeros(3) if expected is None else np.asarray(expected, float).reshape(3)
    return gtsam.CustomFactor(noise, keys, partial(_constant_velocity_error, keys, float(dt1), float(dt2), expected))


# --- wall landmarks (a vertical wall seen from many poses) ----------------------------------

def wall_residual(pose, m: float, d: float, axis: int, anchor, measured: float, jacobians: bool = False):
    """Offset residual of one wall observation: ``d - n . (t - anchor) - measured`` (m).

    The wall is the line ``{p : n . (p - anchor) = d}`` in odom, its normal
    ``n = (cos a, sin a)`` at ``a = m + axis * pi / 2``: it belongs to the local Manhattan
    frame of heading ``m`` (the instance variable), so the graph never gets a second,
    free wall direction. ``anchor`` (2,) is a fixed point (where the wall was first seen)
    so that ``d`` stays the wall's distance from there and the lever of a heading error is
    the distance travelled along the wall, not the distance from the odom origin.
    ``pose``: (3,) ``T_odom_base`` of the observing frame; ``measured``: the wall's offset
    from base_link along its normal (:class:`planar_vo.core.steps.WallObservation`).

    With ``jacobians``: also ``(H_pose (1, 3), H_m (1, 1), H_d (1, 1))``, ``H_pose`` with
    respect to GTSAM's Pose2 tangent (body-frame ``[dx, dy, dtheta]``; the offset is seen
    from the base_link origin, so it does not depend on the pose's own heading).
    """
    a = m + axis * HALF_PI
    n = np.array([math.cos(a), math.sin(a)])
    rel = np.asarray(pose[:2], dtype=float) - np.asarray(anchor, dtype=float)
    r = d - float(n @ rel) - measured
    if not jacobians:
        return r
    H_pose = np.zeros((1, 3))
    H_pose[0, :2] = -(n @ _rot(pose[2]))
    H_m = np.array([[-float(np.array([-n[1], n[0]]) @ rel)]])
    return r, (H_pose, H_m, np.ones((1, 1)))


def _wall_error(keys, axis, anchor, measured, native, this, values, H):
    p = _pose_vec(values, keys[0])
    m = values.atPose2(keys[1]).theta() if native else values.atRot2(keys[1]).theta()
    d = float(values.atVector(keys[2])[0])
    if H is None:
        return np.array([wall_residual(p, m, d, axis, anchor, measured)])
    r, (h_pose, h_m, h_d) = wall_residual(p, m, d, axis, anchor, measured, jacobians=True)
    H[0] = h_pose
    H[1] = np.array([[0.0, 0.0, h_m[0, 0]]]) if native else h_m
    H[2] = h_d
    return np.array([r])


def wall_factor(pose: int, instance: int, wall: int, axis: int, anchor, measured: float, sigma: float, *,
                kind: str, kernel: str, parameter: float):
    """Factor tying ``X(pose)``, Manhattan instance ``M(instance)`` and wall landmark
    ``W(wall)`` (a 1-vector, the wall's offset from ``anchor``): :func:`wall_residual`,
    std ``sigma`` (m). ``kind``: the Manhattan factor kind (``native`` instances are Pose2,
    ``custom`` ones Rot2). A ``gtsam.CustomFactor``: the back-end adds one per wall only
    every ``wall_spacing_m`` of travel, so the Python callbacks stay a small share."""
    keys = [X(pose), M(instance), W(wall)]
    noise = robust_noise(gtsam.noiseModel.Isotropic.Sigma(1, sigma), kernel, parameter)
    return gtsam.CustomFactor(noise, keys, partial(_wall_error, keys, int(axis),
                                                   np.asarray(anchor, dtype=float).copy(), float(measured),
                                                   kind == "native"))
