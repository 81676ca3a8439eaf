"""Ground truth for loop closure: which keyframes revisit an earlier keyframe's place, and how
far a closure's relative pose is from the true one.

Poses are planar ``T_odom_base`` ``(x, y, theta)`` rows (REP 103 ``base_link`` in ``odom`` or in
the synthetic world: any fixed planar frame, relative poses do not depend on it), one per frame
of a log, e.g. :func:`planar_vo.sim.synth.synth_trajectory`'s or the base poses of the log's
``/ground_truth``. A benchmark counts the keyframes of :func:`revisit_pairs` that its accepted
closures close and checks every accepted closure with :func:`closure_error`.
"""
from __future__ import annotations

import math

import numpy as np

from planar_vo.core.geometry import se2_between, wrap_angle

__all__ = ["revisit_pairs", "revisited_keyframes", "closure_error", "path_distance", "base_poses_from_cam"]


def base_poses_from_cam(T_world_cam, T_base_cam) -> np.ndarray:
    """``T_world_base`` ``(N, 3)`` float64 ``(x, y, theta)`` of camera poses ``T_world_cam`` ``(N, 4, 4)``
    (a log's ``/ground_truth`` or ``LOG.gt.tum``, world z up) and the mount ``T_base_cam`` ``(4, 4)``
    (the log's ``/tf_static``): ``T_world_base = T_world_cam T_base_cam^-1``, projected on the floor."""
    T = np.asarray(T_world_cam, dtype=np.float64).reshape(-1, 4, 4) @ np.linalg.inv(np.asarray(T_base_cam, float))
    return np.column_stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])])


def path_distance(T_odom_base) -> np.ndarray:
    """``(N,)`` float64 metres travelled from frame 0 to each frame (sum of position steps)."""
    P = np.asarray(T_odom_base, dtype=np.float64)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1))])


def _checked(T_odom_base, candidates) -> tuple[np.ndarray, np.ndarray]:
    P = np.asarray(T_odom_base, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all():
        raise ValueError(f"T_odom_base: expected finite (N, 3) poses (x, y, theta), got shape {P.shape}")
    k = np.asarray(candidates)
    if k.ndim != 1 or (len(k) and not np.issubdtype(k.dtype, np.integer)):
        raise ValueError("candidates: expected a 1-D array of integer frame indices")
    k = k.astype(np.int64)
    if len(k) and (k.min() < 0 or k.max() >= len(P)):
        raise ValueError(f"candidates: frame indices must be within [0, {len(P) - 1}]")
    return P, np.unique(k)


def revisit_pairs(T_odom_base, candidates, *, max_distance_m: float = 1.0, max_angle_deg: float = 30.0,
                  min_path_gap_m: float = 5.0) -> list[tuple[int, int]]:
    """Pairs ``(earlier, later)`` of keyframes in the same place: frame indices from ``candidates``
    ``(K,)`` whose base positions in ``T_odom_base`` ``(N, 3)`` float64 are at most
    ``max_distance_m`` apart and whose headings differ by at most ``max_angle_deg``, with at
    least ``min_path_gap_m`` metres driven between them (so that neighbours along the path,
    which any odometry links, do not count). Sorted by ``later``, then ``earlier``; every
    earlier keyframe in reach is listed, so a later one may appear in several pairs.
    Memory is O(K^2) (a few K x K arrays): meant for keyframes, not every frame of a long log.
    """
    if not (max_distance_m >= 0 and max_angle_deg >= 0 and min_path_gap_m >= 0):
        raise ValueError("revisit_pairs: max_distance_m, max_angle_deg and min_path_gap_m must be >= 0")
    P, k = _checked(T_odom_base, candidates)
    s = path_distance(P)[k]
    Q = P[k]
    d = np.linalg.norm(Q[:, None, :2] - Q[None, :, :2], axis=2)
    a = np.abs(wrap_angle(Q[:, None, 2] - Q[None, :, 2]))
    gap = s[None, :] - s[:, None]  # [i, j]: metres driven from keyframe i to keyframe j
    ok = (d <= max_distance_m) & (a <= math.radians(max_angle_deg)) & (gap >= min_path_gap_m)
    ok &= np.arange(len(k))[:, None] < np.arange(len(k))[None, :]
    i, j = np.nonzero(ok)
    order = np.lexsort((i, j))
    return [(int(k[i[o]]), int(k[j[o]])) for o in order]


def revisited_keyframes(pairs) -> list[int]:
    """The later keyframes of ``pairs`` (each once, ascending): the keyframes a loop closer should close."""
    return sorted({int(later) for _, later in pairs})


def closure_error(T_odom_base, earlier: int, later: int, p_earlier_later) -> tuple[float, float]:
    """``(metres, degrees)`` between a closure's relative pose ``p_earlier_later`` (3,) (the later
    base pose in the earlier one's frame, ``(x, y, theta)``) and the true one from ``T_odom_base``."""
    P = np.asarray(T_odom_base, dtype=np.float64)
    true = se2_between(P[int(earlier)], P[int(later)])
    est = np.asarray(p_earlier_later, dtype=np.float64).reshape(3)
    return float(np.linalg.norm(est[:2] - true[:2])), float(abs(math.degrees(wrap_angle(est[2] - true[2]))))
