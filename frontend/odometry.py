"""Frame-to-frame planar visual odometry (the paper's front-end, Sec. 2 and 3.2).

Per frame: level the camera (given mount or floor estimate), detect the floor and walls
from inverse-depth histograms, group walls into local Manhattan frames and track them,
associate corners with the previous frame and lift them to levelled 3-D. The step from
the previous frame is then estimated by

1. direction-plus-point (Sec. 2.1): the yaw from a local Manhattan frame seen in both
   frames (eq. 1) at the two observations' own sigmas, the translation by 1-point RANSAC
   on 3-D matches at that yaw (eq. 2). The frame must be tracked for a few frames and
   cover enough image area in both views (walls entering the view give biased headings).
   When the 2-point estimate below is also available it may veto the Manhattan yaw (a
   disagreement beyond ``dpp_veto_sigmas`` and ``dpp_veto_min_deg`` means a wrong
   association: the 2-point step is used), but never bends it; else
2. the 2-point planar homography (Sec. 2.2) with metric scale from depth (enough matches
   with depth must agree on the scale); else
3. a partial step, ``STATUS_PARTIAL``, when a Manhattan frame still gives the yaw: that
   yaw at its own sigma, the translation along the normals of walls seen in both frames,
   from a few agreeing 3-D matches, and along the direction the walls leave open from
   the two depth images aligned along it (frontend/depthalign.py: box sides, door
   frames, end walls); only what none of them fixes stays at the bridge's guess and
   sigma. Without a Manhattan or 2-point yaw, the yaw may come from the depth images
   aligned about it (pillars and boxes of a textureless hall; ``depth_yaw``), and a step
   whose translation alone was measured is partial at the guessed yaw; else
4. a bridge, ``STATUS_BRIDGED``: constant velocity (or zero motion) with a large
   covariance, when nothing of the step was measured -- never silently.

Steps are reported as base_link SE(2) increments with an information matrix in
gtsam.Pose2 tangent order ``[x, y, theta]``, propagated from the estimator's covariance
over ``(yaw, t_x, t_z)`` through the levelled-to-base conversion.
"""
from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from planar_vo.core import geometry
from planar_vo.core.errors import InputError
from planar_vo.frontend.config import FrontendConfig
from planar_vo.frontend.depthalign import (DepthAlignOptions, align_along, align_yaw, coarse_yaw_along, informative,
                                           informative_yaw, sample_points)
from planar_vo.frontend.farcorners import FarCorners, FarOptions
from planar_vo.frontend.gapresection import GapFrame, StartGapResection
from planar_vo.frontend.estimators import (DirPointOptions, MetricTwoPointOptions,
                                           estimate_planar_motion_2pt_metric, score_depth_matches,
                                           estimate_planar_motion_dpp)
from planar_vo.frontend.features import FeatureSet, FeatureTracker
from planar_vo.frontend.keyframe import KeyframeTracker
from planar_vo.frontend.levelling import Levelling, LevellingState
from planar_vo.frontend.manhattan import LocalFrame, ManhattanTracker, group_walls
from planar_vo.frontend.planarity import out_of_plane_motion
from planar_vo.frontend.planes import Plane, PlaneDetection, PlaneDetector
from planar_vo.frontend.pointplanes import refine_pairs_on_planes
from planar_vo.frontend.solvers import yaw_from_manhattan_headings
from planar_vo.core.steps import (STATUS_2PT, STATUS_BRIDGED, STATUS_DPP, STATUS_PARTIAL, FrameDiagnostics,
                                      FrameResult, GapLink, KeyframeLink, KeyframeYaw, ManhattanObservation,
                                      Step, WallObservation)
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame


@dataclass
class _Prev:
    """What the next frame needs from this one (each frame is processed once)."""

    features: FeatureSet
    x_lev: np.ndarray      # (N, 2) levelled normalised coordinates
    P_lev: np.ndarray      # (N, 3) levelled points, NaN without depth
    frames: list[LocalFrame]
    walls: list[Plane]
    planes: list[Plane] | None = None  # walls and floor
    depth: np.ndarray | None = None    # (H, W) float32 m, for partial steps' depth alignment
    R_lev_cam: np.ndarray | None = None
    align_points: tuple | None = None  # its depth alignment points and normals, once sampled


