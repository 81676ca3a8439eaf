"""Two-view planar-motion problems with ground truth, for the solver tests and benchmarks.

Workshop, not product: :func:`make_planar_problem` simulates what the front-end's solvers
(:mod:`planar_vo.frontend.solvers`) and estimators see -- levelled normalised coordinates
and depth points with image noise, depth noise, levelling errors and outliers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.geometry import rot_x, rot_y, rot_z
from planar_vo.frontend.solvers import heading_of_direction


@dataclass
class PlanarProblem:
    """A simulated two-view planar-motion problem with ground truth.

    ``x1``, ``x2``: (N, 2) float64 normalised coordinates as the estimator sees them (after
    levelling with the simulated tilt error, with image noise and outliers). ``P1``, ``P2``:
    (N, 3) float64 levelled 3-D points as the depth sensor sees them (tilt error and depth
    noise included; NaN where depth is missing). ``yaw`` (rad) and ``t`` (3,) metres: the
    true motion ``X2 = R_y(yaw) X1 + t``; ``t_dir`` its unit direction. ``inliers``: (N,)
    bool, False for injected outliers. ``tilt1``, ``tilt2``: (3, 3) the levelling errors
    applied to view 1 / 2 (``X_seen = tilt @ X_true``). ``X1``: (N, 3) true view-1 points.
    ``focal``: pixels. ``wall_heading1/2``: heading of a world wall normal in each view.
    """

    x1: np.ndarray
    x2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    yaw: float
    t: np.ndarray
    inliers: np.ndarray
    X1: np.ndarray
    tilt1: np.ndarray = field(default_factory=lambda: np.eye(3))
    tilt2: np.ndarray = field(default_factory=lambda: np.eye(3))
    focal: float = 1000.0
    wall_heading1: float = 0.0
    wall_heading2: float = 0.0

    @property
    def t_dir(self) -> np.ndarray:
        return self.t / np.linalg.norm(self.t)

    @property
    def R(self) -> np.ndarray:
        return rot_y(self.yaw)


def _tilt(pitch: float, roll: float) -> np.ndarray:
    """Levelling error in ``lev``: pitch about x (right), roll about z (forward)."""
    return rot_x(pitch) @ rot_z(roll)


def make_planar_problem(
    rng: np.random.Generator,
    n: int = 500,
    motion: str = "forward",
    yaw_range_deg: float = 15.0,
    noise_px: float = 0.0,
    focal: float = 1000.0,
    fov_deg: float = 50.0,
    scene_depth: float = 1.0,
    baseline: float = 0.15,
    ground_fraction: float = 0.5,
    camera_height: float = 0.2,
    tilt_error: tuple[float, float] = (0.0, 0.0),
    tilt_mode: str = "shared",
    outlier_ratio: float = 0.0,
    depth_noise: float = 0.0,
    yaw: float | None = None,
    depth_spread: float = 0.5,
) -> PlanarProblem:
    """Simulate the paper's synthetic scene (Sec. 3.1) and a planar motion through it.

    ``n`` points visible in both views, ``ground_fraction`` of them on the floor
    ``camera_height`` below the camera, the rest above it, depths uniform in
    ``scene_depth * [1 - depth_spread, 1 + depth_spread]`` (mean ``scene_depth``; a small
    spread is a far wall, where yaw and sideways translation trade off), inside a ``fov_deg`` square field of
    view. View 2's centre moves by ``baseline * scene_depth`` along view 1's z
    (``"forward"``) or x (``"sideways"``) axis and turns by a yaw uniform in
    ``+-yaw_range_deg`` (or ``yaw`` radians if given). ``noise_px``: Gaussian image noise
    (pixels, at ``focal``). ``tilt_error``: (pitch, roll) standard deviations (rad) of the
    levelling error, drawn once for both views (``"shared"``: a miscalibrated mount) or per
    view (``"independent"``). ``outlier_ratio``: that fraction of view-2 observations
    replaced by random image points. ``depth_noise``: relative depth noise (sigma = this * Z^2
    / scene_depth) added to ``P1``/``P2`` along the viewing rays.
    """
    if motion not in ("forward", "sideways"):
        raise ValueError(f"motion must be 'forward' or 'sideways', got {motion!r}")
    if tilt_mode not in ("shared", "independent"):
        raise ValueError(f"tilt_mode must be 'shared' or 'independent', got {tilt_mode!r}")
    half = math.tan(math.radians(fov_deg) / 2.0)
    if yaw is None:
        yaw = math.radians(rng.uniform(-yaw_range_deg, yaw_range_deg))
    R = rot_y(yaw)
    b = baseline * scene_depth
    c2 = np.array([0.0, 0.0, b]) if motion == "forward" else np.array([b, 0.0, 0.0])
    t = -R @ c2  # camera-2 centre at c2 in view 1: X2 = R (X1 - c2)
    h = camera_height * scene_depth
    if not 0.0 <= depth_spread < 1.0:
        raise ValueError(f"depth_spread must be in [0, 1), got {depth_spread}")
    zlo, zhi = (1.0 - depth_spread) * scene_depth, (1.0 + depth_spread) * scene_depth

    n_ground = int(round(ground_fraction * n))
    pts: list[np.ndarray] = []
    for count, ground in ((n_ground, True), (n - n_ground, False)):
        got = 0
        while got < count:
            m = 4 * (count - got) + 16
            Z = rng.uniform(zlo, zhi, m)
            X = rng.uniform(-half, half, m) * Z
            Y = np.full(m, h) if ground else rng.uniform(-half, half, m) * Z
            P = np.stack([X, Y, Z], axis=1)
            Q = P @ R.T + t
            keep = (np.abs(Y / Z) <= half) & (Q[:, 2] > 0.1 * scene_depth)
            keep &= (np.abs(Q[:, 0] / np.maximum(Q[:, 2], 1e-9)) <= half)
            keep &= np.abs(Q[:, 1] / np.maximum(Q[:, 2], 1e-9)) <= half
            if not ground:
                keep &= Y < h - 1e-3 * scene_depth  # strictly above the floor
            P = P[keep][: count - got]
            pts.append(P)
            got += len(P)
    X1 = np.concatenate(pts)
    X2 = X1 @ R.T + t

    sp, sr = tilt_error
    E1 = _tilt(rng.normal(0.0, sp) if sp > 0 else 0.0, rng.normal(0.0, sr) if sr > 0 else 0.0)
    if tilt_mode == "shared":
        E2 = E1
    else:
        E2 = _tilt(rng.normal(0.0, sp) if sp > 0 else 0.0, rng.normal(0.0, sr) if sr > 0 else 0.0)
    S1 = X1 @ E1.T
    S2 = X2 @ E2.T
    x1 = S1[:, :2] / S1[:, 2:3]
    x2 = S2[:, :2] / S2[:, 2:3]
    if noise_px > 0:
        x1 = x1 + rng.normal(0.0, noise_px / focal, x1.shape)
        x2 = x2 + rng.normal(0.0, noise_px / focal, x2.shape)

    inliers = np.ones(n, dtype=bool)
    n_out = int(round(outlier_ratio * n))
    if n_out:
        idx = rng.choice(n, n_out, replace=False)
        inliers[idx] = False
        x2[idx] = rng.uniform(-half, half, (n_out, 2))

    def sensed(S, x):
        Z = S[:, 2]
        if depth_noise > 0:
            Z = Z + rng.normal(0.0, 1.0, len(Z)) * depth_noise * Z ** 2 / scene_depth
        return np.column_stack([x * Z[:, None], Z])

    P1 = sensed(S1, x1)
    P2 = sensed(S2, x2)
    if n_out:
        P2[~inliers, 2] = rng.uniform(zlo, zhi, n_out)
        P2[~inliers, :2] = x2[~inliers] * P2[~inliers, 2:3]

    # a wall normal (world) at a random heading, seen from both views
    wall = rot_y(rng.uniform(-np.pi, np.pi)) @ np.array([0.0, 0.0, 1.0])
    return PlanarProblem(
        x1=x1, x2=x2, P1=P1, P2=P2, yaw=float(yaw), t=t, inliers=inliers, X1=X1,
        tilt1=E1, tilt2=E2, focal=focal,
        wall_heading1=heading_of_direction(wall), wall_heading2=heading_of_direction(R @ wall),
    )
