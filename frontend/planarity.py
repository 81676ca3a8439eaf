"""Is the camera really moving on a plane? A 6-DoF check on 3-D/3-D matches.

The planar estimators cannot see motion they do not model, so each frame pair is also fitted
with a general rigid motion (3-point RANSAC + Kabsch/Umeyama over the inliers) in the
levelled frame. For a robot on a flat floor its rotation axis is vertical and its vertical
translation zero; a handheld camera shows tilt changes and vertical motion. The pipeline
turns these per-step figures into the run's planarity verdict.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class OutOfPlane:
    """6-DoF motion between two levelled views, reduced to what planar motion forbids.

    ``tilt_deg``: angle by which the rotation moves the vertical axis (0 for planar motion).
    ``dy_m``: vertical translation in metres (0 for planar motion). ``inliers``: support.
    """

    tilt_deg: float
    dy_m: float
    inliers: int
    R: np.ndarray  # (3, 3) rotation of the fit, ``P2 ~ R P1 + t``
    t: np.ndarray  # (3,)


def _kabsch(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched rigid fit ``B ~ R A + t`` for (..., n, 3) point sets."""
    ca, cb = A.mean(-2, keepdims=True), B.mean(-2, keepdims=True)
    H = np.swapaxes(A - ca, -1, -2) @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cb[..., 0, :] - (R @ ca[..., 0, :, None])[..., 0]
    return R, t


def out_of_plane_motion(P1: np.ndarray, P2: np.ndarray, *, seed: int = 0, iterations: int = 64,
                        rel_threshold: float = 0.02, min_inliers: int = 8) -> OutOfPlane | None:
    """Fit ``P2 ~ R P1 + t`` robustly and report its non-planar part.

    ``P1``, ``P2``: (N, 3) float64 levelled points (metres) of the same features in views 1
    and 2 (finite rows only). Inlier test: residual below ``rel_threshold`` times depth.
    Returns None when fewer than ``min_inliers`` points support any hypothesis.
    """
    P1 = np.asarray(P1, dtype=float)
    P2 = np.asarray(P2, dtype=float)
    if P1.shape != P2.shape or P1.ndim != 2 or P1.shape[1] != 3:
        raise ValueError(f"out_of_plane_motion: expected two (N, 3) arrays, got {P1.shape} and {P2.shape}")
    n = len(P1)
    if n < max(3, min_inliers):
        return None
    rng = np.random.default_rng(seed)
    # Three distinct indices per hypothesis, uniformly, drawn for all hypotheses at once
    # (a per-sample ``rng.choice`` costs more than the whole fit): the second skips the
    # first, the third skips both.
    a = rng.integers(0, n, iterations)
    b = rng.integers(0, n - 1, iterations)
    b += b >= a
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    c = rng.integers(0, n - 2, iterations)
    c += c >= lo
    c += c >= hi
    idx = np.stack([a, b, c], axis=1)
    R, t = _kabsch(P1[idx], P2[idx])
    # Residuals |R P1 + t - P2| of every point under every hypothesis, (k, n), one
    # coordinate at a time on contiguous (k, n) arrays (a generic einsum and a norm over a
    # length-3 axis cost more than the rest of the function). Products summed as
    # (x0 + x2) + x1, the order numpy's einsum used, so that the figures do not move.
    X, Y, Z = (np.ascontiguousarray(P1[:, j]) for j in range(3))
    sq = None
    for i in range(3):
        r = X * R[:, i, 0, None]
        r += Z * R[:, i, 2, None]
        r += Y * R[:, i, 1, None]
        r += t[:, i, None]
        r -= P2[:, i]
        r *= r
        sq = r if sq is None else sq + r
    res = np.sqrt(sq)
    thr = rel_threshold * np.maximum(P2[:, 2], 0.5)
    inl = res < thr[None]
    best = inl.sum(1).argmax()
    mask = inl[best]
    if mask.sum() < min_inliers:
        return None
    for _ in range(2):  # refit over the inliers, re-select
        Rb, tb = _kabsch(P1[mask], P2[mask])
        mask = np.linalg.norm(P1 @ Rb.T + tb - P2, axis=1) < thr
        if mask.sum() < min_inliers:
            return None
    y = np.array([0.0, 1.0, 0.0])
    tilt = math.degrees(math.acos(min(1.0, max(-1.0, float(y @ Rb @ y)))))
    # Translation of the camera centre along gravity: view-2 origin in view 1 is -R^T t.
    dy = float(-(Rb.T @ tb)[1])
    return OutOfPlane(tilt, dy, int(mask.sum()), Rb, tb)
