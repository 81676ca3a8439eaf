"""Low-texture corridors (issue 9): the 1-point translation from a dozen noisy depths.

On the low-texture tuning logs the direction-plus-point steps took their translation from
about twelve corners on the side walls and the floor, seen obliquely: each depth reading
carries the sensor noise (larger at oblique incidence) and the depth of the nearest pixel,
not of the tracked sub-pixel position, and the chain summed those errors (per-step
``t_z`` error 5.3 mm, 0.6-1 % of the path). Refining each corner's depth by the wall or
floor it lies on (the planes are fitted to thousands of pixels) cut that error to 1.5 mm
there (straight_s127). Here the same situation is simulated point by point, and rendered, against truth.
"""
from __future__ import annotations

import math

import numpy as np

from planar_vo.frontend.estimators import DirPointOptions, estimate_planar_motion_dpp
from planar_vo.frontend.planes import Plane
from planar_vo.frontend.pointplanes import refine_pairs_on_planes

F = 525.0
HEIGHT = 0.8      # camera above the floor (levelled y is down)
HALF_WIDTH = 1.0  # walls at x = -1 and x = +1
INCIDENCE = 0.6   # the sensor's sigma grows by 1 + 0.6 (1 / cos - 1)


def _Ry(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _corridor_points(rng, n: int, z_max: float = 1.7) -> tuple[np.ndarray, np.ndarray]:
    """``(points (n, 3), plane index (n,))``: corners on the left wall, right wall, floor,
    up to ``z_max`` ahead (within 60 deg of the walls' normals)."""
    which = rng.integers(0, 3, n)
    z = rng.uniform(0.6, z_max, n)
    P = np.empty((n, 3))
    P[:, 2] = z
    wall = which < 2
    P[wall, 0] = np.where(which[wall] == 0, -HALF_WIDTH, HALF_WIDTH)
    P[wall, 1] = rng.uniform(-0.9, HEIGHT - 0.05, wall.sum())
    P[~wall, 0] = rng.uniform(-0.9, 0.9, (~wall).sum())
    P[~wall, 1] = HEIGHT
    return P, which


def _planes(R: np.ndarray, t: np.ndarray, rng, offset_sigma: float) -> list[Plane]:
    """The three planes seen from a camera at ``X' = R X + t``, offsets fitted to ~1 mm."""
    out = []
    for n, d in ((np.array([-1.0, 0.0, 0.0]), HALF_WIDTH), (np.array([1.0, 0.0, 0.0]), HALF_WIDTH),
                 (np.array([0.0, 1.0, 0.0]), HEIGHT)):
        n2 = R @ n
        out.append(Plane("wall", n2, d + float(n2 @ t) + rng.normal(0.0, offset_sigma), 0.2, 1000, 0.0,
                         np.eye(3)))
    return out


def _measure(P: np.ndarray, which: np.ndarray, planes: list[Plane], rng) -> np.ndarray:
    """Levelled readings of true points ``P`` (n, 3): the tracked position with 0.5 px noise,
    the depth of the nearest pixel on the same plane, with incidence-dependent noise, in mm."""
    u = F * P[:, :2] / P[:, 2:3] + rng.normal(0.0, 0.5, (len(P), 2))
    ray = np.column_stack([u / F, np.ones(len(P))])
    ray_px = np.column_stack([np.rint(u) / F, np.ones(len(P))])
    n = np.array([planes[k].normal for k in which])
    d = np.array([planes[k].offset for k in which])
    z_px = d / np.einsum("ij,ij->i", n, ray_px)            # the nearest pixel's depth
    cos = np.abs(np.einsum("ij,ij->i", n, ray_px / np.linalg.norm(ray_px, axis=1)[:, None]))
    sigma = (0.0015 + 0.0015 * z_px ** 2) * (1.0 + INCIDENCE * (1.0 / np.maximum(cos, 0.2) - 1.0))
    z = np.rint((z_px + rng.normal(0.0, 1.0, len(P)) * sigma) * 1000.0) / 1000.0
    return ray * z[:, None]


_KW = dict(depth_sigma_const=0.002, depth_sigma_quad=0.002, incidence=0.5, ray_sigma=0.5 / F, plane_sigma=0.002,
           gate_chi2=9.21)


def _steps(refine: bool, n_steps: int = 150, n_points: int = 12, seed: int = 5):
    """Per step: (translation error (2,), stated sigmas (2,)) of direction-plus-point."""
    rng = np.random.default_rng(seed)
    opt = DirPointOptions(focal_px=F, seed=0)
    errs, sig = [], []
    for _ in range(n_steps):
        yaw = math.radians(rng.normal(0.0, 0.5))
        t = np.array([rng.normal(0.0, 0.005), 0.0, -0.05])
        R = _Ry(yaw)
        P1, which = _corridor_points(rng, n_points)
        P2 = P1 @ R.T + t
        planes1 = _planes(np.eye(3), np.zeros(3), rng, 0.001)
        planes2 = _planes(R, t, rng, 0.001)
        M1, M2 = _measure(P1, which, planes1, rng), _measure(P2, which, planes2, rng)
        scale = None
        if refine:
            M1, M2, s1, s2 = refine_pairs_on_planes(M1, M2, planes1, planes2, yaw, **_KW)
            scale = (s1, s2)
        motion, info = estimate_planar_motion_dpp(M1, M2, yaw, opt, yaw_sigma=1e-5, depth_scale=scale)
        assert motion is not None
        errs.append([motion.t[0] - t[0], motion.t[2] - t[2]])
        sig.append(np.sqrt(np.diag(info.covariance)[1:]))
    return np.array(errs), np.array(sig)


def test_plane_refined_depths_cut_the_translation_error():
    """Twelve corners on oblique walls and floor per step: the raw readings' translation
    errs by about 2 mm per step along the corridor; refined on their planes it errs by
    about half of that, and the stated sigmas stay honest (error / sigma RMS
    within 0.5-2 per axis)."""
    e_raw, _ = _steps(refine=False)
    e_fit, s_fit = _steps(refine=True)
    rms_raw = np.sqrt((e_raw ** 2).mean(0))
    rms_fit = np.sqrt((e_fit ** 2).mean(0))
    assert rms_raw[1] > 0.0015                     # the mechanism: mm-level per-step t_z errors
    assert rms_fit[1] < 0.6 * rms_raw[1]
    assert rms_fit[0] < rms_raw[0]
    norm = np.sqrt(((e_fit / s_fit) ** 2).mean(0))
    assert np.all((norm > 0.5) & (norm < 2.0)), norm


def test_corners_proud_of_the_wall_keep_their_offset():
    """Exact readings of corners 6 mm proud of the walls (a poster, a door frame) and one
    0.3 m in front (a box): the refined points are the true ones. Snapping them onto the
    wall would scale the step by 1 + 6 mm / 1 m; the box corner is on no plane and keeps its
    reading and weight."""
    rng = np.random.default_rng(3)
    yaw, t = math.radians(0.4), np.array([0.003, 0.0, -0.05])
    R = _Ry(yaw)
    P1, which = _corridor_points(rng, 20)
    wall = which < 2
    P1[wall, 0] += np.where(which[wall] == 0, 0.006, -0.006)   # proud: towards the camera
    P1 = np.vstack([P1, [[-0.7, 0.0, 2.0]], [[np.nan] * 3]])
    P2 = P1 @ R.T + t
    Q1, Q2, s1, s2 = refine_pairs_on_planes(P1, P2, _planes(np.eye(3), np.zeros(3), rng, 0.0),
                                            _planes(R, t, rng, 0.0), yaw, **_KW)
    np.testing.assert_allclose(Q1[:-1], P1[:-1], atol=1e-9)
    np.testing.assert_allclose(Q2[:-1], P2[:-1], atol=1e-9)
    refined = (s1[:20] < 1.0) & (s2[:20] < 1.0)               # weighted up
    assert refined.sum() >= 10
    assert s1[20] == 1.0 and s2[20] == 1.0                   # the box corner
    assert np.isnan(Q1[21]).all() and np.isnan(Q2[21]).all()


def test_rendered_low_texture_corridor_steps_against_truth():
    """A rendered low-texture straight corridor (480 x 270, 15 Hz, depth noise growing with
    incidence, posters and door frames 6 mm proud): the direction-plus-point steps' along-track
    error, against the ground truth, is well under half of what the raw depth readings give."""
    from planar_vo.core import geometry as g
    from planar_vo.frontend.config import FrontendConfig, OdometryConfig
    from planar_vo.frontend.odometry import PlanarOdometry
    from planar_vo.sim.synth import SynthConfig, render_sequence, synth_intrinsics, synth_mount

    cfg = SynthConfig(layout="straight", n_frames=45, seed=11, texture="low", rate_hz=15.0, speed=0.5, ramp_s=0.3,
                      depth_incidence=0.6, edge_dropout=0.5, door_proud_m=0.006,
                      poster_proud_m=0.006).at_resolution(480, 270)
    frames = list(render_sequence(cfg, frames=range(16)))
    rms = {}
    for refine in (False, True):
        odo = PlanarOdometry(synth_intrinsics(cfg), synth_mount(cfg),
                             FrontendConfig(odometry=OdometryConfig(plane_refine=refine)))
        results = [odo.process(f.rgbd) for f in frames]
        err = np.array([r.step.pose - g.se2_between(a.pose_world_base, b.pose_world_base)
                        for r, a, b in zip(results[1:], frames[:-1], frames[1:]) if r.step.status == "dpp"])
        # 9 of 15: near the end the corners on box and door silhouettes have no depth
        # (features.occlusion_rel) and the steps are partial
        assert len(err) >= 9
        rms[refine] = np.sqrt((err[:, :2] ** 2).mean(0))
    assert rms[False][0] > 0.002                 # raw depths: mm-level along-track errors per step
    assert rms[True][0] < 0.5 * rms[False][0]
    assert rms[True][1] < rms[False][1]
