"""Two-view planar-motion problems with ground truth, for the solver tests and benchmarks.

Workshop, not product: :func:`make_planar_problem` simulates what the front-end's solvers
(:mod:`planar_vo.frontend.solvers`) and estimators see -- levelled normalised coordinates
and depth points with image noise, depth noise, levelling errors and outliers;
:func:`make_far_corner_drive` a drive through an open hall whose corners lie beyond the
depth range, for the far corners' triangulation and resection
(:mod:`planar_vo.frontend.farcorners`).
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


@dataclass
class FarCornerDrive:
    """A base driving through an open hall, as :class:`planar_vo.frontend.farcorners.FarCorners`
    and the front-end see it: the same world corners in every frame.

    ``x`` (F, N, 2) float64: levelled normalised coordinates per frame (image noise
    included); ``P`` (F, N, 3): levelled points as the sensor reads them, NaN where it does
    not (the far corners always; the near ones in ``depth_frames`` only); ``steps``: the F-1
    true levelled steps ``(yaw, t (3,))`` into frames 1..F-1 (``X_i = R_y(yaw) X_{i-1} + t``);
    ``speeds`` (F-1,): metres per step.
    """

    x: np.ndarray
    P: np.ndarray
    steps: list
    speeds: np.ndarray


def make_far_corner_drive(seed: int, speeds, *, n_far: int = 80, n_near: int = 12, far_m=(6.0, 14.0),
                          pixel_px: float = 0.3, focal: float = 540.7, depth_frames=None,
                          weave_deg: float = 0.2) -> FarCornerDrive:
    """A drive forward at ``speeds`` (F-1,) metres per step with a small weave (step yaws of
    up to ``weave_deg``): ``n_far`` corners ``far_m`` ahead beyond the depth range (pillars,
    doors, boxes of a hall) and ``n_near`` floor corners that are 1.5-3.5 m ahead in the last
    frame, read with Kinect-like depth noise in the frames ``depth_frames`` (F,) bool
    (default all). Seeded."""
    rng = np.random.default_rng(seed)
    speeds = np.asarray(speeds, dtype=float)
    F = len(speeds) + 1
    depth_frames = np.ones(F, bool) if depth_frames is None else np.asarray(depth_frames, bool)
    far = np.column_stack([rng.uniform(-6, 6, n_far), rng.uniform(-2.5, 0.7, n_far), rng.uniform(*far_m, n_far)])
    near = np.column_stack([rng.uniform(-1.2, 1.2, n_near), np.full(n_near, 0.8),
                            rng.uniform(1.5, 3.5, n_near) + speeds.sum()])
    X = np.vstack([far, near])
    steps = [(math.radians(weave_deg) * math.sin(0.2 * i), np.array([0.0, 0.0, -v])) for i, v in enumerate(speeds)]
    xs, Ps = [], []
    sig = pixel_px / focal
    for i in range(F):
        if i:
            X = X @ rot_y(steps[i - 1][0]).T + steps[i - 1][1]
        xs.append(X[:, :2] / X[:, 2:] + rng.normal(0, sig, (len(X), 2)))
        P = X * (1.0 + rng.normal(0, 1.5e-3 * (1 + X[:, 2:] ** 2) / X[:, 2:], (len(X), 1)))
        P[:n_far] = np.nan
        if not depth_frames[i]:
            P[n_far:] = np.nan
        Ps.append(P)
    return FarCornerDrive(np.array(xs), np.array(Ps), steps, speeds)
