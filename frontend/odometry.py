"""Frame-to-frame planar visual odometry (the paper's front-end, Sec. 2 and 3.2).

Per frame: level the camera (given mount or floor estimate), detect the floor and walls
from inverse-depth histograms, group walls into local Manhattan frames and track them,
associate corners with the previous frame and lift them to levelled 3-D. The step from
the previous frame is then estimated by

1. direction-plus-point (Sec. 2.1): the yaw from a local Manhattan frame seen in both
   frames (eq. 1), the translation by 1-point RANSAC on 3-D matches (eq. 2). The frame
   must be tracked for a few frames and cover enough image area in both views (walls
   entering the view give biased headings). When the 2-point estimate below is also
   available, the two yaws are checked against each other (a disagreement beyond
   3 sigma means a wrong Manhattan association: the 2-point step is used) and fused by
   their variances, and the 1-point translation is taken at the fused yaw; else
2. the 2-point planar homography (Sec. 2.2) with metric scale from depth (enough matches
   with depth must agree on the scale); else
3. a bridge, flagged ``STATUS_BRIDGED``: constant velocity (or zero motion) with a large
   covariance -- never silently. A shared large Manhattan frame still gives the yaw.

Steps are reported as base_link SE(2) increments with an information matrix in
gtsam.Pose2 tangent order ``[x, y, theta]``, propagated from the estimator's covariance
over ``(yaw, t_x, t_z)`` through the levelled-to-base conversion.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

from planar_vo import geometry
from planar_vo.errors import InputError
from planar_vo.frontend.config import FrontendConfig
from planar_vo.frontend.estimators import (DirPointOptions, MetricTwoPointOptions,
                                           estimate_planar_motion_2pt_metric, estimate_planar_motion_dpp)
from planar_vo.frontend.features import FeatureSet, FeatureTracker
from planar_vo.frontend.levelling import Levelling, LevellingState
from planar_vo.frontend.manhattan import LocalFrame, ManhattanTracker, group_walls
from planar_vo.frontend.planarity import out_of_plane_motion
from planar_vo.frontend.planes import PlaneDetection, PlaneDetector
from planar_vo.frontend.solvers import yaw_from_manhattan_headings
from planar_vo.frontend.types import (STATUS_2PT, STATUS_BRIDGED, STATUS_DPP, FrameResult,
                                      ManhattanObservation, Step)
from planar_vo.io.types import CameraIntrinsics, Mount, RGBDFrame


@dataclass
class _Prev:
    """What the next frame needs from this one (each frame is processed once)."""

    features: FeatureSet
    x_lev: np.ndarray      # (N, 2) levelled normalised coordinates
    P_lev: np.ndarray      # (N, 3) levelled points, NaN without depth
    frames: list[LocalFrame]


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
    The covariance is pushed through the (smooth) map by its Jacobian, taken by central
    differences (the map is a few trigonometric terms, so this is exact to ~1e-10).
    """
    def f(p):
        return geometry.lev_step_to_base_step(
            geometry.levelled_motion_to_pose(p[0], np.array([p[1], 0.0, p[2]])), m_base_lev)

    p0 = np.array([yaw, t[0], t[2]], dtype=float)
    step = f(p0)
    if cov is None:
        return step, None
    J = np.empty((3, 3))
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        a, b = f(p0 + d), f(p0 - d)
        diff = a - b
        diff[2] = float(geometry.wrap_angle(diff[2]))
        J[:, k] = diff / (2 * h)
    return step, J @ cov @ J.T


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
        self._planes = PlaneDetector(intrinsics, c.planes, self._levelling.state.R_lev_cam)
        self._features = FeatureTracker(intrinsics, c.features)
        self._manhattan = ManhattanTracker(c.manhattan)
        o = c.odometry
        self._dpp_opt = DirPointOptions(focal_px=intrinsics.fx, max_iterations=o.ransac_iterations, seed=o.seed)
        self._2pt_opt = MetricTwoPointOptions(focal_px=intrinsics.fx, max_error_px=o.ransac_threshold_px,
                                              seed=o.seed)
        self._prev: _Prev | None = None
        self._last_motion: tuple[float, np.ndarray] | None = None  # levelled (yaw, t) of the last estimate
        self._dpp_track = -1  # Manhattan track of the last direction-plus-point step
        self._n = 0
        self.last_detection: PlaneDetection | None = None
        # frame index -> (features, matches, new corners, seconds) of track() calls made ahead
        self._tracked: dict[int, tuple] = {}

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
        info: dict = {}

        t0 = clock()
        det = self._detect_planes(depth, info)
        R = self._levelling.state.R_lev_cam
        t1 = clock()
        timings["planes"] = t1 - t0

        frames = group_walls(det.walls, self.config.manhattan)
        yaw_prior = self._last_motion[0] if self._last_motion is not None else 0.0
        self._manhattan.associate(frames, yaw_prior)
        t2 = clock()
        timings["manhattan"] = t2 - t1

        tracked = self._tracked.pop(frame.index, None)
        if tracked is None:
            if self._tracked:
                raise RuntimeError(f"frame {frame.index}: track() ran ahead for frames "
                                   f"{sorted(self._tracked)} but not for this one; call it for every frame, in order")
            tracked = self._track(color, depth)
        fs, matches, new_corners, t_track = tracked
        t_lev = clock()
        x_lev, P_lev = levelled_features(fs, R)
        t3 = clock()
        timings["features"] = t_track + (t3 - t_lev)
        info.update(features=len(fs), new_corners=new_corners, matches=len(matches))

        step = None
        lev_motion = (0.0, np.zeros(3))
        if self._prev is not None:
            step, lev_motion = self._estimate(self._prev, x_lev, P_lev, matches, frames, yaw_prior, info)
        t4 = clock()
        timings["estimate"] = t4 - t3

        self._manhattan.commit(frames, lev_motion[0])
        self._prev = _Prev(fs, x_lev, P_lev, frames)
        mount_yaw = geometry.mount_se2(self.mount.T_base_cam)[2]
        observations = [ManhattanObservation(float(geometry.wrap_quarter(f.heading + mount_yaw)), f.sigma,
                                             f.score, f.track_id)
                        for f in frames if f.score >= self.config.manhattan.min_score]
        timings["total"] = clock() - t_start
        self._n += 1
        return FrameResult(frame.index, frame.stamp, step, observations, timings, info)

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

    def _detect_planes(self, depth: np.ndarray, info: dict) -> PlaneDetection:
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
        info["floor_seen"] = floor is not None
        info["planes"] = len(det.horizontals) + len(det.walls)
        info["walls"] = len(det.walls)
        info["wall_fraction"] = det.wall_fraction
        info["floor_fraction"] = floor.support if floor is not None else 0.0
        info["levelling"] = dict(s.as_dict(), floor_seen=floor is not None, floor_normal_cam=floor_cam,
                                 camera_height_m=floor.offset if floor is not None else None)
        self.last_detection = det  # for diagnostics and tests; not part of FrameResult
        return det

    def _estimate(self, prev: _Prev, x_lev, P_lev, matches, frames, yaw_prior, info):
        c = self.config.odometry
        i0, i1 = matches[:, 0], matches[:, 1]
        x1, x2 = prev.x_lev[i0], x_lev[i1]
        P1, P2 = prev.P_lev[i0], P_lev[i1]
        ok = np.isfinite(x1).all(1) & np.isfinite(x2).all(1)
        x1, x2, P1, P2 = x1[ok], x2[ok], P1[ok], P2[ok]
        depth_ok = np.isfinite(P1[:, 2]) & np.isfinite(P2[:, 2])
        info["matches_with_depth"] = int(depth_ok.sum())
        # The floor, when seen, judges planarity far better (planar_vo.pipeline): the 6-DoF
        # check is only needed on frames without one.
        if c.planarity_check and depth_ok.sum() >= 8 and not info.get("floor_seen"):
            oop = out_of_plane_motion(P1[depth_ok], P2[depth_ok], seed=c.seed)
            if oop is not None:
                info["out_of_plane"] = {"tilt_deg": oop.tilt_deg, "dy_m": oop.dy_m, "inliers": oop.inliers,
                                        "R": oop.R.tolist(), "t": oop.t.tolist()}
        max_yaw = math.radians(c.max_step_yaw_deg)
        mount_se2 = geometry.mount_se2(self.mount.T_base_cam)

        # 1. Direction-plus-point with a local frame seen in both views: the dominant
        # usable one, unless its 1-point inlier ratio is poor -- then the best of them.
        prev_sigma = {f.track_id: f.sigma for f in prev.frames}
        prev_score = {f.track_id: f.score for f in prev.frames}
        n_depth = max(int(depth_ok.sum()), 1)
        best = None
        mf_yaw = None  # (yaw, sigma) of the dominant usable local frame, kept for bridging
        # The yaw telescopes (drift-free) only along one track: stay with the last one used.
        ordered = sorted(frames, key=lambda f: (f.track_id != self._dpp_track, -f.score))
        for f in ordered:
            if (f.prev_heading is None or f.track_id not in prev_sigma or f.age < c.dpp_min_track_age
                    or min(f.score, prev_score[f.track_id]) < c.dpp_min_score):
                continue
            yaw_sigma = math.hypot(f.sigma, prev_sigma[f.track_id])
            if yaw_sigma > math.radians(c.dpp_max_yaw_sigma_deg):
                continue
            yaw = yaw_from_manhattan_headings(f.prev_heading, f.heading, yaw_prior)
            if mf_yaw is None and f.score >= c.bridge_min_score:
                mf_yaw = (yaw, yaw_sigma)
            motion, est = estimate_planar_motion_dpp(P1, P2, yaw, self._dpp_opt, yaw_sigma=yaw_sigma)
            info.setdefault("dpp", []).append({"status": est.status, "inliers": est.num_inliers,
                                               "track_id": f.track_id, "yaw_sigma": yaw_sigma})
            if motion is None or est.num_inliers < c.min_inliers:
                continue
            if best is None or est.num_inliers > best[1].num_inliers:
                best = (motion, est, f.track_id)
            if est.num_inliers >= 0.8 * n_depth:
                break
        dpp = best if best is not None and best[1].num_inliers >= c.dpp_min_inlier_ratio * n_depth else None

        # 2. 2-point homography with metric scale from depth: the step when no Manhattan
        # frame is shared, and a cross-check of the Manhattan yaw when one is.
        two = None
        if len(x1) >= 2:
            motion, est = estimate_planar_motion_2pt_metric(x1, x2, P1, P2, self._2pt_opt)
            n_in = est.num_inliers
            n_scale = int(est.scale_inliers.sum()) if est.scale_inliers is not None else 0
            info["2pt"] = {"status": est.status, "inliers": n_in, "scale_inliers": n_scale,
                           "iterations": est.iterations}
            # A scale from a handful of depths cannot be checked against outliers.
            if (motion is not None and n_in >= c.min_inliers and n_in >= c.min_inlier_ratio * len(x1)
                    and n_scale >= c.min_scale_inliers and abs(motion.yaw) <= max_yaw
                    and est.covariance is not None and est.covariance[0, 0] > 0):
                two = (motion, est)

        if dpp is not None:
            motion, est, tid = dpp
            yaw, var = motion.yaw, est.covariance[0, 0]
            if two is not None and c.fuse_yaw:
                # Both yaws measure the same rotation: a wrong Manhattan association shows as
                # a disagreement (then the 2-point step stands); else fuse them by their
                # variances and take the 1-point translation at the fused yaw.
                yaw2, var2 = two[0].yaw, two[1].covariance[0, 0]
                d = float(geometry.wrap_angle(yaw - yaw2))
                info["yaw_check"] = {"dpp_minus_2pt_deg": math.degrees(d),
                                     "sigma_deg": math.degrees(math.sqrt(var + var2))}
                if d * d > 9.0 * (var + var2):
                    dpp = None
                else:
                    yaw_f = yaw - d * var / (var + var2)
                    motion, est = estimate_planar_motion_dpp(P1, P2, yaw_f, self._dpp_opt,
                                                             yaw_sigma=math.sqrt(var * var2 / (var + var2)))
                    if motion is None:
                        dpp = None
            if dpp is not None:
                step = self._accept(motion.yaw, motion.t, est.covariance, STATUS_DPP, est.num_inliers,
                                    mount_se2, info)
                if step is not None:
                    self._dpp_track = tid
                    return step
        if two is not None:
            motion, est = two
            step = self._accept(motion.yaw, motion.t, est.covariance, STATUS_2PT, est.num_inliers, mount_se2, info)
            if step is not None:
                return step

        # 3. Bridge, flagged: constant velocity (or zero) translation with a large
        # covariance; the yaw from a shared Manhattan frame when there is one (it does not
        # need features), else from the same prior as the translation.
        if c.bridge == "constant_velocity" and self._last_motion is not None:
            yaw, t = self._last_motion
            how = "constant_velocity"
        else:
            yaw, t = 0.0, np.zeros(3)
            how = "zero"
        sigma_theta = math.radians(c.bridge_sigma_theta_deg)
        if mf_yaw is not None:
            yaw, sigma_theta = mf_yaw[0], max(mf_yaw[1], math.radians(c.min_sigma_theta_deg))
            how += "+manhattan_yaw"
        pose, _ = lev_motion_to_base_step(yaw, t, None, mount_se2)
        cov = np.diag([c.bridge_sigma_xy ** 2, c.bridge_sigma_xy ** 2, sigma_theta ** 2])
        info["bridge"] = how
        return Step(pose, np.linalg.inv(cov), STATUS_BRIDGED, 0), (yaw, t)

    def _accept(self, yaw, t, cov, status, n_in, mount_se2, info):
        """The step of an estimate, or None when its own covariance says it is not determined."""
        c = self.config.odometry
        pose, cov_b = lev_motion_to_base_step(yaw, t, cov, mount_se2)
        sd = np.sqrt(np.maximum(np.diag(cov_b), 0.0))
        if not (np.isfinite(cov_b).all() and sd[0] <= c.max_sigma_xy and sd[1] <= c.max_sigma_xy
                and sd[2] <= math.radians(c.max_sigma_theta_deg)):
            info.setdefault("rejected", []).append({"status": status, "sigma_xy_theta": sd.tolist()})
            return None
        # Floors for what the inlier residuals cannot see (levelling, calibration).
        cov_b = 0.5 * (cov_b + cov_b.T) + np.diag([c.min_sigma_xy ** 2, c.min_sigma_xy ** 2,
                                                   math.radians(c.min_sigma_theta_deg) ** 2])
        self._last_motion = (float(yaw), np.asarray(t, dtype=float).copy())
        return Step(pose, np.linalg.inv(cov_b), status, int(n_in)), (float(yaw), np.asarray(t, float))
