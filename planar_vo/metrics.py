"""Trajectory accuracy metrics (pure: arrays in, numbers out).

All trajectories are camera optical-frame poses ``T_world_cam`` (N, 4, 4) in a z-up
world. Estimates and ground truth are associated by timestamp first.

* ATE RMSE: position RMSE after the least-squares SE(3) alignment (Umeyama, no scale).
* RPE per metre: for every pose pair ``delta`` metres of ground-truth path apart, the
  relative-motion error; translation as a fraction of ``delta`` (m/m), rotation in deg/m.
* End-point drift: distance between the final positions after aligning the first poses,
  as a percentage of the ground-truth path length (the paper's metric, Sec. 3.2).
* Final yaw error: heading difference (about world z) of the final poses after the same
  first-pose alignment, in degrees.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from planar_vo.geometry import wrap_angle, yaw_of_cam


def associate(stamps_a: np.ndarray, stamps_b: np.ndarray, max_dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(ia, ib)`` matching each stamp of ``a`` to the nearest of ``b`` within ``max_dt`` s.

    Each ``b`` stamp is used at most once (the closest ``a`` wins); both arrays sorted ascending.
    """
    a = np.asarray(stamps_a, dtype=float)
    b = np.asarray(stamps_b, dtype=float)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    j = np.clip(np.searchsorted(b, a), 1, len(b) - 1) if len(b) > 1 else np.zeros(len(a), int)
    if len(b) > 1:
        left_better = np.abs(a - b[j - 1]) <= np.abs(a - b[j])
        j = np.where(left_better, j - 1, j)
    dt = np.abs(a - b[j])
    ok = dt <= max_dt
    ia, ib, dt = np.nonzero(ok)[0], j[ok], dt[ok]
    # keep the closest a for every b
    order = np.lexsort((dt, ib))
    ia, ib = ia[order], ib[order]
    first = np.ones(len(ib), bool)
    first[1:] = ib[1:] != ib[:-1]
    ia, ib = ia[first], ib[first]
    o = np.argsort(ia)
    return ia[o], ib[o]


def umeyama_se3(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(4, 4) rigid transform ``T`` minimising ``sum |dst - T src|^2`` for (N, 3) point sets."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama_se3: expected two (N, 3) arrays, got {src.shape} and {dst.shape}")
    T = np.eye(4)
    if len(src) == 0:
        return T
    mu_s, mu_d = src.mean(0), dst.mean(0)
    if len(src) < 3:
        T[:3, 3] = mu_d - mu_s
        return T
    C = (dst - mu_d).T @ (src - mu_s) / len(src)
    U, _, Vt = np.linalg.svd(C)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    T[:3, :3] = R
    T[:3, 3] = mu_d - R @ mu_s
    return T


def path_length(positions: np.ndarray) -> float:
    p = np.asarray(positions, dtype=float)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def _rot_angle(R: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0)))


@dataclass
class TrajectoryErrors:
    """Errors of one estimated trajectory against ground truth."""

    matched: int
    path_length_m: float
    ate_rmse_m: float
    rpe_trans_per_m: float
    rpe_rot_deg_per_m: float
    endpoint_drift_m: float
    endpoint_drift_pct: float
    final_yaw_error_deg: float

    def as_dict(self) -> dict:
        return asdict(self)


def trajectory_errors(est_stamps, est_poses, gt_stamps, gt_poses, *, max_dt: float = 0.02,
                      rpe_delta_m: float = 1.0) -> TrajectoryErrors:
    """Compare ``est_poses`` (N, 4, 4) to ``gt_poses`` (M, 4, 4); see the module docstring."""
    est_poses = np.asarray(est_poses, dtype=float)
    gt_poses = np.asarray(gt_poses, dtype=float)
    ia, ib = associate(est_stamps, gt_stamps, max_dt)
    nan = float("nan")
    if len(ia) < 2:
        return TrajectoryErrors(len(ia), nan, nan, nan, nan, nan, nan, nan)
    E, G = est_poses[ia], gt_poses[ib]
    pe, pg = E[:, :3, 3], G[:, :3, 3]
    length = path_length(pg)

    T = umeyama_se3(pe, pg)
    aligned = (T[:3, :3] @ pe.T).T + T[:3, 3]
    ate = float(np.sqrt(np.mean(np.sum((aligned - pg) ** 2, axis=1))))

    # RPE over segments of ~rpe_delta_m metres of ground-truth path.
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pg, axis=0), axis=1))])
    t_err, r_err = [], []
    for i in range(len(cum)):
        j = int(np.searchsorted(cum, cum[i] + rpe_delta_m))
        if j >= len(cum):
            break
        dg = np.linalg.inv(G[i]) @ G[j]
        de = np.linalg.inv(E[i]) @ E[j]
        err = np.linalg.inv(dg) @ de
        seg = cum[j] - cum[i]
        t_err.append(np.linalg.norm(err[:3, 3]) / seg)
        r_err.append(math.degrees(_rot_angle(err[:3, :3])) / seg)
    rpe_t = float(np.mean(t_err)) if t_err else nan
    rpe_r = float(np.mean(r_err)) if r_err else nan

    A = G[0] @ np.linalg.inv(E[0])  # first-pose alignment
    end = A @ E[-1]
    drift = float(np.linalg.norm(end[:3, 3] - G[-1][:3, 3]))
    yaw_err = math.degrees(float(wrap_angle(yaw_of_cam(end) - yaw_of_cam(G[-1]))))
    return TrajectoryErrors(
        matched=int(len(ia)),
        path_length_m=length,
        ate_rmse_m=ate,
        rpe_trans_per_m=rpe_t,
        rpe_rot_deg_per_m=rpe_r,
        endpoint_drift_m=drift,
        endpoint_drift_pct=100.0 * drift / length if length > 0 else nan,
        final_yaw_error_deg=yaw_err,
    )


def planarity(gt_poses: np.ndarray) -> dict:
    """How planar a camera trajectory is: height range (m) and tilt range (deg) of its optical axis.

    A robot on a flat floor keeps both near zero; a handheld camera does not.
    """
    P = np.asarray(gt_poses, dtype=float)
    z = P[:, 2, 3]
    # Angle between the camera's y (down) axis and world down, per pose.
    down = P[:, :3, 1] @ np.array([0.0, 0.0, -1.0])
    tilt = np.degrees(np.arccos(np.clip(down, -1.0, 1.0)))
    return {"height_range_m": float(np.ptp(z)) if len(z) else 0.0,
            "tilt_range_deg": float(np.ptp(tilt)) if len(tilt) else 0.0}
