"""Trajectory accuracy metrics: ATE and RPE from evo, the paper's figures on top.

All trajectories are camera optical-frame poses ``T_world_cam`` (N, 4, 4) in a z-up
world. Estimates and ground truth are associated by timestamp first (``evo.core.sync``).

* ATE RMSE: position RMSE after the least-squares SE(3) alignment (Umeyama, no scale) --
  ``evo_ape tum GT EST -a --t_max_diff MAX_DT``; on a straight ground-truth path, where that
  alignment is undetermined, after aligning the first poses (``--align_origin``).
* RPE per metre: for every ground-truth pose, the pose :data:`RPE_DELTA_M` metres of
  ground-truth path further on (within 10 %), the relative-motion error; translation in
  m per metre, rotation in deg per metre -- ``evo_rpe tum GT EST -r trans_part|angle_deg
  -d 1 -u m --all_pairs --pairs_from_reference --t_max_diff MAX_DT`` (mean, divided by the delta).
* End-point drift: distance between the final positions after aligning the first poses,
  as a percentage of the ground-truth path length (the paper's metric, Sec. 3.2).
* Final yaw error: heading difference (about world z) of the final poses after the same
  first-pose alignment, in degrees.

evo is the tool readers of trajectory figures use, so its numbers are taken as they are:
``tests/test_evaluate_evo.py`` checks that ``planar-vo evaluate`` agrees with ``evo_ape`` and
``evo_rpe`` run on the same files.
"""
from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass

import numpy as np
from evo.core import metrics, sync
from evo.core.filters import FilterException
from evo.core.geometry import GeometryException
from evo.core.trajectory import PoseTrajectory3D

from planar_vo.core.geometry import wrap_angle, yaw_of_cam

#: RPE segment length along the ground-truth path (m) and its relative tolerance.
RPE_DELTA_M = 1.0
RPE_DELTA_TOL = 0.1


def path_length(positions: np.ndarray) -> float:
    p = np.asarray(positions, dtype=float)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


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
    #: how the estimate was aligned for the ATE (:func:`ate_rmse`)
    ate_alignment: str = "se3"

    def as_dict(self) -> dict:
        return asdict(self)


def evo_trajectory(stamps, poses) -> PoseTrajectory3D:
    """An evo trajectory from (N,) stamps in s and (N, 4, 4) poses."""
    return PoseTrajectory3D(poses_se3=list(np.asarray(poses, dtype=float)),
                            timestamps=np.asarray(stamps, dtype=float))


def ate_rmse(gt: PoseTrajectory3D, est: PoseTrajectory3D) -> tuple[float, str]:
    """Position RMSE (m) of ``est`` after alignment to ``gt`` (both synchronised), and the alignment.

    ``"se3"``: Umeyama SE(3), as ``evo_ape -a``. When the ground-truth positions lie on a line
    (a robot driving straight) the rotation about that line is undetermined and evo refuses
    Umeyama; then ``"first_pose"``: the first poses made equal, as ``evo_ape --align_origin``.
    """
    aligned = copy.deepcopy(est)
    try:
        aligned.align(gt, correct_scale=False)
        how = "se3"
    except GeometryException:
        aligned = copy.deepcopy(est)
        aligned.align_origin(gt)
        how = "first_pose"
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((gt, aligned))
    return float(ape.get_statistic(metrics.StatisticsType.rmse)), how


def rpe_per_metre(gt: PoseTrajectory3D, est: PoseTrajectory3D, relation: metrics.PoseRelation,
                  delta_m: float = RPE_DELTA_M) -> float:
    """Mean relative error over ``delta_m`` metres of ground-truth path, per metre; nan if no pair."""
    rpe = metrics.RPE(relation, delta=delta_m, delta_unit=metrics.Unit.meters, rel_delta_tol=RPE_DELTA_TOL,
                      all_pairs=True, pairs_from_reference=True)
    try:
        rpe.process_data((gt, est))
    except (metrics.MetricsException, FilterException):  # no pair of poses delta_m apart
        return float("nan")
    return float(rpe.get_statistic(metrics.StatisticsType.mean)) / delta_m


def _associate(est_stamps, est_poses, gt_stamps, gt_poses, max_dt: float):
    """``(gt, est)`` evo trajectories of the poses matched by stamp (``evo.core.sync``), or
    None when no stamp is in common."""
    try:
        return sync.associate_trajectories(evo_trajectory(gt_stamps, gt_poses),
                                           evo_trajectory(est_stamps, est_poses), max_diff=max_dt)
    except sync.SyncException:
        return None