def levelled_features(fs: FeatureSet, R_lev_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(x_lev (N, 2), P_lev (N, 3))`` of a feature set; ``x_lev`` NaN behind the levelled camera."""
    rays = np.column_stack([fs.xy, np.ones(len(fs))]) @ R_lev_cam.T
    with np.errstate(divide="ignore", invalid="ignore"):
        x = rays[:, :2] / np.where(rays[:, 2:3] > 1e-6, rays[:, 2:3], np.nan)
    return x, fs.P_cam @ R_lev_cam.T


def lev_motion_to_base_step(yaw: float, t: np.ndarray, cov: np.ndarray | None,
                            m_base_lev: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Base_link step ``(x, y, theta)`` and its (3, 3) covariance from a levelled motion.

    ``yaw``, ``t`` (3,): ``X_lev2 = R_y(yaw) X_lev1 + t``; ``cov``: (3, 3) over
    ``(yaw, t_x, t_z)`` or None; ``m_base_lev``: :func:`geometry.mount_se2` of the mount.
    The covariance is pushed through the (smooth) map by its Jacobian
    (:func:`lev_to_base_jacobian`).
    """
    step = _lev_to_base(np.array([yaw, t[0], t[2]], dtype=float), m_base_lev)
    if cov is None:
        return step, None
    J = lev_to_base_jacobian(yaw, t, m_base_lev)
    return step, J @ cov @ J.T


def _lev_to_base(p: np.ndarray, m_base_lev: np.ndarray) -> np.ndarray:
    return geometry.lev_step_to_base_step(geometry.levelled_motion_to_pose(p[0], np.array([p[1], 0.0, p[2]])),
                                          m_base_lev)


def lev_to_base_affine(yaw: float, m_base_lev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(k (2,), M (2, 2))``: at a given levelled ``yaw`` the base_link step's ``(x, y)``
    is ``k + M (t_x, t_z)``, affine in the levelled translation (``k`` the lever arm's
    part; :func:`lev_motion_to_base_step`)."""
    def base_xy(tx: float, tz: float) -> np.ndarray:
        return lev_motion_to_base_step(yaw, np.array([tx, 0.0, tz]), None, m_base_lev)[0][:2]
    k = base_xy(0.0, 0.0)
    return k, np.column_stack([base_xy(1.0, 0.0) - k, base_xy(0.0, 1.0) - k])


def lev_to_base_jacobian(yaw: float, t: np.ndarray, m_base_lev: np.ndarray) -> np.ndarray:
    """(3, 3) Jacobian of the base_link step ``(x, y, theta)`` with respect to the levelled
    motion ``(yaw, t_x, t_z)`` (:func:`lev_motion_to_base_step`), by central differences
    (the map is a few trigonometric terms, so this is exact to ~1e-10)."""
    p0 = np.array([yaw, t[0], t[2]], dtype=float)
    J = np.empty((3, 3))
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        diff = _lev_to_base(p0 + d, m_base_lev) - _lev_to_base(p0 - d, m_base_lev)
        diff[2] = float(geometry.wrap_angle(diff[2]))
        J[:, k] = diff / (2 * h)
    return J


def _offset_var_fit(w: Plane) -> float:
    """Variance (m^2) of the image-to-image part of a wall's offset ``d = 1 / |q|``: its
    fit covariance ``cov_q`` (``q = normal / offset``) propagated. The depth errors
    correlated across the plane (``systematic * rms_rel * d``, as in :attr:`Plane.yaw_sigma`)
    are those of the same wall seen from nearly the same place in the other image: they
    cancel in the offset difference ``d2 - d1`` a partial step uses."""
    q = w.normal / w.offset
    J = -q / float(np.linalg.norm(q)) ** 3
    return max(float(J @ w.cov_q @ J), 0.0)


def wall_observations(walls: list[Plane], m_base_lev: np.ndarray, min_support: float, max_offset: float,
                      min_width: float) -> list[WallObservation]:
    """The walls a back-end can use as landmarks, in base_link (:class:`WallObservation`).

    ``m_base_lev``: (3,) :func:`geometry.mount_se2`, the levelled camera's planar pose
    ``(x, y, yaw)`` in base_link. A wall ``n_lev . p_lev = d`` (2-D, lev x forward, y left)
    is ``n_b . p_b = d + n_b . c`` in base_link, with ``n_b`` the normal rotated by the
    mount's yaw and ``c`` the camera's position. Kept: walls with at least ``min_support``
    of the image, nearer than ``max_offset`` (m; beyond it the range limit biases the
    offset) and at least ``min_width`` (m) wide (box faces and pillars are left out: their
    few points fit a poorer plane and they are easily confused with the wall behind). The
    offset's sigma adds the depth errors correlated across the plane to the fit's, since a
    landmark compares one wall's offset seen from far-apart places, where they do not cancel.
    """
    out = []
    c, mount_yaw = np.asarray(m_base_lev[:2], dtype=float), float(m_base_lev[2])
    for w in walls:
        if w.support < min_support or w.offset > max_offset or w.width < min_width:
            continue
        yaw = float(geometry.wrap_angle(w.yaw + mount_yaw))
        n_b = np.array([math.cos(yaw), math.sin(yaw)])
        var = _offset_var_fit(w) + (w.systematic * w.rms_rel * w.offset) ** 2
        out.append(WallObservation(yaw, float(w.offset + n_b @ c), float(math.sqrt(var)), float(w.support)))
    return out


def _collinear(x: np.ndarray, min_spread: float, info: FrameDiagnostics, min_across: float = math.inf) -> bool:
    """True when the (N, 2) image points lie along one line: the ratio of the smaller to
    the larger principal spread is below ``min_spread`` and their rms distance from the
    line is below ``min_across`` (normalised units). On plain walls the only corners are on
    the floor-wall junction, where KLT slides along the line (the aperture problem) and
    the matches agree on a wrong motion along it; they scatter off it by a pixel or two.
    Corners of boxes and pillars across an open hall also fill a band that is wide but
    flat (ratio 0.04-0.10 on a low-texture tuning hall), yet lie 10-25 px rms off its
    axis: not a line, and their steps (13-16 agreeing depths) were bridged for it."""
    if len(x) < 3:
        return True
    sv = np.linalg.svd(x - x.mean(0), compute_uv=False)
    spread = float(sv[1] / sv[0]) if sv[0] > 0 else 0.0
    across = float(sv[1] / math.sqrt(len(x)))
    if spread < min_spread and across < min_across:
        info.rejected.append({"inlier_spread": spread, "across_rms": across})
        return True
    return False


def match_walls(walls1: list[Plane], walls2: list[Plane], yaw: float, t_prior: np.ndarray, config,
                max_offset: float = math.inf) -> list[tuple[Plane, Plane, np.ndarray]]:
    """The same physical walls in two frames: ``(w1, w2, n2)`` with ``n2`` (2,) the unit
    horizontal normal of ``w2`` in levelled ``(x, z)``.

    With ``X2 = R_y(yaw) X1 + t``, a plane ``n1 . X1 = d1`` becomes ``n2 . X2 = d1 + n2 . t``
    with ``n2 = R_y(yaw) n1``. A wall of frame 2 pairs with the frame-1 wall whose rotated
    normal agrees within ``config.wall_match_deg`` and whose offset agrees within
    ``config.wall_match_m`` after the prior motion ``t_prior`` (2,), the closest offset
    winning; walls under ``config.wall_min_support`` or beyond ``max_offset`` are left out.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    cos_gate = math.cos(math.radians(config.wall_match_deg))
    usable1 = [w for w in walls1 if w.support >= config.wall_min_support and w.offset <= max_offset]
    pairs = []
    for w2 in walls2:
        if w2.support < config.wall_min_support or w2.offset > max_offset:
            continue
        n2 = np.array([w2.normal[0], w2.normal[2]]) / math.hypot(w2.normal[0], w2.normal[2])
        best = None
        for w1 in usable1:
            m = R @ w1.normal
            gap = abs(w2.offset - w1.offset - float(n2 @ t_prior))
            if (m[0] * n2[0] + m[2] * n2[1]) / math.hypot(m[0], m[2]) >= cos_gate and gap <= config.wall_match_m \
                    and (best is None or gap < best[0]):
                best = (gap, w1)
        if best is not None:
            pairs.append((best[1], w2, n2))
    return pairs


def yaw_from_wall_pairs(pairs: list[tuple[Plane, Plane, np.ndarray]], yaw_hint: float) -> tuple[float, float]:
    """Eq. 1 wall by wall: ``(yaw, sigma)`` (rad) from the heading change of each wall seen
    in both frames (:func:`match_walls`), weighted by the walls' image-to-image sigmas.

    A local frame's heading is a weighted mean over its walls; when walls a degree or two
    apart (a box face, a wall of a neighbouring frame) join or leave the group, that mean
    moves while nothing turned. The same wall in both views has no such shift.
    """
    y = np.array([yaw_from_manhattan_headings(w1.yaw, w2.yaw, yaw_hint) for w1, w2, _ in pairs])
    var = np.array([w1.yaw_sigma_fit ** 2 + w2.yaw_sigma_fit ** 2 for w1, w2, _ in pairs])
    wt = 1.0 / np.maximum(var, 1e-14)
    d = np.asarray(geometry.wrap_angle(y - yaw_hint), dtype=float)
    return yaw_hint + float((wt * d).sum() / wt.sum()), math.sqrt(1.0 / float(wt.sum()))


def window_velocity(recent: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, float]:
    """The constant-velocity guess from the translations measured in the window: ``recent``
    ``[(t (3,) levelled, variance), ...]``; returns their inverse-variance weighted mean
    (3,) and its sigma.

    Steps measured alike weigh alike (the plain mean, sigma / sqrt(n)). A coarse step weighs
    less: on a low-texture tuning hall (hall_s3704) a 2-point step measured 52 mm (sigma
    26 mm) for a true 12 mm, and the 13 partial steps copying the plain mean of its window
    went 70 mm too far."""
    w = np.array([1.0 / v for _, v in recent])
    t = (w[:, None] * np.array([r for r, _ in recent])).sum(0) / w.sum()
    return t, math.sqrt(1.0 / float(w.sum()))


def occupied_cells(x: np.ndarray, cell: float = 0.125) -> int:
    """Image cells (``cell`` normalised units square) holding at least one of the (N, 2) points."""
    if len(x) == 0:
        return 0
    return len(np.unique(np.floor(np.asarray(x) / cell).astype(np.int64), axis=0))


def inflate_crowded_yaw(cov: np.ndarray, cells: int, min_cells: float, depth: float = math.nan) -> np.ndarray:
    """The 2-point covariance (3, 3) over (yaw, t_x, t_z) with the yaw's sigma scaled by
    ``min_cells / cells`` when the inliers occupy fewer than ``min_cells`` image cells
    (``cells``, :func:`occupied_cells`). Crowded matches share their
    errors, which the inlier residuals cannot show: on the low-texture tuning halls the yaw
    erred 5x its stated sigma, and the sideways translation by -Z times the yaw error (the
    far-wall ambiguity, ``X2 = R X1 + t`` unchanged). So the variance is added along that
    direction, ``(1, -depth, 0)``, with ``depth`` (m) the matches' typical depth; without
    one, to the yaw alone (its correlations scaled with it)."""
    k = min_cells / max(cells, 1)
    if k <= 1.0:
        return cov
    if not math.isfinite(depth):
        d = np.array([k, 1.0, 1.0])
        return cov * np.outer(d, d)
    v = np.array([1.0, -depth, 0.0])
    return cov + (k * k - 1.0) * cov[0, 0] * np.outer(v, v)


def _typical_depth(P: np.ndarray) -> float:
    """Median depth (m) of the (N, 3) levelled points with a valid one, NaN without any."""
    z = np.asarray(P)[:, 2] if len(P) else np.zeros(0)
    z = z[np.isfinite(z) & (z > 0)]
    return float(np.median(z)) if len(z) else math.nan


def _step_covariance(cov_k: np.ndarray, cov_step: np.ndarray, chained_yaw: bool,
                     carried: np.ndarray) -> np.ndarray:
    """(3, 3) covariance over ``(yaw, t_x, t_z)`` of a step taken as the difference of two
    motions from a keyframe: their errors share the keyframe's part, so the step errs by
    about what one motion from the keyframe does (``cov_k``), not by the sum of two;
    ``carried`` (3, 3): what guessed steps since the last measurement added, which the step
    takes back, kept whole. When the motion from the keyframe kept the chained yaw (eq. 1
    telescoping along a track), the step's yaw is the frame-to-frame estimate's own
    (``cov_step``): its variance replaces the chained one, the correlations scaled with it.

    A motion re-measured whole on a 2-point chain: its length comes from each frame's own
    depths (the step errs as one motion does), but its yaw and sideways translation from
    the tracks' image positions, whose errors the two motions share (the keyframe's
    corners, and a track's slowly drifting position), so there the step is no less certain
    than the frame-to-frame estimate of the same step: those two variances are capped at
    ``cov_step``'s. With ``cov_k`` alone they were about twice the errors (sideways and yaw
    errors 0.53 / 0.61 of their sigmas over 1607 such steps of the tuning halls of seeds
    3700-3707, 0.87 / 1.09 with the cap; the normalised-error band of docs/bench asks for 0.5-2)."""
    if chained_yaw:
        cov = cov_k + carried
        if cov[0, 0] <= 0:
            return cov
        d = np.array([math.sqrt(cov_step[0, 0] / cov[0, 0]), 1.0, 1.0])
        return cov * np.outer(d, d)
    v_k, v_s = np.diag(cov_k)[:2], np.diag(cov_step)[:2]
    d = np.ones(3)
    d[:2] = np.sqrt(np.where(v_s < v_k, v_s / np.where(v_k > 0, v_k, 1.0), 1.0))
    return cov_k * np.outer(d, d) + carried


def _image_yaw_bend(motion, est) -> tuple[float, float, float]:
    """``(sigma, image yaw, bend)`` (rad) of a 2-point estimate: its yaw sigma, the yaw the
    image matches alone give (``epipolar_yaw``), and how far the joint fit's yaw is from it."""
    y_img = float(est.extra.get("epipolar_yaw", motion.yaw))
    return math.sqrt(float(est.covariance[0, 0])), y_img, abs(float(geometry.wrap_angle(motion.yaw - y_img)))


def _refused_scale_yaw(motion, est) -> tuple[float, float] | None:
    """``(yaw, sigma)`` (rad) of a 2-point estimate whose metric scale was refused, or None.

    A few depths can bend the joint fit's yaw away from what the image matches say (a
    depth-edge point passing the scale gate): then the yaw is the matches' own, with the
    disagreement as its sigma. A rotation that explains every match leaves the yaw no
    freedom. Far points let the yaw and the sideways direction trade off, and the image
    matches alone picked a wrong end of that valley (yaw errors of 0.4-1.6 deg at 5-20
    sigma on the tuning halls); a wheeled base's step follows its heading
    (``odometry.lateral_slip``, ``lateral_prior_m`` in ``est.extra``): the joint fit's yaw
    then holds without a trusted scale, which only enters through the camera's lever arm
    (on a low-texture tuning hall, seed 3501, 58 such steps erred 0.07 deg rms, where the
    bridges they had been erred 0.1-0.4 deg each while the heading weaved). A holonomic
    base: nothing fixes the direction without depth (None).
    """
    sigma, y_img, bend = _image_yaw_bend(motion, est)
    if est.status == "pure_rotation":
        return y_img, max(sigma, bend)
    if "lateral_prior_m" in est.extra:
        return float(motion.yaw), max(sigma, bend)
    return None


def _kf_prior(kf_t) -> tuple[np.ndarray, np.ndarray]:
    """The levelled ``(t_x, t_z)`` (2,) and (2, 2) covariance of a step measured from the
    keyframe (``PlanarOdometry._keyframe_translation``), as a partial step's prior in the
    guess's place: fused with a guess that lags a base speeding up, the steps fell short
    of the motions from K."""
    return np.asarray(kf_t[0][1], float)[[0, 2]], kf_t[1][1:, 1:]


def _prior_cov(sigma_prior) -> np.ndarray:
    """(2, 2) covariance of a translation prior given as one sigma per axis (m) or as a
    (2, 2) covariance (m^2)."""
    a = np.asarray(sigma_prior, dtype=float)
    return a if a.shape == (2, 2) else np.eye(2) * float(a) ** 2


def wall_constraints(walls1: list[Plane], walls2: list[Plane], yaw: float, t_prior: np.ndarray,
                     config, sigma_prior=math.inf) -> list[tuple[np.ndarray, float, float]]:
    """Translation constraints ``(n (2,), delta, var)`` meaning ``n . t = delta`` (levelled
    ``(t_x, t_z)``, metres) from vertical planes seen in both frames, given the step's yaw.

    Each wall pair of :func:`match_walls` fixes the translation along its normal,
    ``n2 . t = d2 - d1`` (a side wall the sideways motion, an end wall the distance along).
    Walls beyond ``config.wall_max_offset_m`` are not used (near the sensor's range limit
    only the points that noise brought nearer survive, and the offset is biased). Walls
    with (anti)parallel normals are merged into one constraint: two nearly parallel
    normals would otherwise turn their offset noise into a large motion along the wall.

    ``sigma_prior``: the sigma of ``t_prior`` per axis (m) or its (2, 2) covariance (m^2;
    :meth:`PlanarOdometry._wheeled_prior`). A pair whose offset change
    departs from the prior by more than ``config.wall_gate_sigmas`` combined sigmas is a
    different plane in one of the views (a box face in front of the wall it stands
    against), not a measurement: it is left out.
    """
    cos_gate = math.cos(math.radians(config.wall_match_deg))
    C = _prior_cov(sigma_prior) if np.isfinite(sigma_prior).all() else None
    pairs = []
    for w1, w2, n2 in match_walls(walls1, walls2, yaw, t_prior, config, config.wall_max_offset_m):
        delta = w2.offset - w1.offset
        var = _offset_var_fit(w1) + _offset_var_fit(w2) + config.wall_min_sigma_m ** 2
        var_prior = math.inf if C is None else float(n2 @ C @ n2)
        if abs(delta - float(n2 @ t_prior)) <= config.wall_gate_sigmas * math.sqrt(var + var_prior):
            pairs.append((n2, delta, var))
    merged: list[list] = []  # [n_ref, sum w*delta, sum w] with delta signed along n_ref
    for n, delta, var in pairs:
        for m in merged:
            if abs(float(n @ m[0])) >= cos_gate:
                sign = 1.0 if n @ m[0] > 0 else -1.0
                m[1] += sign * delta / var
                m[2] += 1.0 / var
                break
        else:
            merged.append([n, delta / var, 1.0 / var])
    return [(n, wd / w, 1.0 / w) for n, wd, w in merged]


def translation_from_walls(constraints, t_prior: np.ndarray, sigma_prior) -> tuple[np.ndarray, np.ndarray]:
    """Levelled translation ``(t_x, t_z)`` (2,) and its (2, 2) covariance from
    :func:`wall_constraints` and a prior ``t_prior`` (2,) with ``sigma_prior`` (one sigma
    per axis, m, or a (2, 2) covariance), which keeps what no wall observes (information
    form)."""
    A = np.linalg.inv(_prior_cov(sigma_prior))
    b = A @ t_prior
    for n, delta, var in constraints:
        A += np.outer(n, n) / var
        b += n * delta / var
    cov = np.linalg.inv(A)
    return cov @ b, cov


class PlanarOdometry:
    """Frame-to-frame planar odometry for one RGB-D camera.

    ``intrinsics``: the colour camera (depth registered to it). ``mount``: the camera's
    ``T_base_cam`` if known (a NaN height means "measure it from the floor"); without
    it pitch, roll and height are estimated from the floor. ``config``: FrontendConfig.
    Call :meth:`process` once per frame, in order. ``clock`` times the stages reported in
    ``FrameResult.timings`` (wall clock; benchmarks set ``time.thread_time`` for CPU time).
    """

    clock = staticmethod(time.perf_counter)

    def __init__(self, intrinsics: CameraIntrinsics, mount: Mount | None = None,
                 config: FrontendConfig | None = None):
        if not isinstance(intrinsics, CameraIntrinsics):
            raise TypeError(f"intrinsics must be a CameraIntrinsics, got {type(intrinsics).__name__}")
        if intrinsics.width <= 0 or intrinsics.height <= 0 or not (intrinsics.fx > 0 and intrinsics.fy > 0):
            raise InputError(f"camera intrinsics {intrinsics.width}x{intrinsics.height} fx={intrinsics.fx} "
                             f"fy={intrinsics.fy} are not usable; check the camera_info topic or the calibration")
        self.intrinsics = intrinsics
        self.config = config or FrontendConfig()
        c = self.config
        self._levelling = Levelling(c.levelling, mount)
        depth_range = (c.min_depth, c.max_depth)
        self._planes = PlaneDetector(intrinsics, c.planes, self._levelling.state.R_lev_cam, depth_range)
        self._features = FeatureTracker(intrinsics, c.features, depth_range)
        self._manhattan = ManhattanTracker(c.manhattan)
        o = c.odometry
        self._dpp_opt = DirPointOptions(focal_px=intrinsics.fx, max_iterations=o.ransac_iterations, seed=o.seed)
        self._2pt_opt = MetricTwoPointOptions(focal_px=intrinsics.fx, max_error_px=o.ransac_threshold_px,
                                              seed=o.seed, lateral_slip=o.lateral_slip,
                                              lateral_floor_m=o.lateral_floor_m)
        self._prev: _Prev | None = None
        self._keyframes = KeyframeTracker(o.keyframe_min_fraction, o.keyframe_max_baseline_m, o.keyframe_max_yaw_deg)
        # corners beyond the depth range, triangulated from the measured steps: a step no
        # estimator measured is resected against them (frontend/farcorners.py)
        self._far = FarCorners(FarOptions(
            pixel_sigma=self._dpp_opt.pixel_sigma / intrinsics.fx, walk=o.keyframe_track_px / intrinsics.fx,
            depth_sigma=(self._dpp_opt.depth_sigma_const, self._dpp_opt.depth_sigma_quad))) if o.far_corners else None
        # the gap of unmeasured steps a log starts with, resected backwards after it
        # (frontend/gapresection.py); its motions go out with the frame that measured them
        self._gap = StartGapResection(self._far.opt) if self._far is not None and o.start_gap_resection else None
        self._gap_links: list[GapLink] = []
        # this frame's keyframe.commit arguments: the motion keyframe -> this frame the step
        # was taken from, or the step that was guessed, each with its covariance
        self._kf_measured: tuple | None = None
        self._kf_guessed: tuple | None = None
        # a partial step's yaw measured from the keyframe: (frames since K, levelled yaw K -> here, variance)
        self._kf_yaw: tuple[int, float, float] | None = None
        self._last_motion: tuple[float, np.ndarray] | None = None  # levelled (yaw, t) of the last estimate
        # the last velocity_window measured steps, (frame self._n, levelled t (3,), its
        # variance m^2): the guess and its rate of change (_remember_translation, _bridge_sigmas)
        self._history: list[tuple[int, np.ndarray, float]] = []
        self._dpp_track = -1  # Manhattan track of the last direction-plus-point step
        self._n = 0
        # steps since the translation / yaw was last measured, and the frame interval, for
        # the uncertainty of a constant-velocity guess (see _bridge_sigmas)
        self._since_t = 0
        self._since_yaw = 0
        self._last_t_sigma = 0.0  # m, the guessed translation's own sigma (levelled, larger axis)
        self._last_stamp: float | None = None
        self._dt = 0.1
        self.last_detection: PlaneDetection | None = None
        # frame index -> (features, matches, new corners, seconds) of track() calls made ahead
        self._tracked: dict[int, tuple] = {}
        self._depth: tuple[np.ndarray, np.ndarray] | None = None  # this frame's (depth, R_lev_cam)
        self._unread: np.ndarray | None = None  # this frame's corners without a depth reading near
        # the depth noise model of the 1-point translation (DirPointOptions), not a second one
        self._align_opt = DepthAlignOptions(min_depth=c.min_depth, max_depth=min(c.max_depth, o.wall_max_offset_m),
                                            sigma_const=self._dpp_opt.depth_sigma_const,
                                            sigma_quad=self._dpp_opt.depth_sigma_quad)

    # ------------------------------------------------------------------ state
    @property
    def levelling(self) -> LevellingState:
        """Current pitch/roll/height and where they come from."""
        return self._levelling.state

    @property
    def mount(self) -> Mount:
        """The mount in use: the given one, or one built from the estimated levelling."""
        return self._levelling.mount()

    # ------------------------------------------------------------------ main
    def process(self, frame: RGBDFrame) -> FrameResult:
        """Process the next frame; returns its step (None for the first) and observations."""
        clock = self.clock
        t_start = clock()
        color, depth = self._check(frame)
        timings: dict[str, float] = {}
        info = FrameDiagnostics()

        t0 = clock()
        det = self._detect_planes(depth, info)
        R = self._levelling.state.R_lev_cam
        t1 = clock()
        timings["planes"] = t1 - t0

        frames = group_walls(det.walls, self.config.manhattan)
        yaw_prior = self._last_motion[0] if self._last_motion is not None else 0.0
        self._manhattan.associate(frames, yaw_prior, self._bridge_sigmas(False)[1] if self._since_yaw else 0.0)
        t2 = clock()
        timings["manhattan"] = t2 - t1

        tracked = self._tracked.pop(frame.index, None)
        if tracked is None:
            if self._tracked:
                raise RuntimeError(f"frame {frame.index}: track() ran ahead for frames "
                                   f"{sorted(self._tracked)} but not for this one; call it for every frame, in order")
            tracked = self._track(color, depth)
        fs, matches, new_corners, t_track = tracked
        self._unread = fs.unread  # corners with no depth reading around them (far corners)
        t_lev = clock()
        x_lev, P_lev = levelled_features(fs, R)
        t3 = clock()
        timings["features"] = t_track + (t3 - t_lev)
        info.features, info.new_corners, info.matches = len(fs), new_corners, len(matches)

        if self._last_stamp is not None and frame.stamp > self._last_stamp:
            self._dt = frame.stamp - self._last_stamp
        self._last_stamp = frame.stamp
        planes = list(det.walls) + ([det.floor] if det.floor is not None else [])
        self._depth = (depth, R)
        step, lev_motion = self._measure(x_lev, P_lev, matches, frames, det.walls, planes, yaw_prior, info)
        t4 = clock()
        timings["estimate"] = t4 - t3

        # a vetoed observation (a group whose walls changed) must not become the reference
        veto = info.yaw_check if info.yaw_check and info.yaw_check.get("vetoed") else None
        self._manhattan.commit(frames, lev_motion[0], lev_motion[2],
                               distrusted={veto["track_id"]} if veto else frozenset())
        self._prev = _Prev(fs, x_lev, P_lev, frames, det.walls, planes, depth, R)
        m_base_lev = geometry.mount_se2(self.mount.T_base_cam)
        mount_yaw = m_base_lev[2]
        observations = [ManhattanObservation(float(geometry.wrap_quarter(f.compass_heading + mount_yaw)),
                                             f.compass_sigma, f.score, f.track_id)
                        for f in frames if f.score >= self.config.manhattan.min_score
                        and f.width >= self.config.manhattan.min_wall_width_m]
        walls = wall_observations(det.walls, m_base_lev, self.config.odometry.wall_min_support,
                                  self.config.odometry.wall_max_offset_m, self.config.manhattan.min_wall_width_m)
        timings["total"] = clock() - t_start
        self._n += 1
        return FrameResult(frame.index, frame.stamp, step, observations, timings, info, walls,
                           gap_links=self._gap_links)

    def _measure(self, x_lev, P_lev, matches, frames, walls, planes, yaw_prior, info):
        """``(step or None, levelled (yaw, t, yaw variance))`` into this frame: estimated
        from the previous frame (:meth:`_estimate`), re-measured against the keyframe,
        which this frame then carries on or becomes (frontend/keyframe.py)."""
        step, lev_motion = None, (0.0, np.zeros(3), 0.0)
        tracked = self._keyframes.follow(matches, len(x_lev))
        if self._far is not None:
            self._far.follow(matches, len(x_lev), self._unread)
        self._kf_measured = self._kf_guessed = self._kf_yaw = None
        if self._prev is not None:
            step, lev_motion = self._estimate(self._prev, x_lev, P_lev, matches, frames, walls, yaw_prior, info,
                                              planes)
        far_step = self._far_step(step, lev_motion, info)
        if self._far is not None:
            self._far.commit(x_lev, P_lev, *far_step)
        if self._gap is not None:
            self._gap_links = self._gap_resected(x_lev, P_lev, matches, step, lev_motion, far_step[1], info)
        age = self._keyframes.kf.age + 1 if self._keyframes.kf is not None else 0
        renewed = self._keyframes.commit(x_lev, P_lev, planes, self._kf_measured, self._kf_guessed,
                                         walls=step is not None and step.status == STATUS_DPP,
                                         yaw_var=self._kf_yaw[2] if self._kf_yaw and self._kf_guessed is not None else None)
        if renewed and self._depth is not None:
            self._keyframes.kf.depth, self._keyframes.kf.R_lev_cam = self._depth
        info.keyframe = {"age": age, "tracked": tracked, "renewed": renewed}
        return step, lev_motion

    def _gap_resected(self, x_lev, P_lev, matches, step: Step | None, lev_motion, cov, info) -> list[GapLink]:
        """Hand this frame to the start gap's resection (:class:`StartGapResection`); the
        motions into the gap's frames it resected, as the back-end's :class:`GapLink`. ``cov``: the
        step's levelled covariance when it was measured (:meth:`_far_step`), else None. A
        step only the walls turned gives its yaw's variance to the resection's yaw prior."""
        if self._gap.done:  # every frame after the log's start: nothing to keep or build
            return []
        yaw_var = None
        if cov is None and step is not None and step.status == STATUS_PARTIAL and info.partial \
                and info.partial.get("yaw") == "measured":
            yaw_var = float(lev_motion[2])
        z = P_lev[:, 2]
        # run backwards, the corners with a depth reading are the ones the gap's far corners
        # come nearest as: they anchor it (only corners on a depth edge stay out)
        followed = None if self._unread is None else self._unread | (np.isfinite(z) & (z > 0))
        frame = GapFrame(x_lev, z, matches, followed, (float(lev_motion[0]), np.asarray(lev_motion[1])), cov, yaw_var)
        mount = geometry.mount_se2(self.mount.T_base_cam)
        yaw_info = 1.0 / math.radians(self.config.odometry.bridge_sigma_theta_deg) ** 2
        out = []
        for a, b, (yaw, t), cov_ab in self._gap.add(self._n, frame):
            pose, cov_b = lev_motion_to_base_step(yaw, t, cov_ab, mount)
            information = np.zeros((3, 3))
            information[:2, :2] = np.linalg.inv(cov_b[:2, :2])
            information[2, 2] = yaw_info
            out.append(GapLink(self._n - a, self._n - b, pose, information))
        info.gap_links = len(out) or None
        return out

    @staticmethod
    def _far_step(step: Step | None, lev_motion, info) -> tuple:
        """``(levelled step, (3, 3) cov)`` for :meth:`FarCorners.commit` of a step whose
        translation was measured (direction-plus-point, 2-point, a partial step measured by
        walls and depths), else ``(None, None)``. The covariance over ``(yaw, t_x, t_z)`` is
        the step's base_link one with its translation made isotropic: it only scales the
        triangulated depths' sigmas."""
        measured = step is not None and (step.status in (STATUS_DPP, STATUS_2PT)
                                         or (step.status == STATUS_PARTIAL and info.partial.get("measured")))
        if not measured:
            return None, None
        cov_b = np.linalg.inv(step.information)
        s2 = 0.5 * float(cov_b[0, 0] + cov_b[1, 1])
        return (lev_motion[0], np.asarray(lev_motion[1], float)), np.diag([float(cov_b[2, 2]), s2, s2])

    def look_ahead(self, frames: Iterable[RGBDFrame]) -> None:
        """Show the odometry the first frames of the run before :meth:`process` of any:
        the plane detector learns the sensor's range from their depth
        (:meth:`PlaneDetector.look_ahead`), which the first frames' walls need."""
        self._planes.look_ahead(self._check(f)[1] for f in frames)

    def track(self, frame: RGBDFrame) -> None:
        """Run the feature stage of :meth:`process` for ``frame`` now, ahead of it.

        Corner tracking depends on the images alone, not on planes or levelling, so a
        pipeline may run it as soon as a frame is decoded, in another thread (OpenCV
        releases the GIL), while :meth:`process` works on an earlier frame. Call it for
        every frame, in order, before :meth:`process` of that frame, which then uses the
        stored result: the output is the same as without it.
        """
        color, depth = self._check(frame)
        self._tracked[frame.index] = self._track(color, depth)

    def take_tracked(self, frame: RGBDFrame) -> tuple:
        """The stored result of :meth:`track` for ``frame``, removed from this object: a
        reader process's copy of the odometry tracks, and hands it to the main copy's
        :meth:`give_tracked` (the tracker's state stays in the reader)."""
        return self._tracked.pop(frame.index)

    def give_tracked(self, frame: RGBDFrame, tracked: tuple) -> None:
        """Store another copy's :meth:`take_tracked` of ``frame`` as if :meth:`track` had run here."""
        self._tracked[frame.index] = tracked

    # ------------------------------------------------------------------ stages
    def _track(self, color, depth) -> tuple:
        """``(FeatureSet, matches, corners detected, clock seconds)`` of the next frame."""
        t0 = self.clock()
        gray = cv2.cvtColor(color, cv2.COLOR_BGR2GRAY) if color.ndim == 3 else color
        fs, matches = self._features.process(gray, depth)
        return fs, matches, self._features.last_detected, self.clock() - t0

    def _check(self, frame: RGBDFrame):
        K = self.intrinsics
        color, depth = frame.color, frame.depth
        if depth is None or depth.ndim != 2 or depth.shape != (K.height, K.width):
            raise InputError(f"frame {frame.index}: depth image {getattr(depth, 'shape', None)} does not match "
                             f"the calibration ({K.height}, {K.width}); register depth to the colour camera")
        if color is None or color.shape[:2] != (K.height, K.width) or color.dtype != np.uint8:
            raise InputError(f"frame {frame.index}: colour image {getattr(color, 'shape', None)} "
                             f"{getattr(color, 'dtype', '')} does not match the calibration "
                             f"({K.height}, {K.width}, 3) uint8")
        if depth.dtype != np.float32:
            depth = depth.astype(np.float32)
        return color, depth

    def _detect_planes(self, depth: np.ndarray, info: FrameDiagnostics) -> PlaneDetection:
        lev = self._levelling
        s = lev.state
        seed = self.last_detection.floor if self.last_detection is not None else None
        det = self._planes.detect(depth, floor_offset_hint=s.height if s.ready else None, levelled=s.ready,
                                  floor_seed=seed)
        floor = det.floor
        if floor is not None and lev.observe_floor(floor.normal, floor.offset, floor.support):
            old_R = self._planes.R_lev_cam
            self._planes.set_levelling(lev.state.R_lev_cam)
            # A large correction (bootstrap) invalidates this frame's walls: detect again.
            dR = old_R @ lev.state.R_lev_cam.T
            if math.degrees(math.acos(min(1.0, (np.trace(dR) - 1) / 2))) > 0.5:
                det = self._planes.detect(depth, floor_offset_hint=None, levelled=lev.state.ready)
                floor = det.floor
        s = lev.state
        floor_cam = None
        if floor is not None:
            floor_cam = (self._planes.R_lev_cam.T @ floor.normal).tolist()
        info.floor_seen = floor is not None
        info.planes = len(det.horizontals) + len(det.walls)
        info.walls = len(det.walls)
        info.wall_fraction = det.wall_fraction
        info.floor_fraction = floor.support if floor is not None else 0.0
        info.levelling = replace(s)  # a snapshot: the levelling goes on changing
        info.floor_normal_cam = floor_cam
        info.camera_height_m = floor.offset if floor is not None else None
        self.last_detection = det  # for diagnostics and tests; not part of FrameResult
        return det

    def _on_planes(self, prev: _Prev, planes, P1, P2, yaw: float):
        """:func:`refine_pairs_on_planes` of the matches: ``(P1, P2, depth variance scales)``."""
        c, o = self.config.odometry, self._dpp_opt
        if not c.plane_refine:
            return P1, P2, None
        Q1, Q2, s1, s2 = refine_pairs_on_planes(
            P1, P2, prev.planes or [], planes, yaw, depth_sigma_const=o.depth_sigma_const,
            depth_sigma_quad=o.depth_sigma_quad, incidence=c.depth_incidence, ray_sigma=o.pixel_sigma / o.focal_px,
            plane_sigma=c.plane_sigma_m, gate_chi2=o.chi2, min_cos=c.plane_min_cos)
        return Q1, Q2, (s1, s2)

    def _estimate(self, prev: _Prev, x_lev, P_lev, matches, frames, walls, yaw_prior, info, planes):
        """The step into this frame, in order of preference (module docstring)."""
        c = self.config.odometry
        x1, x2, P1, P2, depth_ok = self._matched(prev, x_lev, P_lev, matches, info)
        mount_se2 = geometry.mount_se2(self.mount.T_base_cam)
        # the 1-point translation uses the plane-refined depths
        pts = self._on_planes(prev, planes, P1, P2, yaw_prior)
        dpp, mf_yaw = self._dpp(prev, frames, walls, pts, int(depth_ok.sum()), yaw_prior, info)
        two = self._two_point(x1, x2, P1, P2, info, mount_se2)
        across = c.min_inlier_spread_px / self.intrinsics.fx
        dpp, two = (None if e is None or _collinear(x2[e[1].inliers], c.min_inlier_spread, info, across) else e
                    for e in (dpp, two))
        # The veto needs only the 2-point yaw, which a refused scale leaves intact: in an
        # open hall a track jumping to a box face 5 deg off came with too few depths for a
        # whole 2-point step and went through (-5.2 deg in one step on a tuning hall).
        # A wrong association leaves no Manhattan yaw for a partial step either, and the
        # Manhattan yaw of a step whose 1-point translation failed passes the same test.
        # Scored on the depths as read, here and in _rotation_under_walls: the plane-refined
        # ones share the walls' fits (_vetoed).
        raw = (P1, P2, None)
        if dpp is not None and two is not None and self._vetoed(dpp, two, raw, info):
            dpp, mf_yaw = None, None
        elif dpp is None and mf_yaw is not None and two is not None and self._partial_vetoed(mf_yaw, two, raw, info):
            mf_yaw = None
        two, weak = self._weak_scale(two, mf_yaw, info)
        if two is not None and mf_yaw is not None and two[1].status == "pure_rotation":
            two = self._rotation_under_walls(two, mf_yaw, raw, info)
        if weak is not None and mf_yaw is None:
            # no wall gives the yaw, the 2-point method does: a partial step at its yaw,
            # measured from the keyframe when it can be
            mf_yaw = self._keyframe_yaw(weak, x_lev, P_lev, mount_se2, info)
        depth = _typical_depth(P1)
        for est, status in ((dpp, STATUS_DPP), (two, STATUS_2PT)):
            if est is None:
                continue
            motion, e = est[0], est[1]
            yaw, t, cov = motion.yaw, motion.t, e.covariance
            weak = status == STATUS_2PT and self._weak_scale_aligns(info)
            if weak:
                (yaw, t), cov, _ = self._aligned((yaw, t), cov, prev, info, "frame")
            kf = self._from_keyframe(status, (motion.yaw, motion.t), e.covariance, x_lev, P_lev, planes, mount_se2,
                                     info, weak)
            link, cov_t = None, cov
            if kf is not None:
                (yaw, t), link, cov_t = self._keyframe_step(kf, cov)
            if status == STATUS_2PT and self._velocity_jump(t, cov_t, info):
                continue
            step = self._accept(yaw, t, cov, status, e.num_inliers, mount_se2, info, link, cov_t, depth)
            if step is not None:
                if status == STATUS_DPP:
                    self._dpp_track = est[2]
                if kf is None and self.config.odometry.keyframes and not self._keyframes.active():
                    # the keyframe is the previous frame: the step is the motion from it
                    kf = ((yaw, np.asarray(t, float)), cov)
                self._kf_measured = kf[:2] if kf is not None else None
                return step
        return self._partial_or_bridge(prev.walls, walls, mf_yaw, mount_se2, info, pts, x_lev, P_lev)

    def _keyframe_step(self, kf, cov: np.ndarray):
        """``(step, link, cov_t)`` of a step taken as the difference of two motions from the
        keyframe, ``kf`` as :meth:`_from_keyframe` returns it: the levelled step ``(yaw, t)``,
        the link ``(lag, motion, cov, guess_cov)`` and the step's (3, 3) covariance
        (:func:`_step_covariance`; ``cov``: the frame-to-frame estimate's)."""
        kt = self._keyframes
        # the step also takes back what guessed steps since the last measurement got wrong;
        # after a depth-aligned motion, all of the last one's error: its scale came from
        # another alignment, or from a few depths alone (its guesses included)
        carried = kt.kf.cov if kf[3] else kt.kf.guess_cov
        link = (kt.kf.age + 1, kf[0], kf[1], kt.kf.guess_cov)
        return kt.step_from(kf[0]), link, _step_covariance(kf[1], cov, kf[2], carried)

    def _from_keyframe(self, status: str, step: tuple[float, np.ndarray], cov: np.ndarray, x_lev, P_lev, planes,
                       mount_se2, info, weak: bool = False) -> tuple | None:
        """``(motion, cov, chained, aligned)``: the motion keyframe -> this frame re-measured
        with the step's estimator, its (3, 3) covariance over ``(yaw, t_x, t_z)``, whether it
        kept the chained yaw, and whether it was depth-aligned; or None (no earlier keyframe,
        too few corners, or a motion that disagrees with the chained steps;
        frontend/keyframe.py). ``weak``: the step's scale is weak: a motion that passed is
        then aligned against the keyframe's depth (:meth:`_aligned`). The gate compares the
        motions as measured, ``step`` and ``cov`` the frame-to-frame estimate's before its
        own alignment: compared with aligned steps, whose sigmas along the motion are a
        tenth of the few depths', the motions from the keyframe failed it and the keyframe
        was renewed, the step taken frame to frame (in tests/test_keyframe.py's weak-scale
        drive, 2.7 sigma sideways).

        ``step``: the step's levelled ``(yaw, t)`` with covariance ``cov``. A direction-plus-
        point step keeps its Manhattan yaw (eq. 1 telescopes along the track): only the
        translation is solved again (eq. 2) at the chained yaw; so is a 2-point step after
        one since the keyframe (the chain's yaw is the walls'); a 2-point step on a 2-point
        chain is solved again whole.
        """
        c, kt = self.config.odometry, self._keyframes
        if not (c.keyframes and kt.active()) or (status == STATUS_DPP and not c.keyframe_dpp):
            return None
        kf = kt.kf
        pred = kt.predicted(step)
        x1, x2, P1, P2 = kt.correspondences(x_lev, P_lev)
        n_depth = int((np.isfinite(P1).all(1) & np.isfinite(P2).all(1)).sum())
        chained = status == STATUS_DPP or kf.walls
        if chained:
            pts = self._on_planes(kf, planes, P1, P2, pred[0])
            yaw_sigma = math.sqrt(kf.cov[0, 0] + cov[0, 0])
            motion, est = estimate_planar_motion_dpp(pts[0], pts[1], pred[0], self._dpp_opt, yaw_sigma=yaw_sigma,
                                                     depth_scale=pts[2])
            ok = (motion is not None and est.num_inliers >= c.dpp_min_inliers
                  and est.num_inliers >= c.dpp_min_inlier_ratio * max(n_depth, 1))
        else:
            if len(x1) < 2:
                return None
            motion, est = estimate_planar_motion_2pt_metric(x1, x2, P1, P2, self._keyframe_two_point_options(
                mount_se2, kf.age))
            ok = (motion is not None and est.covariance is not None and est.num_inliers >= c.min_inliers
                  and est.num_inliers >= c.min_inlier_ratio * len(x1)
                  and int(est.scale_inliers.sum()) >= c.weak_scale_inliers)
        if not ok:
            return None
        d = np.array([float(geometry.wrap_angle(motion.yaw - pred[0])), motion.t[0] - pred[1][0],
                      motion.t[2] - pred[1][2]])
        S = kf.cov + cov + est.covariance
        m2 = float(d @ np.linalg.solve(S, d))
        if not m2 <= c.keyframe_gate_chi2:
            info.rejected.append({"status": status, "keyframe_sigmas": math.sqrt(m2), "keyframe_age": kf.age})
            return None
        m = (float(motion.yaw), np.asarray(motion.t, float))
        if not weak:
            return m, est.covariance, chained, False
        m, cov_k, aligned = self._aligned(m, est.covariance, kf, info, "keyframe")
        return m, cov_k, chained, aligned

    def _two_point_from_keyframe(self, x_lev, P_lev, mount_se2) -> tuple:
        """``(x1, motion, est)``: the 2-point metric motion from the keyframe K to this frame
        over K's corners still tracked (``x1`` their levelled coordinates in K), with the
        image noise of tracks as old as K; ``(x1, None, None)`` with fewer than two."""
        x1, x2, P1, P2 = self._keyframes.correspondences(x_lev, P_lev)
        if len(x1) < 2:
            return x1, None, None
        return (x1,) + tuple(estimate_planar_motion_2pt_metric(
            x1, x2, P1, P2, self._keyframe_two_point_options(mount_se2, self._keyframes.kf.age)))

    def _keyframe_two_point_options(self, mount_se2, age: int):
        """The 2-point options for a motion from a keyframe ``age`` frames back: a corner
        tracked frame by frame (KLT) wanders from where it was first seen by a random walk,
        so its image error grows as ``keyframe_track_px * sqrt(age)`` on top of the
        per-frame ``pixel_sigma`` (added in variance)."""
        opt = replace(self._two_point_options(mount_se2), follow_heading=False)  # no single arc
        walk = self.config.odometry.keyframe_track_px
        if walk <= 0 or age <= 0:
            return opt
        return replace(opt, pixel_sigma=math.sqrt(opt.pixel_sigma ** 2 + age * walk ** 2))

    def _matched(self, prev: _Prev, x_lev, P_lev, matches, info):
        """Matched levelled coordinates and points ``(x1, x2, P1, P2, depth_ok)``; runs the
        6-DoF planarity fit on frames without a floor."""
        c = self.config.odometry
        i0, i1 = matches[:, 0], matches[:, 1]
        x1, x2 = prev.x_lev[i0], x_lev[i1]
        P1, P2 = prev.P_lev[i0], P_lev[i1]
        ok = np.isfinite(x1).all(1) & np.isfinite(x2).all(1)
        x1, x2, P1, P2 = x1[ok], x2[ok], P1[ok], P2[ok]
        depth_ok = np.isfinite(P1[:, 2]) & np.isfinite(P2[:, 2])
        info.matches_with_depth = int(depth_ok.sum())
        # The floor, when seen, judges planarity far better (planar_vo.pipeline): the 6-DoF
        # check is only needed on frames without one.
        if c.planarity_check and depth_ok.sum() >= 8 and not info.floor_seen:
            oop = out_of_plane_motion(P1[depth_ok], P2[depth_ok], seed=c.seed)
            info.out_of_plane = oop
        return x1, x2, P1, P2, depth_ok

    def _dpp(self, prev: _Prev, frames, walls, pts, n_depth: int, yaw_prior: float, info):
        """Direction-plus-point (Sec. 2.1): ``((motion, est, track, local yaw) or None, mf_yaw)``.

        ``pts``: ``(P1 (M, 3), P2 (M, 3), depth variance scales or None)`` of the matches,
        refined on the planes (:meth:`_on_planes`).

        The yaw is the difference of the two views' headings of one local Manhattan frame
        (eq. 1) with their own sigmas; the 1-point RANSAC (eq. 2) only finds ``t`` at that
        yaw. ``mf_yaw``: ``(yaw, sigma, frame-to-frame yaw, track)`` of the dominant usable frame, or None -- a step
        whose translation fails keeps it (a partial step).
        """
        c = self.config.odometry
        n_depth = max(n_depth, 1)
        best, mf_yaw = None, None
        # Stay with the track used last: switching tracks adds both tracks' errors.
        for f in sorted(frames, key=lambda f: (f.track_id != self._dpp_track, -f.score)):
            if (f.prev_heading is None or f.age < c.dpp_min_track_age
                    or min(f.score, f.prev_score) < c.dpp_min_score):
                continue
            # Weak observations leave the step to the 2-point method; a strong one's yaw
            # difference errs only by the image-to-image part of the two sigmas.
            if math.hypot(f.sigma, f.prev_sigma) > math.radians(c.dpp_max_yaw_sigma_deg):
                continue
            yaw_sigma = f.step_sigma()
            yaw = yaw_from_manhattan_headings(f.prev_heading, f.heading, yaw_prior)
            # The matches see the frame-to-frame rotation; the step's yaw also takes back
            # what earlier steps got wrong since the reference (a few tenths of a degree,
            # which moves the next position by well under a millimetre).
            local = yaw_from_manhattan_headings(f.prev_local, f.heading, yaw_prior)
            yaw, local, yaw_sigma = self._same_walls(prev, f, walls, yaw, local, yaw_sigma, info)
            if self._reference_jumped(f, yaw, local, yaw_sigma, info):
                continue
            if mf_yaw is None and f.score >= c.bridge_min_score:
                mf_yaw = (yaw, yaw_sigma, local, f.track_id)
            # the translation is solved at this yaw: its error, floor included, moves the
            # camera sideways by the points' distance times the yaw error (correlated)
            t_yaw_sigma = math.hypot(yaw_sigma, math.radians(c.min_sigma_theta_deg))
            motion, est = estimate_planar_motion_dpp(pts[0], pts[1], local, self._dpp_opt, yaw_sigma=t_yaw_sigma,
                                                     depth_scale=pts[2])
            info.dpp.append({"status": est.status, "inliers": est.num_inliers,
                             "track_id": f.track_id, "yaw_sigma": yaw_sigma})
            if motion is None or est.num_inliers < c.dpp_min_inliers:
                continue
            if best is None or est.num_inliers > best[1].num_inliers:
                best = (replace(motion, yaw=float(geometry.wrap_angle(yaw))), est, f.track_id, motion.yaw)
            if est.num_inliers >= 0.8 * n_depth:
                break
        if best is not None and best[1].num_inliers < c.dpp_min_inlier_ratio * n_depth:
            best = None
        return best, mf_yaw

    def _reference_jumped(self, f: LocalFrame, yaw: float, local: float, yaw_sigma: float, info) -> bool:
        """True when the track's carried reference no longer belongs to the surfaces it sees.

        The step's yaw takes back what the steps the reference was carried over got wrong
        (``yaw - local``: a few tenths of a degree). In an open hall a track unseen for a
        frame can come back on another surface within the tracking gate -- a box face 5 deg
        off the one it followed -- and the whole jump would enter one step as rotation
        (-5.2 deg on a tuning hall, the 2-point yaw agreeing with ``local``). Beyond
        ``dpp_veto_sigmas`` of the step's sigma and ``reference_jump_min_deg`` the frame is
        not used for this step; its observation then becomes the track's new reference.
        """
        c = self.config.odometry
        d = abs(float(geometry.wrap_angle(yaw - local)))
        if d <= max(c.dpp_veto_sigmas * yaw_sigma, math.radians(c.reference_jump_min_deg)):
            return False
        info.rejected.append({"track_id": f.track_id, "reference_jump_deg": math.degrees(d)})
        return True

    def _same_walls(self, prev: _Prev, f: LocalFrame, walls, yaw: float, local: float, yaw_sigma: float, info):
        """``(yaw, local, yaw_sigma)`` of the direction-plus-point step, checked wall by wall
        when ``odometry.wall_yaw_check_sigmas`` > 0 (off by default).

        When the track's reference is its observation in the previous frame, the walls of
        the frame in both views are paired (:func:`match_walls`) and eq. 1 is also applied
        wall by wall. A disagreement beyond ``wall_yaw_check_sigmas`` means the group's
        walls changed (a wall a degree or two off joined or left it): the wall-by-wall yaw
        is used. Otherwise the frame's yaw stands, since it telescopes along the track --
        which the substitution breaks when a face joins abruptly and fades out gradually.
        """
        c = self.config.odometry
        pf = next((p for p in prev.frames if p.track_id == f.track_id), None)
        if c.wall_yaw_check_sigmas <= 0 or pf is None or f.prev_heading is None or f.prev_heading != pf.heading:
            return yaw, local, yaw_sigma
        t = self._last_motion[1] if self._last_motion is not None else np.zeros(3)
        pairs = match_walls([prev.walls[i] for i in pf.walls], [walls[j] for j in f.walls], yaw,
                            np.array([t[0], t[2]]), c)
        if not pairs:
            return yaw, local, yaw_sigma
        y_w, s_w = yaw_from_wall_pairs(pairs, yaw)
        d = float(geometry.wrap_angle(y_w - yaw))
        if abs(d) <= c.wall_yaw_check_sigmas * math.hypot(s_w, yaw_sigma):
            return yaw, local, yaw_sigma
        info.group_changed = {"track_id": f.track_id, "frame_minus_walls_deg": -math.degrees(d),
                              "pairs": len(pairs)}
        return y_w, y_w, s_w

    def _two_point(self, x1, x2, P1, P2, info, mount_se2=None):
        """2-point homography with metric scale from depth (Sec. 2.2): ``(motion, est)`` or None.
        ``mount_se2`` (3,): the planar mount, for the wheeled base's no-sideways-slip prior
        (``odometry.lateral_slip``)."""
        c = self.config.odometry
        if len(x1) < 2:
            return None
        motion, est = estimate_planar_motion_2pt_metric(x1, x2, P1, P2, self._two_point_options(mount_se2))
        n_in = est.num_inliers
        cells = occupied_cells(x2[est.inliers]) if est.inliers is not None else 0
        if motion is not None and est.covariance is not None:
            z = P1[est.inliers, 2]
            z = z[np.isfinite(z)]
            est.covariance = inflate_crowded_yaw(est.covariance, cells, c.two_point_min_cells,
                                                 float(np.median(z)) if len(z) else math.nan)
        n_scale = int(est.scale_inliers.sum()) if est.scale_inliers is not None else 0
        info.two_point = {"status": est.status, "inliers": n_in, "scale_inliers": n_scale,
                          "iterations": est.iterations, "cells": cells}
        # from yaw_only_min_inliers on the estimate may still give a pure rotation's yaw
        # (_weak_scale); a whole step needs min_inliers
        if (motion is not None and n_in >= min(c.min_inliers, c.yaw_only_min_inliers)
                and n_in >= c.min_inlier_ratio * len(x1)
                and abs(motion.yaw) <= math.radians(c.max_step_yaw_deg)
                and est.covariance is not None and est.covariance[0, 0] > 0):
            return motion, est
        return None

    def _two_point_options(self, mount_se2=None) -> MetricTwoPointOptions:
        """The 2-point options, with the wheeled base's no-sideways-slip prior when
        ``odometry.lateral_slip`` is set and ``mount_se2`` (3,) is given (pure rotations
        fitted on the heading with ``odometry.pure_rotation_on_heading``)."""
        c = self.config.odometry
        if c.lateral_slip > 0 and mount_se2 is not None:
            return replace(self._2pt_opt, mount_se2=tuple(float(v) for v in mount_se2),
                           follow_heading=c.pure_rotation_on_heading)
        return self._2pt_opt

    def _weak_scale(self, two, mf_yaw, info):
        """``(two, yaw)``: the 2-point estimate kept as a whole step, or its yaw alone.

        The yaw and the direction of a 2-point step come from all its image matches; only
        the metric scale needs depth. In an open hall most corners lie beyond the depth
        range (walls 5 m away and more), and a robot starting from rest makes millimetre
        steps: on the low-texture tuning halls 5-11 of ~100 matches had depth, and the
        steps so refused were bridged at zero motion with a 1 m sigma (1.5-4 m of path
        lost at the start of 300-frame logs). A scale from ``min_scale_inliers`` agreeing
        depths is trusted as it is; from ``weak_scale_inliers`` on it is kept when no
        Manhattan yaw offers a partial step instead (a scale from a handful of depths is
        less sure than two walls' offsets); below that only the 2-point yaw is used
        (``yaw`` = ``(yaw, sigma, yaw)`` for a partial step), never a scale none agreed on.
        """
        c = self.config.odometry
        if two is None:
            return None, None
        est = two[1]
        n_scale = info.two_point["scale_inliers"]  # stated by _two_point
        whole = est.num_inliers >= c.min_inliers
        if n_scale >= c.min_scale_inliers and whole:
            return two, None
        # A few depths can bend the joint fit's yaw away from what the image matches say
        # (a depth-edge point passing the scale gate); then the step is not trusted and
        # its yaw is the matches' own, with the disagreement as its sigma.
        sigma, _, bend = _image_yaw_bend(two[0], est)
        if n_scale >= c.weak_scale_inliers and mf_yaw is None and bend <= 3.0 * sigma and whole:
            return two, None
        info.two_point["scale_refused"] = n_scale
        yaw = _refused_scale_yaw(two[0], est)
        return None, None if yaw is None else (yaw[0], yaw[1], yaw[0])

    def _rotation_under_walls(self, two, mf_yaw: tuple[float, float, float], pts, info):
        """``two``, or None where a 2-point estimate the images took for a pure rotation
        gives way to a Manhattan yaw ``mf_yaw`` (``_dpp``) measured better than its own: the
        step is then partial at that yaw, its translation from the same depths.

        A pure rotation's yaw maps the matches by rotation alone, so the flow of a forward
        motion towards far points turns into yaw: on a seen hall (hall_s6402, every match on
        an end wall 4.1-4.5 m ahead) four such steps in a row erred -0.4 to -0.8 deg at 1-2 of
        their sigmas, where the wall's yaw erred 0.01 deg, and their yaw-sideways correlation
        (-0.95) carried the graph's correction of the yaw into 0.1 m sideways. A Manhattan yaw
        beyond the veto's gate (:meth:`_vetoed`) gives way only if it explains the 3-D
        matches at a lower cost than the rotation's yaw, each with its best translation: on
        another seen hall (hall_s6305) a track vetoed the frame before came back 1.3 deg off
        with a 1-point translation refused (62 of 142 depths agreeing), and taken as the
        step's yaw it turned the final heading from -0.08 to -1.07 deg. (The veto a partial
        step's Manhattan yaw passes, :meth:`_partial_vetoed`, runs first with the same gate
        and cost test, so such a yaw rarely reaches this one.) ``pts``: the 3-D matches as
        read (``(P1, P2, None)``), for the reason :meth:`_vetoed` gives: the depths refined
        onto a wall fitted off move with it and vouch for its yaw."""
        var2 = two[1].covariance[0, 0]
        if mf_yaw[1] ** 2 >= var2:
            return two
        d = float(geometry.wrap_angle(mf_yaw[2] - two[0].yaw))
        if abs(d) > self._veto_gate(mf_yaw[1] ** 2, var2):
            _, cost_walls = self._best_at_yaw(replace(two[0], yaw=mf_yaw[2]), pts)
            _, cost_two = self._best_at_yaw(two[0], pts)
            if cost_two < cost_walls:
                info.two_point["kept_over_manhattan_deg"] = math.degrees(d)
                return two
        info.two_point["gave_way"] = "manhattan_yaw"
        return None

    def _keyframe_yaw(self, weak: tuple[float, float, float], x_lev, P_lev, mount_se2, info):
        """``(yaw, sigma, rate yaw)`` (rad) of a partial step whose yaw is the 2-point
        method's: the difference of the yaws from the keyframe K to this frame and to the
        previous one, or ``weak`` (its frame-to-frame yaw) when K is the previous frame, the
        chain since K took its yaw from walls, or the motion from K fails or disagrees. The
        rate yaw, which the next guesses turn at, stays the frame-to-frame one.

        Frame to frame, such yaws erred with a bias of their own per scene, which a chain
        of them collects: the partial steps of the held-out hall_s4205 summed -3.26 deg
        (292 steps; +0.93 from K), those of four tuning halls -0.71 to +0.91 deg (-0.10 to
        +0.45 from K; docs/bench/keyframe_partial_yaw_session27.md). Measured from K, the
        step's yaw errs by the difference of two motions' errors from K, and the chain
        since K telescopes to the last one: the errors no longer add up. The step's sigma is the frame-to-frame one with the
        guessed yaws' since K added (the comment at the sigma says why not two motions').
        """
        c, kt = self.config.odometry, self._keyframes
        if not (c.keyframes and c.keyframe_partial_yaw and kt.active()) or kt.kf.walls:
            return weak
        x1, motion, est = self._two_point_from_keyframe(x_lev, P_lev, mount_se2)
        if motion is None and est is None:
            return weak
        yaw = None
        if (motion is not None and est.covariance is not None and est.covariance[0, 0] > 0
                and est.num_inliers >= c.yaw_only_min_inliers and est.num_inliers >= c.min_inlier_ratio * len(x1)):
            trusted = est.scale_inliers is not None and int(est.scale_inliers.sum()) >= c.min_scale_inliers
            yaw = (float(motion.yaw), math.sqrt(float(est.covariance[0, 0]))) if trusted else \
                _refused_scale_yaw(motion, est)
        if yaw is None:
            return weak
        step_yaw = float(geometry.wrap_angle(yaw[0] - kt.kf.motion[0]))
        # Consecutive yaws from K share the drift of K's tracks (the keyframe_track_px walk
        # in their sigmas), so their difference errs like a frame-to-frame yaw; it also
        # takes back what guessed yaws since the last measurement got wrong.
        sigma = math.sqrt(weak[1] ** 2 + kt.kf.guess_cov[0, 0])
        d = float(geometry.wrap_angle(step_yaw - weak[0]))
        m2 = d * d / (kt.kf.cov[0, 0] + yaw[1] ** 2 + weak[1] ** 2)
        info.keyframe_yaw = {"age": kt.kf.age, "inliers": int(est.num_inliers), "yaw_deg": math.degrees(step_yaw),
                             "frame_deg": math.degrees(weak[0]), "sigmas": math.sqrt(m2)}
        if not m2 <= c.keyframe_gate_chi2:
            info.rejected.append({"status": STATUS_PARTIAL, "keyframe_sigmas": math.sqrt(m2),
                                  "keyframe_age": kt.kf.age})
            return weak
        self._kf_yaw = (kt.kf.age + 1, yaw[0], yaw[1] ** 2)
        # the next guesses turn at the frame-to-frame rate, not at what this step took back
        return step_yaw, sigma, weak[2]

    def _vetoed(self, dpp, two, pts, info) -> bool:
        """True when the 2-point yaw contradicts the Manhattan yaw (a wrong association).

        Both measure the same rotation, but the Manhattan yaw is the paper's drift-free one:
        the 2-point yaw may only veto it, never pull it (a biased 2-point yaw with a small
        variance would bend every step the same way and the chain would collect it).
        A veto needs the 2-point yaw to explain the 3-D matches at a lower truncated cost
        (MSAC, :func:`score_depth_matches`, the same test for both), each yaw with its best
        translation (:meth:`_best_at_yaw`). A wrong association leaves the 1-point
        translation few agreeing points, whereas a 2-point fit pulled along the yaw/sideways
        ambiguity by far image matches explains fewer depths than the walls' yaw does (five
        such steps at a 37 deg junction, each 2.6-2.9 deg off at a stated 0.08 deg, had
        vetoed direction-plus-point steps with every depth agreeing). The cost, not the
        count: facing one wall a yaw error is nearly a sideways shift, the two counts tie
        within a match or two either way, and the cost still tells them apart (a Manhattan
        yaw 0.51 deg off on a held-out hall: 37 against 36 matches, cost 113 against 72).

        ``pts``: the 3-D matches as read (``(P1, P2, None)``), not refined onto the walls
        (:func:`refine_pairs_on_planes`): a wall fitted a degree or two off in one frame
        gives the wrong Manhattan yaw and moves the depths refined onto it rigidly with it,
        so they vouched for the error they were to test (unseen hall_s8601: a frontal wall
        3.7 m ahead fitted 1.7 deg off; refined, 84 of 129 depths agreed with the wrong yaw
        and 58 with the 2-point one; as read, 110 and all 129, cost 573 against 184).
        """
        return self._veto(dpp[3], dpp[1].covariance[0, 0], dpp[2], two, pts, info,
                          lambda: self._best_at_yaw(replace(dpp[0], yaw=dpp[3]), pts))

    def _partial_vetoed(self, mf_yaw: tuple[float, float, float, int], two, pts, info) -> bool:
        """:meth:`_vetoed` for the Manhattan yaw ``mf_yaw`` (``_dpp``) of a step whose 1-point
        translation failed: the partial step would keep that yaw, so it passes the same
        test, its translation the best the 3-D matches give at that yaw. Without it a track
        whose heading jumped 6.2 deg (loop_s8007 of the low-texture speed-dip probe of
        seeds 8000-8099; 3 of 8 depths agreeing at that yaw) turned the raw chain by 5.9 deg
        in one partial step stated at 0.1 deg, while the 2-point yaw of 27 matches had it
        right."""
        if pts is None:
            return False
        c = self.config.odometry
        var = mf_yaw[1] ** 2 + math.radians(c.min_sigma_theta_deg) ** 2  # as the step's translation is solved
        return self._veto(mf_yaw[2], var, mf_yaw[3], two, pts, info,
                          lambda: self._best_at_yaw(replace(two[0], yaw=mf_yaw[2]), pts), partial=True)

    def _veto(self, local: float, var: float, track, two, pts, info, walls_score, partial: bool = False) -> bool:
        """The veto test of a Manhattan frame-to-frame yaw ``local`` (rad, variance ``var``)
        against the 2-point estimate ``two``; ``walls_score()``: ``(inliers, cost)`` of the
        Manhattan yaw on the 3-D matches."""
        var2 = two[1].covariance[0, 0]
        d = float(geometry.wrap_angle(local - two[0].yaw))
        gate = self._veto_gate(var, var2)
        check = {"dpp_minus_2pt_deg": math.degrees(d), "sigma_deg": math.degrees(math.sqrt(var + var2)),
                 "vetoed": abs(d) > gate, "track_id": track}
        if partial:
            check["partial"] = True
        info.yaw_check = check
        if not check["vetoed"]:
            return False
        n_dpp, cost_dpp = walls_score()
        n_two, cost_two = self._best_at_yaw(two[0], pts)
        check.update(dpp_support=n_dpp, two_point_support=n_two, dpp_cost=cost_dpp, two_point_cost=cost_two)
        check["vetoed"] = bool(cost_two < cost_dpp)
        return check["vetoed"]

    def _veto_gate(self, var_walls: float, var_two: float) -> float:
        """How far (rad) a Manhattan yaw and a 2-point yaw of variances ``var_walls`` and
        ``var_two`` may differ before one is tested against the other on the 3-D matches:
        ``dpp_veto_sigmas`` of their joint sigma, at least ``dpp_veto_min_deg``."""
        c = self.config.odometry
        return max(c.dpp_veto_sigmas * math.sqrt(var_walls + var_two), math.radians(c.dpp_veto_min_deg))

    def _best_at_yaw(self, motion, pts) -> tuple[int, float]:
        """``(inliers, cost)`` on the 3-D matches of the best translation at ``motion``'s yaw:
        its own, or the 1-point RANSAC's (eq. 2) at that yaw, whichever explains more
        matches (then at the lower cost).

        The direction-plus-point translation was fitted to these very matches; a 2-point
        translation was fitted to the image. Scored as they came, a wrong Manhattan yaw
        whose translation soaked up the yaw error sideways out-scored the right 2-point
        yaw (35 against 16 matches, 1.9 deg apart, on a held-out hall). Both yaws now get
        the same translation search, so the score compares the yaws.
        """
        best = score_depth_matches(pts[0], pts[1], motion, self._dpp_opt, pts[2])
        refit, _ = estimate_planar_motion_dpp(pts[0], pts[1], motion.yaw, self._dpp_opt, depth_scale=pts[2])
        if refit is not None:
            best = max(best, score_depth_matches(pts[0], pts[1], refit, self._dpp_opt, pts[2]),
                       key=lambda s: (s[0], -s[1]))
        return best

    def _partial_or_bridge(self, walls1, walls2, mf_yaw, mount_se2, info, pts=None, x_lev=None, P_lev=None):
        """No estimator gave a whole step. With a Manhattan yaw the step is partial: that yaw
        at its own sigma, and the translation along the normals of walls seen in both
        frames (``d2 - d1 = n2 . t``), from a few 3-D matches and the depth alignment
        (:meth:`_partial_translation`); what none fixes stays at the bridge's guess
        (constant velocity or zero) and sigma. Without one, the yaw may come from the depth
        images (:meth:`_depth_yaw`); failing that, a step whose translation something
        measured is partial at the guessed yaw and its sigma, and only a step of which
        nothing was measured is bridged."""
        c = self.config.odometry
        cv = c.bridge == "constant_velocity" and self._last_motion is not None
        (yaw, t), how = (self._last_motion, "constant_velocity") if cv else ((0.0, np.zeros(3)), "zero")
        self._since_t += 1
        sb, s_theta = self._bridge_sigmas(how == "zero")
        far, sb_t = self._far_resection(x_lev, yaw, t, mf_yaw, sb, mount_se2, info)
        turned = mf_yaw is not None  # by walls or corners
        if not turned:
            # no wall and no 2-point yaw: the depth images may still turn (pillars, boxes)
            mf_yaw = self._depth_yaw(yaw, t, sb, mount_se2, info)
        if mf_yaw is None:
            mf_yaw = self._far_yaw(far, yaw, s_theta, info)
        if mf_yaw is not None:
            self._since_yaw = 0
            yaw, sigma_yaw, yaw_ff = mf_yaw[0], max(mf_yaw[1], math.radians(c.min_sigma_theta_deg)), mf_yaw[2]
        else:
            sigma_yaw, yaw_ff = s_theta, yaw
        prior, prior_cov = np.array([t[0], t[2]]), sb_t
        if c.lateral_slip > 0:
            prior, prior_cov = self._wheeled_prior(yaw, prior, sb_t, mount_se2)
        t_xz, cov_t, counts = self._partial_translation(walls1, walls2, yaw, yaw_ff, prior, prior_cov, pts, info,
                                                        wide=not turned, far=far)
        kf_t = None
        if turned and not self._translation_measured(counts):
            # nothing measured the whole translation: the motion from K may
            kf_t = self._keyframe_translation(x_lev, P_lev, yaw, sigma_yaw, t, sb, mount_se2, info)
            if kf_t is not None:
                t_xz, cov_t, counts = self._partial_translation(walls1, walls2, yaw, yaw_ff, *_kf_prior(kf_t), pts,
                                                                info, far=far, dense=counts["dense"] > 0)
        counts["keyframe"] = int(kf_t is not None)
        if mf_yaw is None and not any(counts.values()):
            return self._bridge(yaw, t, sb, s_theta, how, mount_se2, info)
        self._since_yaw += int(mf_yaw is None)  # the yaw is still the guess
        t = np.array([t_xz[0], 0.0, t_xz[1]])
        # No floor on top: every source states its own errors (with a 1 mm floor along the
        # track, two walls' steps stated 1.49 mm for 0.69 mm errors on two tuning logs)
        cov = np.block([[np.array([[sigma_yaw ** 2]]), np.zeros((1, 2))], [np.zeros((2, 1)), cov_t]])
        pose, cov_b = lev_motion_to_base_step(yaw, t, cov, mount_se2)
        # the depth alignment measures along the guess's long axis; on a wheeled base the
        # other is the chord of the turn, so it measures the whole translation
        measured = self._translation_measured(counts)
        info.partial = {"prior": how, **counts, "measured": measured, "yaw": "measured" if mf_yaw else "guess"}
        self._kf_guessed = ((float(yaw), np.asarray(t, float)), cov)
        guess = self._guess_information(yaw, t, None if kf_t is not None else prior_cov,
                                        sigma_yaw if mf_yaw is None else None, mount_se2)
        self._partial_guess(float(yaw_ff), t, cov, how, measured)
        if counts["keyframe"]:
            self._keyframe_guess(kf_t, (float(yaw), t))
        return (Step(pose, np.linalg.inv(cov_b), STATUS_PARTIAL, counts["walls"], keyframe_yaw=self._yaw_link(mount_se2),
                     guess_information=guess, guess_copies=self._since_t,
                     translation_measured=counts["far"] + counts["keyframe"] > 0), (yaw, t, sigma_yaw ** 2))

    @staticmethod
    def _guess_information(yaw: float, t: np.ndarray, prior_cov, sigma_yaw: float | None, mount_se2) -> np.ndarray:
        """(3, 3) base_link information of what of a partial step is the guess: its prior on
        the translation (``prior_cov``, None when something took the guess's place), and
        the yaw when none was measured (``sigma_yaw``, else None). The back-end's motion
        prior states the same constant velocity and takes its place."""
        Ji = np.linalg.inv(lev_to_base_jacobian(yaw, t, mount_se2))
        guess = np.zeros((3, 3))
        if prior_cov is not None:
            guess[1:, 1:] = np.linalg.inv(_prior_cov(prior_cov))
        if sigma_yaw is not None:
            guess[0, 0] = 1.0 / sigma_yaw ** 2
        return Ji.T @ guess @ Ji

    def _translation_measured(self, counts: dict) -> bool:
        """True when a partial step's sources (``counts`` of :meth:`_partial_translation`,
        and ``keyframe``) measured its whole translation: walls of two directions, or a wall
        and the depth alignment, the alignment alone on a wheeled base (the other direction
        is the chord of the turn), a resection against far corners, or the motion from K."""
        lateral = self.config.odometry.lateral_slip > 0
        return bool(counts["walls"] + counts["dense"] >= 2 or (counts["dense"] > 0 and lateral)
                    or counts["far"] > 0 or counts.get("keyframe", 0) > 0)

    def _keyframe_translation(self, x_lev, P_lev, yaw: float, sigma_yaw: float, t_guess: np.ndarray, sb: float,
                              mount_se2, info):
        """A partial step's translation measured from the keyframe K: ``(step (yaw, t),
        cov (3, 3), motion K -> here, its cov)`` or None (the step's covariance states
        two motions' errors and what the guesses since K got wrong, which it takes back).
        Its ``yaw`` (rad, levelled, at sigma ``sigma_yaw``) is measured (walls or the
        2-point method), ``t_guess`` (3,) the guess at sigma ``sb``.

        Frame to frame, the 2-point scale of a few depths (1-4 corners of an open hall in
        range) errs like a whole step (its depth noise, 1-3 cm, does not shrink with a
        20-40 mm step), and such scales are refused (:meth:`_weak_scale`); the step then
        copied a guess, and a base speeding up from rest was guessed at the speed it had
        when the last scale was measured (a seen hall, hall_s8105: 40 steps at 15 mm for 39,
        1 m short). From K the same corners' depths measure a motion of tens of
        centimetres with the same error (frontend/keyframe.py): the step is the difference
        of two motions from K, so the chain telescopes, and it takes the guess's place
        (walls, matches and the depth alignment are fused on top). The motion's yaw must
        agree with the chain's (``keyframe_gate_chi2``), and the step be one the platform
        can drive."""
        c, kt = self.config.odometry, self._keyframes
        if not (c.keyframes and c.keyframe_partial_translation and kt.active()) or x_lev is None or P_lev is None:
            return None
        x1, motion, est = self._two_point_from_keyframe(x_lev, P_lev, mount_se2)
        # two depths at least, that agree: one alone, on a depth edge of a textureless
        # corridor, put its motion 372 mm off at a stated 9 mm, and the velocity copied
        # from it every guess after it 200 mm (tests/test_drift_free_yaw.py)
        if (motion is None or est.covariance is None or est.scale_inliers is None or est.scale_inliers.sum() < 2
                or est.num_inliers < c.yaw_only_min_inliers or est.num_inliers < c.min_inlier_ratio * len(x1)):
            return None
        m = (float(motion.yaw), np.asarray(motion.t, float))
        pred = kt.predicted((yaw, np.asarray(t_guess, float)))
        # The yaw must agree with the chain's: the guessed translations since K are what
        # this measures, and their stated sigmas assume a cruising base (a hall's base
        # speeding up from rest: K's motions 4-6 sigmas from the chain of guesses, within
        # millimetres of the truth). What the platform cannot drive is refused below.
        d = float(geometry.wrap_angle(m[0] - pred[0]))
        m2 = d * d / float(kt.kf.cov[0, 0] + sigma_yaw ** 2 + est.covariance[0, 0])
        info.partial_keyframe = {"age": kt.kf.age, "inliers": int(est.num_inliers),
                                 "depths": int(est.scale_inliers.sum()), "yaw_sigmas": math.sqrt(m2)}
        if not m2 <= c.keyframe_gate_chi2:
            return None
        step = kt.step_from(m)
        # The step errs by this motion's error and the last one's from K (one frame's depths
        # make one step long and the next short by as much: a slow tuning hall's 8 mm steps
        # went -32 to +78 mm, and stated at one motion's error the graph's robust loss took
        # some of them out, and with them what the next step took back), and by what the
        # guesses since K got wrong
        cov = 2.0 * est.covariance + kt.kf.guess_cov
        if self._impossible_motion(step[0], step[1], cov, mount_se2):
            info.partial_keyframe["refused"] = True
            return None
        return step, cov, m, est.covariance

    def _keyframe_guess(self, kf_t, step: tuple[float, np.ndarray]) -> None:
        """After a partial step ``step`` (levelled ``(yaw, t)``) whose translation was measured
        from K (``kf_t``, :meth:`_keyframe_translation`): K holds the motion to this frame as
        measured, and the next guesses copy the velocity of two motions from K
        (:meth:`KeyframeTracker.velocity`; the first since K: the motion over the frames
        since K), whose error does not grow with the steps between them (not the step's own
        translation, which errs by this frame's depths and the last one's alike).

        That motion is the chain's (K's motion composed with the step, which walls and
        matches may have moved off the motion from K: the next step from K takes it back;
        holding the motion from K lost it every step, a slow tuning hall's raw chain 0.26 ->
        0.74 %), unless the guesses since K are less sure than the motion from K: then the
        motion from K (with the guesses unknown, a textureless start from rest guessed at
        zero with a 1 m sigma, the step took another source's 382 mm and every guess after
        it copied a velocity 200 mm off, tests/test_drift_free_yaw.py)."""
        c, kt = self.config.odometry, self._keyframes
        m, cov_m = kf_t[2], kf_t[3]
        if np.linalg.eigvalsh(kt.kf.guess_cov[1:, 1:])[-1] <= np.linalg.eigvalsh(2.0 * cov_m[1:, 1:])[-1]:
            m = kt.predicted(step)
        self._kf_measured, self._kf_guessed = (m, cov_m), None
        v, n = self._keyframes.velocity(m, c.velocity_window)
        self._last_t_sigma = math.sqrt(2.0 * float(np.max(np.diag(cov_m[1:, 1:]))) + c.min_sigma_xy ** 2) / n
        self._remember_translation(v, self._last_t_sigma ** 2)
        self._last_motion = (self._last_motion[0], v)
        self._since_t = 0

    def _yaw_link(self, mount_se2) -> KeyframeYaw | None:
        """The base_link heading change from the keyframe of a partial step whose yaw
        :meth:`_keyframe_yaw` measured from it, or None."""
        if self._kf_yaw is None:
            return None
        lag, yaw, var = self._kf_yaw
        theta = float(lev_motion_to_base_step(yaw, np.zeros(3), None, mount_se2)[0][2])
        return KeyframeYaw(int(lag), theta, float(var))

    def _far_resection(self, x_lev, yaw: float, t: np.ndarray, mf_yaw, sb: float, mount_se2, info):
        """``(far, sb)``: the step resected against the far corners' depths
        (frontend/farcorners.py), ``(step (yaw, t), cov (3, 3), corners)`` or None, from the
        guess ``(yaw, t)`` or the measured yaw ``mf_yaw``; and the sigma (m) of the guess's
        translation ``sb`` to fuse it with (the yaw's search keeps ``sb``). It is fused
        wherever there is one (used only where it refuted the guess, noisy resected steps
        that passed it became the velocity the next guesses copied: a tuning hall, hall_s3704,
        0.72 -> 2.21 %). The step's yaw stays the walls', the 2-point method's or the depth
        images' (resected from 8-28 corners of a small image, yaws erred up to 0.9 deg where
        those measure hundredths)."""
        if self._far is None or x_lev is None:
            return None, sb
        guess_yaw, yaw_var = (yaw, None) if mf_yaw is None else (mf_yaw[0], mf_yaw[1] ** 2)
        far = self._far.step(x_lev, (guess_yaw, np.asarray(t, float)), yaw_var)
        if far is None:
            return None, sb
        info.far = {"corners": far[2], "t_m": [float(far[0][1][0]), float(far[0][1][2])],
                    "sigma_m": [math.sqrt(far[1][1, 1]), math.sqrt(far[1][2, 2])]}
        impossible = self._impossible_motion(guess_yaw, far[0][1], far[1], mount_se2)
        if impossible:
            info.far["refused"] = impossible
            return None, sb
        # Where they refute the guess (chi-square 9.21 over both covariances), the guess keeps
        # no more than the platform's reach: held at a stop's speed it outweighed a resection
        # of the base driving on (hall_s7700 of the low-texture speed-dip probe). Widened
        # wherever there was a resection, a weak one (8 corners, 86 mm) left a textureless
        # corridor's step to its walls at a yaw 2.5 deg off (tests/test_drift_free_yaw.py).
        d = np.array([far[0][1][0] - t[0], far[0][1][2] - t[2]])
        refuted = float(d @ np.linalg.solve(far[1][1:, 1:] + np.eye(2) * sb * sb, d)) > self._dpp_opt.chi2
        info.far["refutes_guess"] = refuted
        return far, max(sb, self.config.odometry.bridge_max_speed * self._dt) if refuted else sb

    def _far_yaw(self, far, guess_yaw: float, sigma_guess: float, info) -> tuple[float, float, float] | None:
        """``(yaw, sigma, yaw)`` (rad) of a step that nothing else turned, from its resection
        against the far corners ``far`` (:meth:`_far_resection`, resected at no yaw prior),
        or None: no resection, ``odometry.far_yaw`` off, or a resected yaw that states no
        less than the guess ``guess_yaw`` (sigma ``sigma_guess``) or disagrees with it by
        more than 3 of their joint sigmas (a resection on a few wrong tracks). The guess
        copies the last measured turn rate: through a weave that turns back it errs by the
        change of the turn rate times the steps since, where the corners measure the turn."""
        if far is None or not self.config.odometry.far_yaw:
            return None
        y, var = float(far[0][0]), float(far[1][0, 0])
        d = float(geometry.wrap_angle(y - guess_yaw))
        if not (var < sigma_guess ** 2 and d * d <= 9.0 * (var + sigma_guess ** 2)):
            return None
        info.far["yaw_deg"] = math.degrees(y)
        return y, math.sqrt(var), y

    def _impossible_motion(self, yaw: float, t: np.ndarray, cov: np.ndarray, mount_se2) -> str | None:
        """Why a resected step (levelled ``t`` (3,), ``cov`` (3, 3) over ``(yaw, t_x, t_z)``)
        at the step's ``yaw`` is one the platform cannot make, or None: longer than its reach
        (``bridge_max_speed`` per frame interval) by more than 3 of its sigmas, or, on a
        wheeled base (``lateral_slip`` > 0), sideways of the chord of its heading change
        beyond ``chi2`` (:meth:`_wheeled_prior` at the resection's own distance along).
        Resections from 8-13 corners of an untextured hall (an unseen set's log,
        hall_s7801) made 39 mm steps 188 and 297 mm backwards and 290 mm sideways, at
        sigmas of 16-51 mm; taken as measured, its smoothed end point went 1.8 -> 11 % off."""
        c = self.config.odometry
        t2, C = np.array([t[0], t[2]]), cov[1:, 1:]
        reach = c.bridge_max_speed * self._dt
        length = float(np.linalg.norm(t2))
        if length > reach and length - reach > 3.0 * math.sqrt(float(t2 @ C @ t2)) / length:
            return "beyond reach"
        if c.lateral_slip <= 0:
            return None
        prior, prior_cov = self._wheeled_prior(yaw, t2, reach, mount_se2)
        d = t2 - prior
        return "sideways" if float(d @ np.linalg.solve(C + prior_cov, d)) > self._dpp_opt.chi2 else None

    def _partial_translation(self, walls1, walls2, yaw: float, yaw_ff: float, prior: np.ndarray, prior_cov, pts,
                             info, wide: bool = False, far=None,
                             dense: bool = True) -> tuple[np.ndarray, np.ndarray, dict]:
        """A partial step's levelled ``(t_x, t_z)`` (2,), its (2, 2) covariance and the
        constraint counts: walls seen in both frames at the step's ``yaw``, the 1-point
        translation of a few 3-D matches and the depth alignment at the frame-to-frame
        ``yaw_ff``, over the guess ``prior`` with ``prior_cov``. ``wide``: the yaw is not
        one walls or corners measured (:meth:`_dense_translation`); then no 3-D matches.
        ``far``: the step resected against far corners (:meth:`_far_resection`), or None.
        ``dense``: False skips the depth alignment (it found nothing at this yaw already)."""
        c = self.config.odometry
        walls = wall_constraints(walls1, walls2, yaw, prior, c, prior_cov)
        t_xz, cov_t = translation_from_walls(walls, prior, prior_cov)
        # at a guessed yaw a point's translation is off sideways by its depth times the yaw's
        # error, which its covariance does not state: only walls and the alignment measure
        points, n_points = self._point_translation(pts, yaw_ff, (t_xz, cov_t), info) if not wide else ([], 0)
        if far is not None:
            # its (2, 2) covariance as two independent constraints along its axes
            lam, vec = np.linalg.eigh(far[1][1:, 1:])
            tf = np.array([far[0][1][0], far[0][1][2]])
            points = points + [(vec[:, j], float(vec[:, j] @ tf), float(lam[j])) for j in range(2)]
        if points:
            t_xz, cov_t = translation_from_walls(walls + points, prior, prior_cov)
        # walls of two directions measured the whole translation already; a few 3-D matches
        # did, but more coarsely (on the boxed textureless corridor of tests/test_depthalign.py,
        # before the contrast test: up to 5.1 mm against the alignment's 2.1 mm): both are used
        dense = [] if len(walls) >= 2 or not dense else self._dense_translation(yaw_ff, t_xz, cov_t, info, wide)
        if dense:
            t_xz, cov_t = translation_from_walls(walls + points + dense, prior, prior_cov)
        return t_xz, cov_t, {"walls": len(walls), "points": n_points, "dense": len(dense),
                             "far": far[2] if far is not None else 0}

    def _partial_guess(self, yaw_ff: float, t: np.ndarray, cov: np.ndarray, how: str, measured: bool) -> None:
        """The constant-velocity guess after a partial step of levelled ``t`` (3,), ``cov``
        (3, 3) over ``(yaw, t_x, t_z)``. The turn rate was measured (the frame-to-frame yaw
        ``yaw_ff``, not the step's, which also takes back the errors of earlier guesses):
        the next guess turns at this rate. The translation guess stays the last measured
        one, whose error _bridge_sigmas states: one wall fixes one direction only, and its
        step's other direction is the guess. Walls of two directions, or a wall and the
        depth alignment (``measured``), measure the whole translation: then it is the new
        guess. A few 3-D matches measure this step's translation but not well enough for a
        guess copied into the steps that follow (4.9 mm rms on 20 mm steps on a tuning
        hall; the bridges copying them went 2.7 mm/step astray)."""
        self._last_motion = (yaw_ff, np.array(t if how == "zero" or measured else self._last_motion[1], dtype=float))
        if measured:
            self._since_t = 0
            self._last_t_sigma = math.sqrt(float(np.max(np.diag(cov[1:, 1:]))))
        elif how == "zero":
            # the zero guess along the wall was never measured: the guesses copying it keep
            # the bridge's full sigma (a ring started at cruise speed lost 1.9 m over 55
            # such steps stated at 2-26 cm)
            self._last_t_sigma = self.config.odometry.bridge_sigma_xy

    def _bridge(self, yaw: float, t: np.ndarray, sb: float, s_theta: float, how: str, mount_se2, info):
        """A bridged step: the guess ``(yaw, t)`` (levelled) at sigmas ``sb`` (m) and
        ``s_theta`` (rad), all of its information a guess."""
        c = self.config.odometry
        self._since_yaw += 1
        # levelled (yaw, t_x, t_z), propagated like every other step: a camera ahead
        # of base_link swings sideways with the yaw the guess gets wrong
        cov = np.diag([s_theta ** 2, sb ** 2, sb ** 2])
        if c.lateral_slip > 0:
            # a wheeled base does not slide: the guess is one of the distance along (the
            # isotropic guess stated its sideways error 10x what it was on the tuning seeds)
            prior, cov[1:, 1:] = self._wheeled_prior(yaw, np.array([t[0], t[2]]), sb, mount_se2)
            t = np.array([prior[0], 0.0, prior[1]])
        pose, cov_b = lev_motion_to_base_step(yaw, t, cov, mount_se2)
        info.bridge = how
        self._kf_guessed = ((yaw, np.asarray(t, float)), cov)
        information = np.linalg.inv(cov_b)
        return (Step(pose, information, STATUS_BRIDGED, 0, guess_information=information, guess_copies=self._since_t),
                (yaw, t, s_theta ** 2))

    def _wheeled_prior(self, yaw: float, t_guess: np.ndarray, sb: float, mount_se2: np.ndarray):
        """Levelled ``(t_x, t_z)`` prior (2,) and its (2, 2) covariance for a partial step of
        a wheeled base at the measured ``yaw`` (rad): the guess ``t_guess`` (2,) gives only
        the distance along (sigma ``sb``, m); the base_link step runs along the chord of its
        heading change, ``y = x tan(yaw / 2)``, off it by the slip (``lateral_floor_m +
        lateral_slip |x|``). With an isotropic guess a wall paired with another plane moved a
        turning step 58 mm sideways, stated at 2.8 mm, on an untextured test hall."""
        c = self.config.odometry
        k, M = lev_to_base_affine(yaw, mount_se2)
        x = float((M @ t_guess + k)[0])
        half = math.tan(yaw / 2.0)
        slip = c.lateral_floor_m + c.lateral_slip * math.hypot(x, sb)
        J = np.array([[1.0, 0.0], [half, 1.0]])
        cov_base = J @ np.diag([sb ** 2, slip ** 2]) @ J.T
        Mi = np.linalg.inv(M)
        return Mi @ (np.array([x, x * half]) - k), Mi @ cov_base @ Mi.T

    def _point_translation(self, pts, yaw: float, known, info) -> tuple[list[tuple[np.ndarray, float, float]], int]:
        """``(constraints, matches)``: translation constraints (as :func:`wall_constraints`)
        from the few 3-D matches that agree at the partial step's frame-to-frame ``yaw``
        (rad), the 1-point translation of eq. 2 along levelled x and z, or none.
        ``pts``: the matches' plane-refined points of :meth:`_on_planes`, or None. ``known``:
        ``(t (2,), cov (2, 2))`` of the walls and the guess; points that contradict it beyond
        the 1-point gate (``chi2``, 2 dof) are not used: in a textureless corridor 5 of 8
        matches agreed 39 mm sideways of what two walls measured to 2 mm."""
        c = self.config.odometry
        if pts is None:
            return [], 0
        motion, est = estimate_planar_motion_dpp(pts[0], pts[1], yaw, self._dpp_opt, yaw_sigma=0.0,
                                                 depth_scale=pts[2])
        n_depth = int((np.isfinite(pts[0]).all(1) & np.isfinite(pts[1]).all(1)).sum())
        # As for direction-plus-point, matches that mostly disagree at this yaw mean a wrong
        # yaw or wrong matches. No test of the inliers' image spread: 3-5 points often lie
        # near one image line, and their depths give the translation (on a tuning hall the
        # spread test refused 21 of the first 40 steps' points, which erred 0-8 mm).
        if (motion is None or est.num_inliers < c.partial_min_points
                or est.num_inliers < c.dpp_min_inlier_ratio * n_depth):
            return [], 0
        cov = est.covariance
        d = np.array([motion.t[0], motion.t[2]]) - known[0]
        if float(d @ np.linalg.solve(cov[1:, 1:] + known[1], d)) > self._dpp_opt.chi2:
            info.rejected.append({"partial_points": int(est.num_inliers), "off_m": d.tolist()})
            return [], 0
        return [(np.array([1.0, 0.0]), float(motion.t[0]), float(cov[1, 1])),
                (np.array([0.0, 1.0]), float(motion.t[2]), float(cov[2, 2]))], int(est.num_inliers)

    def _weak_scale_aligns(self, info) -> bool:
        """True when this frame's 2-point step is kept with a weak scale (fewer than
        ``min_scale_inliers`` agreeing depths, :meth:`_weak_scale`) and
        ``odometry.weak_scale_align`` fuses the depth alignment into it (:meth:`_aligned`)."""
        c = self.config.odometry
        return bool(c.weak_scale_align and c.depth_align and info.two_point
                    and info.two_point.get("scale_inliers", c.min_scale_inliers) < c.min_scale_inliers)

    def _aligned(self, motion: tuple[float, np.ndarray], cov: np.ndarray, source, info, name: str):
        """``(motion, cov, fused)``: a weak-scale 2-point motion ``(yaw, t)`` (levelled, ``t`` (3,))
        from ``source`` (the previous frame's :class:`_Prev` or the keyframe) to this frame,
        with ``cov`` (3, 3) over ``(yaw, t_x, t_z)``, updated by the depth alignment of
        ``source``'s depth onto this frame's along the motion's least known axis (the larger
        axis of its translation covariance: the scale the few depths fixed).

        The alignment searches ``+-4`` of that axis' sigmas (``depth_align_min_range_m`` to
        ``depth_align_max_range_m``) at the motion's yaw; its distance ``s`` along ``u`` is a
        measurement of ``u . t`` of variance ``var``, fused as one Kalman update (the yaw and
        the other axis move by their correlation with ``u . t``). A distance beyond
        ``wall_gate_sigmas`` of the two combined sigmas means one of them is wrong: the
        motion is kept as it was (``fused`` False; ``info.two_point["aligned_..."]`` says
        which)."""
        c = self.config.odometry
        if source is None or source.depth is None or self._depth is None:
            return motion, cov, False
        yaw, t = motion
        t_xz = np.array([t[0], t[2]], dtype=float)
        u, a, _ = self._along_long_axis(source, yaw, t_xz, cov[1:, 1:])
        if a is None:
            info.two_point[f"aligned_{name}"] = None
            return motion, cov, False
        H = np.array([0.0, u[0], u[1]])
        S = float(H @ cov @ H) + a.var
        z = a.s / math.sqrt(S)
        info.two_point[f"aligned_{name}"] = {"s_m": a.s, "sigma_m": math.sqrt(a.var), "sigmas": z}
        if abs(z) > c.wall_gate_sigmas:
            return motion, cov, False
        K = cov @ H / S
        x = np.array([yaw, t_xz[0], t_xz[1]]) + K * a.s
        cov = cov - np.outer(K, H @ cov)
        return (float(x[0]), np.array([x[1], t[1], x[2]])), 0.5 * (cov + cov.T), True

    def _along_long_axis(self, source, yaw: float, t_xz: np.ndarray, cov_t: np.ndarray, wide: bool = False):
        """``(u, alignment, points)``: the depth alignment (:func:`align_along`, or None where
        it finds no clear minimum) of ``source``'s depth (a :class:`_Prev` or the keyframe)
        onto this frame's at ``yaw`` (rad), from the levelled translation ``t_xz`` (2,) along
        ``u`` (2,), the larger axis of its (2, 2) covariance ``cov_t``, over ``+-4`` of that
        axis' sigmas (``depth_align_min_range_m`` to ``depth_align_max_range_m``); ``points``:
        the informative points it used."""
        c = self.config.odometry
        lam, vec = np.linalg.eigh(cov_t)
        sigma, u = math.sqrt(max(float(lam[-1]), 0.0)), vec[:, -1]
        P1, normals = self._align_points(source)
        P1 = P1[informative(normals, u, self._align_opt)]
        half = min(max(4.0 * sigma, c.depth_align_min_range_m), c.depth_align_max_range_m)
        depth, R = self._depth
        return u, align_along(P1, depth, self.intrinsics, R, yaw, t_xz, u, half, self._align_opt, wide=wide), len(P1)

    def _align_points(self, source) -> tuple[np.ndarray, np.ndarray]:
        """The depth alignment's levelled points and normals (N, 3) each of ``source`` (a
        :class:`_Prev` or the keyframe), sampled from its depth once (:func:`sample_points`)."""
        if source.align_points is None:
            source.align_points = sample_points(source.depth, self.intrinsics, source.R_lev_cam, self._align_opt)
        return source.align_points

    def _dense_translation(self, yaw: float, t_xz: np.ndarray, cov_t: np.ndarray, info, wide: bool = False) -> list:
        """``[(u (2,), delta, var)]`` (as :func:`wall_constraints`): the translation along the
        direction ``u`` the walls left to the guess (the larger axis of ``cov_t``), measured
        by aligning the previous frame's depth with this one's at the frame-to-frame ``yaw``
        (frontend/depthalign.py), or ``[]``. ``t_xz`` (2,), ``cov_t`` (2, 2): the step's
        levelled translation so far. ``wide``: also try the wider window where the narrow
        one finds no bowl -- only for a step neither walls nor corners turned, which would
        otherwise be bridged: the wider window has more room for a shallow, biased minimum
        (on two low-texture 30 Hz tuning halls, used for every partial step, it measured 94
        steps 1 mm short each and their smoothed drift went 0.50 -> 1.54 and 1.25 -> 1.83 %)."""
        c = self.config.odometry
        if not c.depth_align or self._prev is None or self._prev.depth is None or self._depth is None:
            return []
        u, a, n_points = self._along_long_axis(self._prev, yaw, t_xz, cov_t, wide)
        if a is None:
            info.partial_dense = {"points": n_points}  # tried: no clear minimum
            return []
        info.partial_dense = {"s_m": a.s, "sigma_m": math.sqrt(a.var), "points": a.n_points}
        return [(u, float(u @ t_xz) + a.s, a.var)]

    def _depth_yaw(self, yaw: float, t: np.ndarray, sb: float, mount_se2, info):
        """``(yaw, sigma, yaw)`` (rad) of a step no wall and no corner turned, measured by
        aligning the previous frame's depth with this one's about the yaw
        (:func:`~planar_vo.frontend.depthalign.align_yaw`), or None.

        The guess's yaw and distance along may both be off by more than either 1-D search
        can take (a robot starting from rest is guessed at zero), so a coarse grid over
        both comes first (:func:`~planar_vo.frontend.depthalign.coarse_yaw_along`):
        +-``depth_yaw_range_deg`` about the guess ``yaw``, and the depth alignment's range
        along the guess's long axis (of sigma ``sb``). On a wheeled base the translation follows each candidate yaw along the
        chord (:meth:`_wheeled_prior`): a camera ahead of base_link moves sideways with the
        turn, and a sideways error ``e`` at range ``r`` reads as a yaw error ``e / r``."""
        c = self.config.odometry
        if not (c.depth_align and c.depth_yaw) or self._prev is None or self._prev.depth is None or self._depth is None:
            return None
        opt = self._align_opt
        P1, normals = self._align_points(self._prev)
        half = math.radians(c.depth_yaw_range_deg)
        t_xz = np.array([t[0], t[2]], dtype=float)
        if c.lateral_slip > 0:
            cov = self._wheeled_prior(yaw, t_xz, sb, mount_se2)[1]

            def chord(yaws: np.ndarray) -> np.ndarray:
                return np.array([self._wheeled_prior(float(y), t_xz, sb, mount_se2)[0] for y in yaws])
        else:
            cov = np.eye(2) * sb * sb

            def chord(yaws: np.ndarray) -> np.ndarray:
                return np.tile(t_xz, (len(yaws), 1))
        lam, vec = np.linalg.eigh(cov)
        u = vec[:, -1]
        half_s = min(max(4.0 * math.sqrt(max(float(lam[-1]), 0.0)), c.depth_align_min_range_m),
                     c.depth_align_max_range_m)
        keep = informative_yaw(P1, normals, opt) | informative(normals, u, opt)
        depth, R = self._depth
        start = coarse_yaw_along(P1[keep], depth, self.intrinsics, R, yaw, chord, u, half, half_s, opt)
        if start is None:
            info.depth_yaw = {"points": int(keep.sum())}
            return None
        yaw0, s0 = yaw + start[0], start[1]

        def t_of(yaws: np.ndarray) -> np.ndarray:
            return chord(yaws) + s0 * u
        step = 2.0 * half / 12
        P_yaw = P1[informative_yaw(P1, normals, opt)]
        a = align_yaw(P_yaw, depth, self.intrinsics, R, yaw0, t_of, 2.0 * step, opt)
        if a is None:
            info.depth_yaw = {"points": len(P_yaw)}  # tried: no clear minimum
            return None
        info.depth_yaw = {"yaw_deg": math.degrees(yaw0 + a.s), "sigma_deg": math.degrees(math.sqrt(a.var)),
                          "points": a.n_points}
        return yaw0 + a.s, math.sqrt(a.var), yaw0 + a.s

    def _bridge_sigmas(self, nothing_known: bool) -> tuple[float, float]:
        """Sigmas (m, rad) of a constant-velocity guess for the step's translation and yaw.

        The guess errs by the velocity change since the last measurement: with
        accelerations up to ``bridge_accel_xy`` / ``bridge_accel_theta_deg`` over ``k`` frame
        intervals ``dt``, by ``a k dt^2`` per step -- a few millimetres and tenths of a
        degree at first, growing while nothing is measured (the translation's growth at most
        ``bridge_max_speed`` times the frame interval), capped at ``bridge_sigma_xy``
        / ``bridge_sigma_theta_deg`` (also used when no motion was ever measured). The
        translation's rate of change is measured (:meth:`_velocity_change`) when it is
        smaller, and it also errs by the copied steps' own error (their sigma).

        One sigma for both axes: per axis, with the measured steps' noise taken out of the
        rate (normalised bridged errors 0.56 / 0.63 / 0.82 instead of 0.41 / 0.07 / 0.25 on
        tuning halls), the partial steps of a low-texture tuning ring trusted their guess
        over walls and points and its raw odometry went 2.5 -> 5.3 % off.
        """
        c = self.config.odometry
        cap_xy, cap_th = c.bridge_sigma_xy, math.radians(c.bridge_sigma_theta_deg)
        if nothing_known:
            return cap_xy, cap_th
        dt2 = self._dt * self._dt
        # the velocity cannot drift beyond the platform's top speed (at 30 Hz the growth
        # alone reached 11 cm a step after 200 frames, and a wall paired with another plane
        # 27 cm off passed the gate as a measurement of a 13 mm step)
        cap = c.bridge_accel_xy * dt2
        drift = self._velocity_change(cap) * self._since_t
        if c.bridge_trend_lag:
            drift = max(drift, self._window_trend_drift(cap))
        drift = min(drift, c.bridge_max_speed * self._dt)
        s_xy = min(max(math.hypot(drift, self._last_t_sigma), c.min_sigma_xy), cap_xy)
        s_th = min(max(math.radians(c.bridge_accel_theta_deg) * dt2 * (self._since_yaw + 1),
                       math.radians(c.min_sigma_theta_deg)), cap_th)
        return s_xy, s_th

    def _window_trend_drift(self, cap: float) -> float:
        """Metres by which the guess (the weighted mean of the window's measured steps,
        :func:`window_velocity`) may miss this frame's step when the steps speed up or slow
        down: the slope of the window's steps (a weighted line per axis, metres per frame,
        at most ``cap``) times the frames from the window's weighted mean frame to this one.
        The mean describes the velocity at the window's middle, two frames before its last
        step for a window of five, not at its last step: counted from the last step only,
        a base speeding up from rest at 0.64 m/s^2 had its first partial steps guessed
        10-18 mm short at a stated 2.7-4.7 mm (seen hall_s10606), and the few 3-D matches that
        measured them right were pulled to the guess (partial steps in the first and last
        1.2 s of the seen and tuning sets: errors over sigma of mean -0.83 and +0.53, RMS 1.54
        and 0.99, against 0.55 in the cruise). 0 with fewer than three steps in the window."""
        w = self.config.odometry.velocity_window
        last = self._history[-1][0] if self._history else None
        win = [e for e in self._history if last - e[0] < w]
        if len(win) < 3:
            return 0.0
        k = np.array([float(e[0]) for e in win])
        v = np.array([e[1] for e in win])[:, [0, 2]]
        wt = 1.0 / np.array([e[2] for e in win])
        k_mean = float((wt * k).sum() / wt.sum())  # the frame whose velocity the guess is
        kc = k - k_mean
        sxx = float((wt * kc * kc).sum())
        if not sxx > 0:
            return 0.0
        slope = (wt[:, None] * kc[:, None] * v).sum(0) / sxx
        return min(float(np.linalg.norm(slope)), cap) * (self._n - k_mean)

    def _velocity_change(self, cap: float) -> float:
        """Metres per frame by which the translation per frame changes: the RMS of the
        differences of the last measured steps (their own errors included), at most ``cap``
        (``bridge_accel_xy dt^2``, the platform's largest acceleration). A robot cruising
        steadily changes its step by its measurement noise, a millimetre or two at 10 Hz,
        not the 5 mm the largest acceleration allows."""
        if len(self._history) < 3:
            return cap
        d = np.diff(np.array([e[1] for e in self._history])[:, [0, 2]], axis=0)
        return min(float(np.sqrt((d * d).sum(1).mean())), cap)

    def _remember_translation(self, t: np.ndarray, var: float) -> list[tuple[np.ndarray, float]]:
        """Keep the measured levelled ``t`` (3,) of this frame with its ``var`` (m^2); returns
        the ``(t, var)`` the constant-velocity guess of the next partial or bridged steps
        averages (:func:`window_velocity`): those measured in the last ``velocity_window``
        frames. A single step's error (1-3 mm on low texture) is copied into every guessed
        step that follows: 68 partial steps in a row on a tuning log (straight_s118) turned
        one step's error into 3 % of their path. Measurements
        older than the window describe an older velocity: where partial steps alternated with
        measured ones the last five measured spanned 10-15 frames, and a robot braking to
        a stop in 1 s was guessed 6-18 mm a step too fast (a low-texture tuning log's last
        14 steps, 9 cm)."""
        w = self.config.odometry.velocity_window
        self._history = (self._history + [(self._n, np.asarray(t, dtype=float).copy(), float(var))])[-w:]
        return [(e[1], e[2]) for e in self._history if self._n - e[0] < w]

    def _yaw_floor(self, status: str, depth: float) -> np.ndarray:
        """(3, 3) levelled covariance over ``(yaw, t_x, t_z)`` of the yaw error no residual
        shows (levelling, calibration, errors the matches share): a floor on the yaw's sigma
        (``two_point_min_sigma_theta_deg`` / ``min_sigma_theta_deg``) along ``(1, -Z, 0)``,
        ``Z`` the matches' typical ``depth``. A translation measured at a wrong yaw moves
        sideways by ``-Z`` times the yaw error (``X2 = R X1 + t``): on the tuning seeds the
        sideways and yaw errors of 2-point and direction-plus-point steps correlate by -0.78
        and -0.82 (slope -2.9 and -1.8 m). Stated uncorrelated, a graph that corrects the
        yaw by the Manhattan frame keeps the sideways error (mechanism 1 of issue 9)."""
        c = self.config.odometry
        f = math.radians(c.two_point_min_sigma_theta_deg if status == STATUS_2PT else c.min_sigma_theta_deg)
        v = np.array([1.0, -depth if math.isfinite(depth) else 0.0, 0.0])
        return f * f * np.outer(v, v)

    def _velocity_jump(self, t: np.ndarray, cov: np.ndarray, info) -> bool:
        """True when a 2-point translation ``t`` (3,), levelled, with ``cov`` (3, 3) over
        (yaw, t_x, t_z), departs from the constant-velocity guess by more than
        ``velocity_gate_sigmas`` of both sigmas (the guess's is the platform's acceleration
        limit, :meth:`_bridge_sigmas`). Matches that agree on a wrong motion do that: floor
        tiles' grout grid aliased under KLT gave a tuning loop 2-point steps 36-51 mm off a
        35.6 mm step (backwards), 2 deg off in yaw. Only while a measured translation is
        recent (``velocity_window`` frames) and three measured steps give the guess's spread."""
        c = self.config.odometry
        m2 = self._velocity_m2(t, cov)
        if m2 is None or m2 <= c.velocity_gate_sigmas ** 2:
            return False
        d = np.array([t[0] - self._last_motion[1][0], t[2] - self._last_motion[1][2]])
        info.rejected.append({"status": STATUS_2PT, "velocity_jump_m": float(np.linalg.norm(d)),
                              "sigmas": math.sqrt(m2)})
        return True

    def _velocity_m2(self, t: np.ndarray, cov: np.ndarray) -> float | None:
        """Squared Mahalanobis distance of a levelled translation ``t`` (3,) with ``cov``
        (3, 3) from the constant-velocity guess (:meth:`_velocity_jump`), or None while the
        guess is not fit to judge (gate off, no recent measured translation)."""
        c = self.config.odometry
        w = c.velocity_window
        if c.velocity_gate_sigmas <= 0 or self._last_motion is None \
                or not any(self._n - e[0] < w for e in self._history):
            return None
        self._since_t += 1  # the guess is for this frame
        sb = self._bridge_sigmas(False)[0]
        # A gate is for motions the platform cannot make: however steady the cruise (its
        # steps changing by their 1-2 mm noise), the robot may brake at its acceleration
        # limit on the next frame. Gated at the cruise's noise, the 2-point steps of a
        # held-out L's 1 s stop ramp (5.5 mm a frame slower each) were refused at 7 sigmas
        # and their partial steps took a depth yaw 0.6 deg off.
        sb = max(sb, c.bridge_accel_xy * self._dt * self._dt * self._since_t)
        self._since_t -= 1
        # ... but a guess is only as steady as the steps it copies: when they disagree among
        # themselves (a direction-plus-point blunder 31-44 mm sideways just before on a tuning
        # hall), their spread is the guess's error, and the right 2-point steps after it must
        # not be refused (bridged, they copied the blunder: raw drift 1.4 -> 3.8 %)
        sb = max(sb, self._velocity_change(math.inf))
        if not math.isfinite(sb):
            return None
        d = np.array([t[0] - self._last_motion[1][0], t[2] - self._last_motion[1][2]])
        return float(d @ np.linalg.solve(cov[1:, 1:] + sb * sb * np.eye(2), d))

    def _accept(self, yaw, t, cov, status, n_in, mount_se2, info, link=None, cov_t=None, depth=math.nan):
        """The step of an estimate, or None when its own covariance says it is not determined.

        ``link``: ``(lag, motion, cov, guess_cov)`` when the step is the difference of two
        motions from a keyframe ``lag`` frames back: ``motion`` (levelled ``(yaw, t)``, with
        ``cov``) the one into this frame, ``guess_cov`` what guessed steps since the last
        measurement added; ``cov_t``: then the step's own covariance (:func:`_step_covariance`).
        ``cov``, the frame-to-frame estimate's, decides whether the step is determined.
        ``depth`` (m): the matches' typical depth (:func:`_typical_depth`), for the floors.
        """
        c = self.config.odometry
        pose, cov_b = lev_motion_to_base_step(yaw, t, cov, mount_se2)
        sd = np.sqrt(np.maximum(np.diag(cov_b), 0.0))
        if not (np.isfinite(cov_b).all() and sd[0] <= c.max_sigma_xy and sd[1] <= c.max_sigma_xy
                and sd[2] <= math.radians(c.max_sigma_theta_deg)):
            info.rejected.append({"status": status, "sigma_xy_theta": sd.tolist()})
            return None
        keyframe = None
        floor_lev = self._yaw_floor(status, depth)
        pose, cov_b = lev_motion_to_base_step(yaw, t, (cov if link is None else cov_t) + floor_lev, mount_se2)
        # Floors for what the inlier residuals cannot see: levelling and calibration errors
        # turn the step and push it sideways. Along the motion the depth noise models hold
        # (direction-plus-point forward errors 0.86 of their sigma without a floor, 0.64
        # with one, on the tuning seeds).
        if status == STATUS_2PT:
            # A 2-point translation's direction comes from the images, its length from the
            # depths: a thin valley along the motion. Across it a stated sigma of 0.4-0.7 mm
            # came with errors near 1.2 mm (tuning seeds): errors the matches share, which
            # grow with their depth. Floored sideways only, an oblique valley kept its
            # width, and a motion prior slid the step along it (a tuning hall's 12 mm
            # steps to 1 mm). So the floor is in both directions.
            shared = c.two_point_shared_px * depth / self.intrinsics.fx if math.isfinite(depth) else 0.0
            floors = np.diag([c.two_point_min_sigma_xy ** 2 + shared ** 2] * 2 + [0.0])
        else:
            floors = np.diag([0.0, c.min_sigma_xy ** 2, 0.0])
        cov_b = 0.5 * (cov_b + cov_b.T) + floors
        if link is not None:
            pose_k, cov_k = lev_motion_to_base_step(link[1][0], link[1][1], link[2] + floor_lev, mount_se2)
            keyframe = KeyframeLink(int(link[0]), pose_k, np.linalg.inv(0.5 * (cov_k + cov_k.T) + floors))
        if link is None:
            var = float(np.max(np.diag(cov[1:, 1:]))) + c.min_sigma_xy ** 2
            t_guess, self._last_t_sigma = window_velocity(self._remember_translation(t, var))
            self._last_motion = (float(yaw), t_guess)
        else:
            # the velocity over the window is the difference of two motions from the keyframe
            # divided by the frames between them: no further averaging (it would lag)
            v, n = self._keyframes.velocity(link[1], c.velocity_window)
            self._last_t_sigma = math.sqrt(2.0 * float(np.max(np.diag(link[2][1:, 1:]))) + c.min_sigma_xy ** 2) / n
            self._remember_translation(v, self._last_t_sigma ** 2)
            self._last_motion = (float(yaw), v)
        self._since_t = self._since_yaw = 0
        yaw_var = float(cov[0, 0]) + math.radians(c.min_sigma_theta_deg) ** 2
        return (Step(pose, np.linalg.inv(cov_b), status, int(n_in), keyframe),
                (float(yaw), np.asarray(t, float), yaw_var))