def _first_pose_aligned(E: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``E`` (K, 4, 4) moved so that its first pose is ``G[0]``: the paper's end-point drift
    alignment."""
    return (G[0] @ np.linalg.inv(E[0]))[None] @ E


def trajectory_errors(est_stamps, est_poses, gt_stamps, gt_poses, *, max_dt: float = 0.02,
                      rpe_delta_m: float = RPE_DELTA_M) -> TrajectoryErrors:
    """Compare ``est_poses`` (N, 4, 4) to ``gt_poses`` (M, 4, 4); see the module docstring."""
    nan = float("nan")
    pair = _associate(est_stamps, est_poses, gt_stamps, gt_poses, max_dt)
    if pair is None:  # no stamp in common
        return TrajectoryErrors(0, nan, nan, nan, nan, nan, nan, nan)
    gt, est = pair
    if est.num_poses < 2:
        return TrajectoryErrors(est.num_poses, nan, nan, nan, nan, nan, nan, nan)
    G = np.asarray(gt.poses_se3)
    length = path_length(G[:, :3, 3])
    end = _first_pose_aligned(np.asarray(est.poses_se3), G)[-1]
    drift = float(np.linalg.norm(end[:3, 3] - G[-1][:3, 3]))
    ate, alignment = ate_rmse(gt, est)
    return TrajectoryErrors(
        matched=int(est.num_poses),
        path_length_m=length,
        ate_rmse_m=ate,
        ate_alignment=alignment,
        rpe_trans_per_m=rpe_per_metre(gt, est, metrics.PoseRelation.translation_part, rpe_delta_m),
        rpe_rot_deg_per_m=rpe_per_metre(gt, est, metrics.PoseRelation.rotation_angle_deg, rpe_delta_m),
        endpoint_drift_m=drift,
        endpoint_drift_pct=100.0 * drift / length if length > 0 else nan,
        final_yaw_error_deg=math.degrees(float(wrap_angle(yaw_of_cam(end) - yaw_of_cam(G[-1])))),
    )


def per_frame_errors(est_stamps, est_poses, gt_stamps, gt_poses, *, max_dt: float = 0.02) -> dict | None:
    """Where an estimate's error grew: per matched frame, ``est_poses`` (N, 4, 4) against
    ``gt_poses`` (M, 4, 4) after the first-pose alignment of the end-point drift.

    Returns ``{"stamp", "along_m", "left_m", "up_m", "yaw_deg"}``, (K,) float64 each: the
    position error along the ground-truth camera's heading (its optical axis projected on
    the floor), to the left of it and up (world z, REP 103), and the heading error
    (estimate minus truth, wrapped). The last row's ``hypot(along, left, up)`` is the end-point
    drift. A gap at the start of a log shows as a jump in the first frames, a run of steps
    measured short as a ramp in ``along_m``. Rows with a vertical optical axis (no heading)
    are NaN in ``along_m`` and ``left_m``. None when fewer than 2 poses match.
    """
    pair = _associate(est_stamps, est_poses, gt_stamps, gt_poses, max_dt)
    if pair is None or pair[1].num_poses < 2:
        return None
    gt, est = pair
    G = np.asarray(gt.poses_se3)
    E = _first_pose_aligned(np.asarray(est.poses_se3), G)
    d = E[:, :3, 3] - G[:, :3, 3]
    fwd = G[:, :3, 2].copy()
    fwd[:, 2] = 0.0
    norm = np.linalg.norm(fwd, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        fwd = np.where(norm[:, None] > 1e-6, fwd / norm[:, None], np.nan)
    left = np.stack([-fwd[:, 1], fwd[:, 0], np.zeros(len(fwd))], axis=1)  # z x fwd
    yaw = [math.degrees(float(wrap_angle(yaw_of_cam(e) - yaw_of_cam(g)))) for e, g in zip(E, G)]
    return {"stamp": np.asarray(est.timestamps, dtype=float), "along_m": np.einsum("ij,ij->i", d, fwd),
            "left_m": np.einsum("ij,ij->i", d, left), "up_m": d[:, 2], "yaw_deg": np.array(yaw)}


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
