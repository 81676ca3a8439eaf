"""Planar pose graph: one ``gtsam.Pose2`` per frame, SE(2) step factors, Manhattan-frame
rotation factors, wall-offset factors on wall landmarks, extra relative factors; solved in batch (Levenberg-Marquardt) or
incrementally (iSAM2).

Poses are SE(2) ``T_odom_base`` ``(x, y, theta)``; ``odom`` coincides with ``base`` at the
first frame. Both graph classes build their factors through one :class:`_GraphBuilder`,
so data association and factor construction live in exactly one place and the two
solvers see identical graphs.
"""
from __future__ import annotations

import bisect
import math
import time
from collections import Counter
import dataclasses
from dataclasses import dataclass, field
from typing import NamedTuple

import gtsam
import numpy as np

from planar_vo.backend.association import ManhattanAssociator, ManhattanLink
from planar_vo.backend.config import BackendConfig
from planar_vo.backend.factors import (M, W, X, constant_velocity_factor, manhattan_anchor, manhattan_factor,
                                       heading_between_factor, manhattan_tie, manhattan_value, robust_noise,
                                       robust_weight, step_noise, wall_factor)
from planar_vo.backend.walls import WallMap
from planar_vo.core.steps import STATUS_BRIDGED, STATUS_PARTIAL, FrameResult
from planar_vo.core.geometry import se2_compose, wrap_angle, wrap_quarter
from planar_vo.backend.wheel import fuse_steps

__all__ = ["PlanarPoseGraph", "IncrementalPlanarPoseGraph"]


def _check_pose(pose, what: str) -> np.ndarray:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{what} must be a finite (3,) SE(2) pose (x, y, theta), got shape {p.shape}")
    return p


def _check_information(information, what: str, psd: bool = False) -> np.ndarray:
    """``information`` as a symmetric (3, 3) float64 array; positive definite (or only
    semi-definite with ``psd``), else ValueError naming ``what``."""
    a = np.asarray(information, dtype=np.float64)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be a finite (3, 3) information matrix, got shape {a.shape}")
    a = 0.5 * (a + a.T)
    if psd:
        if np.linalg.eigvalsh(a)[0] < -1e-9 * max(1.0, float(np.abs(a).max())):
            raise ValueError(f"{what} must be positive semi-definite, got eigenvalues {np.linalg.eigvalsh(a)}")
        return a
    if np.linalg.eigvalsh(a)[0] <= 0.0:
        raise ValueError(f"{what} must be positive definite, got eigenvalues {np.linalg.eigvalsh(a)}")
    return a


#: keys of a closure's dict that its ``info`` may not override
_CLOSURE_KEYS = ("id", "i", "j", "pose", "sigma", "status", "residual_sigmas", "reason")


@dataclass(eq=False)
class _Closure:
    """One loop closure: ``T_base_i_base_j = pose`` (3,) with (3, 3) ``information``.

    ``index``: its factor's slot in the batch graph, or the index iSAM2 gave its factor
    (``ISAM2Result.getNewFactorsIndices``; None while it is not in iSAM2); ``robust``:
    whether that factor carries the closure kernel (else Gaussian).
    """

    id: int
    i: int
    j: int
    pose: np.ndarray
    information: np.ndarray
    info: dict = field(default_factory=dict)
    status: str = "active"
    residual: float | None = None
    reason: str | None = None
    index: int | None = None
    robust: bool = False


def _joint_block(jm, i: int, j: int) -> np.ndarray:
    """(6, 6) covariance of ``[X(i), X(j)]`` from a ``gtsam.JointMarginal``."""
    return np.block([[jm.at(X(i), X(i)), jm.at(X(i), X(j))], [jm.at(X(j), X(i)), jm.at(X(j), X(j))]])


def _relative_covariances(joint_of, pose_of, i: int, js) -> np.ndarray:
    """(len(js), 3, 3) covariances of ``T_base_i_base_j`` for each ``j`` in ``js`` from one
    joint marginal: ``joint_of(keys)`` gives a ``gtsam.JointMarginal`` over ``keys`` and
    ``pose_of(key)`` the ``gtsam.Pose2`` estimate."""
    js = [int(j) for j in js]
    if not js:
        return np.zeros((0, 3, 3))
    jm = joint_of([X(i)] + [X(j) for j in dict.fromkeys(js)])   # each key once
    pose_i = pose_of(X(i))
    return np.stack([_relative_covariance(_joint_block(jm, i, j), pose_i, pose_of(X(j))) for j in js])


def _relative_covariance(joint: np.ndarray, pose_i, pose_j) -> np.ndarray:
    """(3, 3) covariance of ``T_i^-1 T_j`` from the (6, 6) joint covariance of the two
    poses (``gtsam.Pose2`` each, right-perturbed tangent ``[x, y, theta]``, i first).

    With ``T_i Exp(a)`` and ``T_j Exp(b)``: ``T_ij' = Exp(-a) T_ij Exp(b)
    = T_ij Exp(b - Ad(T_ij^-1) a)`` to first order, so ``J = [-Ad(T_ij^-1), I]``.
    """
    t_ij = pose_i.between(pose_j)
    jac = np.hstack([-t_ij.inverse().AdjointMap(), np.eye(3)])
    cov = jac @ joint @ jac.T
    return 0.5 * (cov + cov.T)


def _lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
        cfg: BackendConfig) -> tuple[gtsam.Values, int, float]:
    """Levenberg-Marquardt with the configured limits: ``(solution, iterations, error)``."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.lm_max_iterations)
    params.setRelativeErrorTol(cfg.lm_relative_error_tol)
    params.setAbsoluteErrorTol(cfg.lm_absolute_error_tol)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    return result, int(opt.iterations()), float(opt.error())


def _gaussian_copy(graph: gtsam.NonlinearFactorGraph, skip: set[int], gaussian: bool = True) -> gtsam.NonlinearFactorGraph:
    """The factors of ``graph`` but those at ``skip`` (and removed ones), every robust
    ``BetweenFactorPose2`` (steps, native Manhattan links) replaced by its Gaussian core
    (a ``custom`` Manhattan link, a Python ``CustomFactor``, keeps its kernel); with
    ``gaussian`` False the factors as they are. The copy shares the factors."""
    out = gtsam.NonlinearFactorGraph()
    for idx in range(graph.size()):
        f = graph.at(idx)
        if f is None or idx in skip:
            continue
        if gaussian and isinstance(f, gtsam.BetweenFactorPose2) and isinstance(f.noiseModel(), gtsam.noiseModel.Robust):
            keys = f.keys()
            f = gtsam.BetweenFactorPose2(keys[0], keys[1], f.measured(), f.noiseModel().noise())
        out.add(f)
    return out


def _select_closures(builder: "_GraphBuilder", graph: gtsam.NonlinearFactorGraph, start: gtsam.Values,
                     skip: set[int]) -> tuple[gtsam.Values, int]:
    """Decide which active closures stay: solve ``graph`` (without the factors at ``skip``,
    the closures already in it) plus every active closure, all Gaussian, from ``start``;
    remove the closure with the largest Mahalanobis residual beyond
    ``closure_max_error_sigmas``; repeat until none. Returns ``(solution, iterations)``.

    All Gaussian because a robust step or Manhattan link can give way: a false closure
    pulling metres against a chain of robust steps pushes a few of them into the kernel's
    tail, the chain tears there and the false closure fits with a small residual. A Gaussian
    graph cannot tear, so the false closure's residual stays large (it is one factor against
    many) and it is removed first; a true closure bent by it recovers once it is gone.
    """
    gauss = _gaussian_copy(graph, skip)
    # The selection needs residuals to a small fraction of a sigma, not the final solve's
    # 1e-10: stopping at a 1e-6 relative decrease saved a third of its time on the rings.
    cfg = dataclasses.replace(builder.cfg, lm_relative_error_tol=max(builder.cfg.lm_relative_error_tol, 1e-6))
    at = {}
    for c in builder.active_closures():
        at[c.id] = gauss.size()
        gauss.add(builder.closure_factor(c, robust=False))
    iterations = 0
    values = start
    while True:
        # warm start: without the removed closure the solution moves only near it
        values, its, _ = _lm(gauss, values, cfg)
        iterations += its
        worst = builder.judge_closures(values)
        if worst is None:
            return values, iterations
        builder.remove_closure(worst, "all-Gaussian")
        gauss.remove(at[worst.id])


def _check_pair(i: int, j: int, n: int, what: str, where: str) -> None:
    for name, v in (("i", i), ("j", j)):
        if not (0 <= int(v) < n):
            raise ValueError(f"{what}: {name}={v} is not a frame {where} (0..{n - 1})")
    if int(i) == int(j):
        raise ValueError(f"{what}: i and j must differ, got {i}")


def _is_manhattan_link(f) -> bool:
    """True for a pose-to-Manhattan-frame rotation factor (not anchors or ties)."""
    keys = f.keys()
    return len(keys) == 2 and gtsam.Symbol(keys[0]).chr() == ord("x") and gtsam.Symbol(keys[1]).chr() == ord("m")


def _floored(information: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """(3, 3) information whose marginal variances are at least ``floor`` (3,): each is raised
    by adding a diagonal to the covariance (keeps it positive definite)."""
    cov = np.linalg.inv(information)
    cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
    return np.linalg.inv(cov)


def _rms_velocity_change(t, v, n, i0, i1, noise_out: bool = False) -> float:
    """m/s^2: the RMS rate of velocity change between the steps ``i0`` and ``i1`` (pairs of
    indices) of velocities ``v`` at times ``t`` with noise variances ``n`` (all (K,)), each
    pair weighted by the inverse of its noise; with ``noise_out`` the pairs' own noise
    taken out of each squared change (what is left is the base's acceleration; 0 at least)."""
    w = 1.0 / (n[i1] + n[i0])
    sq = (v[i1] - v[i0]) ** 2 - (n[i0] + n[i1] if noise_out else 0.0)
    return math.sqrt(max(float((w * sq / (t[i1] - t[i0]) ** 2).sum() / w.sum()), 0.0))


class _Line(NamedTuple):
    """A weighted line through forward velocities (:func:`_velocity_line`): the first and
    last times (s), the fitted speeds there (m/s), the slope (m/s^2), whether the slope is
    beyond 3 of its sigmas, and the weighted mean speed (m/s)."""
    t_first: float
    t_last: float
    v_first: float
    v_last: float
    slope: float
    changing: bool
    mean: float


def _velocity_line(samples) -> _Line | None:
    """The weighted least-squares line through ``samples`` [(t, v, variance)], each
    weighted by its inverse variance; None with fewer than 4 or no spread in time. The
    slope's sigma comes from the stated variances, which are conservative (a braking
    partial step stated 2.1-3.5 mm and erred 0.1-0.5), so "changing" errs towards steady."""
    if len(samples) < 4:
        return None
    t, v, n = (np.array(x) for x in zip(*samples))
    wt = 1.0 / n
    tb, vb = float(wt @ t / wt.sum()), float(wt @ v / wt.sum())
    stt = float(wt @ (t - tb) ** 2)
    if not stt > 0:
        return None
    slope = float(wt @ ((t - tb) * (v - vb))) / stt
    return _Line(float(t[0]), float(t[-1]), vb + slope * (t[0] - tb), vb + slope * (t[-1] - tb), slope,
                 abs(slope) > 3.0 / math.sqrt(stt), vb)


class _GraphBuilder:
    """Turns front-end results into new factors and initial values (shared by both solvers)."""

    def __init__(self, config: BackendConfig, associator: ManhattanAssociator | None = None, *,
                 hold_start_gap: bool = True):
        self.cfg = config
        self.assoc = associator if associator is not None else ManhattanAssociator(config)
        self.n = 0
        self.raw: list[np.ndarray] = []     # chained steps, (3,) each
        self.guess: list[np.ndarray] = []   # initial values: steps chained with filtered yaw
        self.counts: Counter = Counter()    # factors by kind
        self.assoc_counts: Counter = Counter()
        # (kind, factor) of every robust factor, to report down-weighting after a solve
        self.robust: list[tuple[str, object]] = []
        self.closures: list[_Closure] = []  # every closure ever added, in order
        self.closure_time = 0.0             # s spent judging closures (selection, settling)
        # Manhattan frame j -> its current variable instance (key M(i)), links on it, last pose
        self.inst_of_frame: list[int] = []
        self._inst_links: list[int] = []
        self._inst_last: list[int] = []
        self.n_inst = 0
        self._inst_yaw: list[float] = []   # initial value of each instance
        #: optional ``f(instance) -> yaw`` giving the solver's current estimate of an instance
        self.instance_estimate = None
        self._tie_sigma = math.radians(config.manhattan_tie_sigma_deg)
        self._floor = np.array([config.step_min_sigma_xy, config.step_min_sigma_xy,
                                math.radians(config.step_min_sigma_theta_deg)]) ** 2
        self._closure_floor = np.array([config.closure_min_sigma_xy, config.closure_min_sigma_xy,
                                        math.radians(config.closure_min_sigma_theta_deg)]) ** 2
        #: the motion prior's memory, per frame: stamp (s), whether its step left the
        #: translation unmeasured, and its step's velocity (:meth:`_velocity`); per axis, the
        #: frames whose step was fine, in order (the gaps' edges, :meth:`_gap_accel`)
        self._mp_stamps: list[float] = []
        self._mp_weak: list[bool] = []
        self._mp_vel: list[tuple | None] = []
        self._mp_fine: tuple[list[int], list[int]] = ([], [])
        self._mp_fine_estimated: list[int] = []  # forward-fine steps an estimator measured (not weak)
        self._mp_measured: list[int] = []  # the first three steps whose forward speed was measured
        # the speed after a start gap (_start_windows) and the frames pending only for it
        self._mp_sw = {"out": [], "acc": np.zeros(4), "next": 0, "end": None}
        self._mp_start_only: set[int] = set()
        #: a start gap's priors wait for the speed measured after it (:meth:`_start_gap_accel`;
        #: a batch solve). iSAM2 cannot take the gap's metre-sigma chain without them, so it
        #: releases them where the gap ends, at the loose bound.
        self.hold_start_gap = hold_start_gap
        #: a gap's priors expect the change of speed measured beside it (:meth:`_gap_trend`):
        #: a batch solve, whose priors can wait for the window after the gap; iSAM2, as for
        #: a start gap, takes them where the gap ends
        self._gap_trends = config.motion_prior_gap_trend and hold_start_gap
        self._trend_gap = None  # (first step, last step, speed profile or None) of the last gap seen
        self._mp_upto = 1               # the last frame whose velocity the prior ties
        self._mp_pending: list[int] = []  # frames whose prior waits for the steps after them
        self._mp_last_weak = -(1 << 30)  # the last frame whose translation was unmeasured
        self._guess_sigma_sum = 0.0  # m, the guess sigmas of a gap's copies so far (_guess_weighted)
        self._yaw_accel = math.radians(config.motion_prior_yaw_accel_deg)
        self._bridged_info = np.diag(1.0 / np.array([config.bridged_sigma_xy, config.bridged_sigma_xy,
                                                     math.radians(config.bridged_sigma_theta_deg)]) ** 2)
        self.walls = WallMap(config)

    def step_information(self, information: np.ndarray, status: str) -> np.ndarray:
        """Information actually used for a step: bridged override, then sigma floors."""
        if status == STATUS_BRIDGED and self.cfg.bridged_policy == "override":
            information = self._bridged_info
        return _floored(information, self._floor)

    def relative_factor(self, i: int, j: int, pose: np.ndarray, information: np.ndarray, kind: str):
        noise = robust_noise(step_noise(information), self.cfg.robust_kernel, self.cfg.step_robust_parameter)
        f = gtsam.BetweenFactorPose2(X(i), X(j), gtsam.Pose2(*pose), noise)
        self.counts[kind] += 1
        if self.cfg.robust_kernel != "none":
            self.robust.append((kind, f))
        return f

    def _step_factors(self, k: int, result: FrameResult, odometry, graph) -> tuple[np.ndarray, np.ndarray]:
        """Add the step factor(s) into frame ``k``; returns the step ``(pose, information)``
        the initial value and the heading filter use: the front-end's step, fused with the
        wheel odometry's when there is one (a bridged step is then replaced by it)."""
        if result.step is None:
            raise ValueError(f"FrameResult {result.index} (graph frame {k}) has step=None; "
                             f"only the first frame of a run may lack a step")
        p = _check_pose(result.step.pose, f"FrameResult {result.index} step.pose")
        info = self.step_information(
            _check_information(result.step.information, f"FrameResult {result.index} step.information"),
            result.step.status)
        kind = result.step.status if result.step.status in (STATUS_BRIDGED, STATUS_PARTIAL) else "step"
        self.raw.append(se2_compose(self.raw[-1], p))
        guess = result.step.guess_information
        if guess is not None and odometry is None and self.cfg.motion_prior_accel > 0:
            info = self._guess_weighted(info, _check_information(guess, f"FrameResult {result.index} "
                                                                        "step.guess_information", psd=True),
                                        result.step.guess_copies)
        vision = self._vision_factor(k, result, p, info, kind)
        if odometry is None:
            for f in vision(np.eye(3)):
                graph.add(f)
            return p, info
        p_w = _check_pose(odometry.pose, "wheel odometry step")
        info_w = _check_information(odometry.information, "wheel odometry information")
        graph.add(self.relative_factor(k - 1, k, p_w, info_w, "wheel_odom"))
        if result.step.status == STATUS_BRIDGED and self.cfg.wheel_odom_replaces_bridge:
            self.counts["bridged_by_wheel_odom"] += 1
            return p_w, info_w
        w = np.eye(3)
        if not odometry.vision_agrees:  # keep vision's yaw, let the odometry carry the translation
            w = np.diag([math.sqrt(self.cfg.wheel_odom_distrust)] * 2 + [1.0])
            info = w @ info @ w
            self.counts["vision_translation_distrusted"] += 1
        for f in vision(w):
            graph.add(f)
        return fuse_steps(p, info, p_w, info_w)

    def _gap_factors(self, k: int, result: FrameResult, graph) -> None:
        """The motions into an earlier gap's frames the front-end measured at frame ``k``
        (``result.gap_links``, frontend/gapresection.py), each a factor of its own."""
        for g in result.gap_links:
            a, b = k - int(g.lag_from), k - int(g.lag_to)
            if not (0 <= a <= k and 0 <= b <= k and a != b):
                raise ValueError(f"FrameResult {result.index} (graph frame {k}): gap link lags {g.lag_from}, "
                                 f"{g.lag_to} must name two frames of 0..{k}")
            p = _check_pose(g.pose, f"FrameResult {result.index} gap_links pose")
            info = _floored(_check_information(g.information, f"FrameResult {result.index} gap_links information"),
                            self._floor)
            graph.add(self.relative_factor(a, b, p, info, "gap_link"))

    def _guess_weighted(self, info: np.ndarray, guess: np.ndarray, copies: int) -> np.ndarray:
        """A step's information ``info`` (3, 3) with its part ``guess`` (3, 3), the front-end's
        constant-velocity guess, kept as ``backend.motion_prior_guess`` says; ``copies``: the
        guess is the copies-th step in a row copying one velocity (``Step.guess_copies``).

        The guess copied into every step of a gap errs alike in all of them (the copied
        velocity's error, then the velocity's change since), but each step states its own
        sigma ``s_k`` as though independent: over a gap the graph would trust the guess
        ``sqrt(k)`` times too much. ``"correlated"`` divides the k-th copy's guess by
        ``f_k = (2 S_{k-1} + s_k) / s_k``, ``S_{k-1}`` the sigmas of the copies before it
        summed: the guessed distance over the first k copies then has variance ``S_k^2``,
        that of errors all of one sign (``sum_j (S_j^2 - S_{j-1}^2) = S_k^2``), and the
        motion prior (:meth:`_motion_prior`), which ties a gap to the speeds measured on
        both sides, gets the say it should in long gaps. ``"replace"`` leaves the guess
        out. What no measurement fixes keeps at least the bridged sigmas
        (``bridged_sigma_xy``, ``bridged_sigma_theta_deg``) so that the graph stays
        determined."""
        mode = self.cfg.motion_prior_guess
        if mode == "keep":
            return info
        keep = 0.0
        if mode == "correlated":
            if copies <= 1:
                self._guess_sigma_sum = 0.0
            lam = float(np.linalg.eigvalsh(guess[:2, :2]).max())  # the guess's tightest direction
            if not lam > 0:
                return info
            s_k = 1.0 / math.sqrt(lam)
            keep = s_k / (2.0 * self._guess_sigma_sum + s_k)
            self._guess_sigma_sum += s_k
        m = info - (1.0 - keep) * guess
        w, v = np.linalg.eigh(0.5 * (m + m.T))
        return (v * np.maximum(w, 0.0)) @ v.T + self._bridged_info

    def _vision_factor(self, k: int, result: FrameResult, p: np.ndarray, info: np.ndarray, kind: str):
        """``f(w)``: the front-end's factors into frame ``k`` (a list) with their information
        weighted by ``w @ info @ w``. A step measured against an earlier keyframe
        (``step.keyframe``) ties that frame to this one directly: the steps between them
        share its measurement, and the keyframe motion is what was measured. (The motions
        from one keyframe also share the keyframe's own errors; a copy of its pose taking
        half of each one's covariance, once, changed the smoothed drift of the three worst
        tuning halls of seeds 3700-3707 by less than 0.1 %, so they stay independent.)"""
        link = result.step.keyframe
        if result.step.keyframe_yaw is not None and self.cfg.keyframe_yaw_links:
            return self._yaw_linked(k, result, p, info, kind)
        if link is None or not self.cfg.keyframe_links:
            return lambda w: [self.relative_factor(k - 1, k, p, w @ info @ w, kind)]
        lag = int(link.lag)
        if not 1 <= lag <= k:
            raise ValueError(f"FrameResult {result.index} (graph frame {k}): keyframe lag {lag} is outside 1..{k}")
        p_k = _check_pose(link.pose, f"FrameResult {result.index} step.keyframe.pose")
        info_k = _floored(_check_information(link.information, f"FrameResult {result.index} step.keyframe.information"),
                          self._floor)
        self.counts["keyframe_links"] += 1
        return lambda w: [self.relative_factor(k - lag, k, p_k, w @ info_k @ w, kind)]

    def _yaw_linked(self, k: int, result: FrameResult, p: np.ndarray, info: np.ndarray, kind: str):
        """``f(w)`` (as :meth:`_vision_factor`) of a partial step whose yaw the front-end
        measured from a keyframe (``step.keyframe_yaw``): the step's factor keeps its
        translation (the marginal of its covariance; the yaw at the bridged sigma keeps the
        graph determined) and the heading change from the keyframe is a factor of its own
        (:func:`heading_between_factor`). The step's yaw is the difference of two such
        changes: on its own factor, the correction it takes back from the guessed yaws since
        the keyframe (their summed sigma in its own) looks to the motion prior like one
        step's jump, and the graph kept the guesses' error (a held-out hall: -1.13 deg
        taken back in one step at a stated 2.0 deg, kept at +1.5 deg by the graph while the
        raw chain went to +0.3)."""
        link = result.step.keyframe_yaw
        lag = int(link.lag)
        if not 1 <= lag <= k:
            raise ValueError(f"FrameResult {result.index} (graph frame {k}): keyframe_yaw lag {lag} is outside 1..{k}")
        variance = float(link.variance)
        if not (math.isfinite(float(link.yaw)) and math.isfinite(variance) and variance > 0):
            raise ValueError(f"FrameResult {result.index} step.keyframe_yaw: yaw {link.yaw} and variance "
                             f"{variance} must be finite, the variance > 0")
        variance = max(variance, float(self._floor[2]))
        cov = np.linalg.inv(info)
        translation = np.zeros((3, 3))
        translation[:2, :2] = np.linalg.inv(cov[:2, :2])
        translation[2, 2] = self._bridged_info[2, 2]
        self.counts["keyframe_yaw_links"] += 1

        def factors(w: np.ndarray) -> list:
            f = heading_between_factor(k - lag, k, float(link.yaw), variance / w[2, 2] ** 2,
                                       kernel=self.cfg.robust_kernel, parameter=self.cfg.step_robust_parameter)
            if self.cfg.robust_kernel != "none":
                self.robust.append(("keyframe_yaw", f))
            return [self.relative_factor(k - 1, k, p, w @ translation @ w, kind), f]
        return factors

    def frame(self, result: FrameResult, previous: np.ndarray | None = None, odometry=None):
        """Factors and values for one frame: ``(NonlinearFactorGraph, Values, index)``.

        ``previous``: the solver's current estimate of the previous pose (3,), used to
        initialise the new one; defaults to the builder's own guess. ``odometry``: the wheel
        odometry's step into this frame (:class:`planar_vo.backend.wheel.OdometryStep`) or None.
        """
        if not isinstance(result, FrameResult):
            raise TypeError(f"add_frame expects a FrameResult, got {type(result).__name__}")
        cfg = self.cfg
        k = self.n
        self.last_links = []
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:
            # The first frame defines odom; a step into it (from before the run) is ignored.
            sig = np.array([cfg.prior_sigma_xy, cfg.prior_sigma_xy, math.radians(cfg.prior_sigma_theta_deg)])
            graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(sig)))
            self.counts["prior"] += 1
            self.assoc.start(0.0, float(sig[2] ** 2))
            pose0 = np.zeros(3)
            self.raw.append(pose0)
            guess = pose0.copy()
            step = None
        else:
            p, info = self._step_factors(k, result, odometry, graph)
            self._gap_factors(k, result, graph)
            step = (p, np.linalg.inv(info))
            self.assoc.predict(float(p[2]), float(step[1][2, 2]))
            prev = self.guess[-1] if previous is None else previous
            guess = se2_compose(prev, p)
        if cfg.manhattan and result.manhattan:
            out = self.assoc.observe(k, result.manhattan)
            guess[2] = float(wrap_angle(guess[2] + out.theta_correction))
            for j, yaw in out.new_frames:
                self.inst_of_frame.append(self._new_instance(yaw, graph, values))
                self._inst_links.append(0)
                self._inst_last.append(k)
            self.last_links = list(out.links)
            inst_of = {}
            for link in out.links:
                inst = inst_of[link.frame] = self._instance_for(link.frame, k, graph, values)
                f = manhattan_factor(link.pose, inst, link.measured, link.sigma,
                                     kind=cfg.manhattan_factor, kernel=cfg.robust_kernel,
                                     parameter=cfg.manhattan_robust_parameter)
                graph.add(f)
                if cfg.robust_kernel != "none":
                    self.robust.append(("manhattan", f))
            self.counts["manhattan"] += len(out.links)
            self.assoc_counts.update(associated=out.associated, rejected=out.rejected,
                                     ignored=out.ignored, new_frames=len(out.new_frames))
            if cfg.walls and result.walls:
                self._wall_factors(k, guess, result.walls, [l for l in out.links if l.pose == k], inst_of,
                                   graph, values)
        self._motion_prior(k, result, odometry, step, graph)
        values.insert(X(k), gtsam.Pose2(*guess))
        self.guess.append(guess)
        self.n += 1
        return graph, values, k

    def _wall_factors(self, k: int, guess: np.ndarray, walls, links, inst_of: dict, graph, values) -> None:
        """Wall-offset factors of frame ``k`` (backend/walls.py): each wall the frame sees on
        an axis of a Manhattan frame it is linked to, tied to that frame's instance and to
        the wall's landmark, which is opened (its value inserted) at its first sighting."""
        for w in self.walls.observe(k, guess, walls, links, inst_of):
            if w.new:
                values.insert(W(w.wall), np.array([w.measured]))
                self.counts["wall_landmarks"] += 1
            graph.add(self._wall_factor(w))

    def flush(self) -> gtsam.NonlinearFactorGraph:
        """The factors held back until more frames arrived, at a solve: the wall factors of
        every landmark's last sighting and the motion priors waiting for the steps after them."""
        graph = gtsam.NonlinearFactorGraph()
        for w in self.walls.flush():
            graph.add(self._wall_factor(w))
        self._release_priors(graph, everything=True)
        return graph

    def _wall_factor(self, w):
        cfg = self.cfg
        f = wall_factor(w.pose, w.instance, w.wall, w.axis, w.anchor, w.measured, w.sigma,
                        kind=cfg.manhattan_factor, kernel=cfg.robust_kernel, parameter=cfg.wall_robust_parameter)
        self.counts["wall"] += 1
        if cfg.robust_kernel != "none":
            self.robust.append(("wall", f))
        return f

    def _motion_prior(self, k: int, result: FrameResult, odometry, step, graph) -> None:
        """Constant base_link velocity across steps whose translation no estimator measured
        (partial, bridged; a step with wheel odometry is measured) and the
        ``motion_prior_window`` steps on each side: the front-end only extrapolates the
        velocity forward from before a gap, this ties a gap to the speed measured on both
        sides (and fills a gap at the start of a run, where there is no "before": a
        textureless corridor until its end wall comes into range). ``step``: the step
        ``(pose (3,), covariance (3, 3))`` into frame ``k`` (None for the first frame).
        Each prior waits for the ``2 motion_prior_window`` frames after it, whose steps
        its acceleration is fitted to (:meth:`_prior_accel`), and for its gap to end, or
        for the solve (:meth:`flush`)."""
        weak = (k > 0 and odometry is None and result.step.status in (STATUS_BRIDGED, STATUS_PARTIAL)
                and not result.step.translation_measured)
        self._mp_stamps.append(float(result.stamp))
        self._mp_weak.append(weak)
        # every step's velocity and stated noise: a guessed one's noise keeps it out of the fit
        vel = self._velocity(step)
        self._mp_vel.append(vel)
        for ax in range(2):
            if vel is not None and vel[3][ax]:
                self._mp_fine[ax].append(k)
        if vel is not None and vel[3][0] and not weak:
            self._mp_fine_estimated.append(k)
        if len(self._mp_measured) < 3 and self._forward_measured(k):
            self._mp_measured.append(k)
        w = self.cfg.motion_prior_window
        if weak:
            self._mp_last_weak = k
        near_gap = k - self._mp_last_weak <= w + 1
        if self.cfg.motion_prior_accel > 0 and (near_gap or self._in_start_gap(k)):
            # a gap reaches back over the measured steps before it (known when it starts)
            first = max(2, self._mp_upto + 1, k - w if weak else k)
            self._mp_pending.extend(range(first, k + 1))
            self._mp_upto = max(self._mp_upto, k)
            if not near_gap:
                self._mp_start_only.add(k)  # its prior only if the start gap's windows arrive
        self._release_priors(graph)

    def _forward_measured(self, k: int) -> bool:
        """Whether step ``k``'s forward speed was measured: by an estimator, or by a partial
        step stated within 25 % (walls ahead, the depth alignment or far corners). A start gap
        ends at the first such step. Counting an estimator's steps only, a log with no
        estimator step at all (an untextured corridor) never ended it: its priors stayed at the
        loose bound, nothing held the start to the speed measured after it, and an untextured
        straight corridor whose distance along was first measured 205 frames in started at
        35 mm a step against a true 26 (straight_s9636 of seeds 9600-9699)."""
        vel = self._mp_vel[k]
        return vel is not None and (not self._mp_weak[k] or math.sqrt(vel[2][0]) < 0.25 * abs(vel[1][0]))

    def _release_priors(self, graph, everything: bool = False) -> None:
        """Add the pending motion priors whose fitting window has arrived and whose gap has
        ended (this frame's translation measured), or all of them with ``everything``: the
        velocity of step j tied to that of step j-1."""
        last = len(self._mp_stamps) - 1
        if not everything and self._mp_last_weak == last:
            return  # a gap goes on: its priors need the speed measured after it
        h = 2 * self.cfg.motion_prior_window
        if (not everything and self._gap_trends and self._mp_pending
                and self._mp_pending[0] <= self._mp_last_weak + 1
                and last - self._mp_last_weak < self.cfg.motion_prior_window):
            return  # the gap's priors wait for the window after it, whose trend they expect
        while self._mp_pending and (everything or self._mp_pending[0] + h <= last):
            if not everything and self._in_start_gap(self._mp_pending[0]) and self._start_windows() is None:
                return  # a gap at the start waits for the speed measured after it
            j = self._mp_pending.pop(0)
            dt1 = self._mp_stamps[j - 1] - self._mp_stamps[j - 2]
            dt2 = self._mp_stamps[j] - self._mp_stamps[j - 1]
            if not (dt1 > 0 and dt2 > 0):
                continue  # repeated stamps: no duration to turn into a velocity
            accel = self._prior_accel(j)
            # the measured steps next to a start gap count as in it once the speed after it is
            # known: tied to one 5 mm step only, a gap took that step's error (_start_gap_accel)
            start = self._in_start_gap(j) and self._start_windows() is not None
            if j in self._mp_start_only and not start:
                continue
            in_gap = self._mp_weak[j] or self._mp_weak[j - 1] or start
            if not in_gap and np.all(accel >= self.cfg.motion_prior_accel):
                # two measured steps whose neighbours show no steadier speed than the upper
                # bound: the prior would only smooth them (a 30 Hz tuning hall of 2-point
                # steps went 0.50 -> 1.09 % with it)
                continue
            if in_gap and self.cfg.motion_prior_gap_baseline_s > 0:
                accel = self._gap_prior_accel(j, accel)
            # The velocity may change by what the acceleration does between the steps' midpoints.
            dt = 0.5 * (dt1 + dt2)
            expected = self._start_ramp(j)
            if expected is None and in_gap and not start and self._gap_trends:
                expected = self._gap_trend(j)
            f = constant_velocity_factor(j, dt1, dt2, accel * dt, self._yaw_accel * dt,
                                         kernel=self.cfg.robust_kernel, parameter=self.cfg.step_robust_parameter,
                                         expected=expected)
            graph.add(f)
            self.counts["motion_prior"] += 1
            if self.cfg.robust_kernel != "none":
                self.robust.append(("motion_prior", f))

    def _start_ramp(self, j: int) -> np.ndarray | None:
        """(3,) the velocity change from step j-1 to step j when both lie before the first
        step whose forward speed was measured and the base is taken to start at rest
        (``motion_prior_start_at_rest``): it speeds up at ``motion_prior_accel`` from the
        first frame until it reaches the speed measured after that gap (the median of the
        first three such steps, as one may be an outlier), then holds it. None otherwise (no
        change expected). Without it the prior carries the speed measured after a gap at the
        start of a run back to the first frame, as though the base had been moving when the
        log began: a base starting from rest is put too far by about v^2 / (2 a)."""
        meas = self._mp_measured
        if not (self.cfg.motion_prior_start_at_rest and meas and j <= meas[0]):
            return None
        v_after = np.median(np.array([self._mp_vel[i][1] for i in meas]), axis=0)
        speed = float(np.linalg.norm(v_after))
        if not speed > 0:
            return None
        t0, st = self._mp_stamps[0], self._mp_stamps

        def ramp(i):  # speed of step i (at its midpoint) on the ramp from rest
            return min(speed, self.cfg.motion_prior_accel * (0.5 * (st[i] + st[i - 1]) - t0))

        dv = (ramp(j) - ramp(j - 1)) * v_after / speed
        return np.array([dv[0], dv[1], 0.0])

    def _gap_trend(self, j: int) -> np.ndarray | None:
        """(3,) the forward velocity change expected from step j-1 to step j, a prior that
        touches a gap (a run of steps whose forward speed was not measured,
        :meth:`_forward_measured`), or None (no change expected: the speeds on both sides are
        joined by a straight ramp; :meth:`_gap_speed`). A gap's priors are released in order
        once it has ended, so its bounds and profile are found once and kept for the next."""
        measured = self._forward_measured
        if measured(j) and measured(j - 1):
            return None  # both speeds measured (a partial step the wall ahead measured)
        i = j - 1 if measured(j) else j
        gap = self._trend_gap
        if gap is None or not gap[0] <= i <= gap[1]:
            a = b = i
            while a > 1 and not measured(a - 1):
                a -= 1
            while b + 1 < len(self._mp_vel) and not measured(b + 1):
                b += 1
            gap = self._trend_gap = (a, b, self._gap_speed(a, b))
        speed = gap[2]
        if speed is None:
            return None
        st = self._mp_stamps
        return np.array([speed(0.5 * (st[j] + st[j - 1])) - speed(0.5 * (st[j - 1] + st[j - 2])), 0.0, 0.0])

    def _gap_speed(self, a: int, b: int):
        """The expected forward speed (m/s) as a function of time over the gap of steps
        ``a..b``, or None (a ramp).

        The forward velocities of the measured steps within ``motion_prior_window`` on each
        side are fitted with a line each (:func:`_velocity_line`). Where one side's slope is
        beyond 3 sigmas, the other's is not, and the slope leads from the steady side's speed
        to its own, the change it shows is carried into the gap at that slope until it meets
        the steady speed: a base braking in front of the wall that ended a gap was braking
        for the last few steps of the gap, not over all of it. Spread over the gap as a
        ramp, a brake that began 4 steps before the end of a 100-step gap cost 0.19 m on
        unseen lturn_s10604 (the raw chain's cruise guess kept it)."""
        w, n = self.cfg.motion_prior_window, len(self._mp_vel)
        before = _velocity_line(self._measured_forward(range(max(1, a - w), a)))
        after = _velocity_line(self._measured_forward(range(b + 1, min(n, b + 1 + w))))
        if before is None or after is None or before.changing == after.changing:
            return None  # both steady (a ramp is all there is to go on) or both changing
        lo, hi = before.t_last, after.t_first  # the gap's edges (the steps' midpoints)
        if after.changing:  # carried back from the side after the gap to the steady speed
            v_steady, slope = before.mean, after.slope
            tc = hi - (after.v_first - v_steady) / slope
            if not lo < tc < hi:
                return None  # the slope leads away from the steady speed, or meets it outside the gap
            return lambda t: v_steady if t <= tc else v_steady + slope * (t - tc)
        v_steady, slope = after.mean, before.slope  # carried on from the side before the gap
        tc = lo + (v_steady - before.v_last) / slope
        if not lo < tc < hi:
            return None
        return lambda t: v_steady if t >= tc else before.v_last + slope * (t - lo)

    def _measured_forward(self, frames) -> list[tuple[float, float, float]]:
        """``(t, v, variance)`` of the forward velocity of the steps among ``frames`` whose
        forward speed was measured (:meth:`_forward_measured`: also a partial step the wall
        ahead measured). Not only the fine ones (:meth:`_velocity`): a line through ten steps
        resolves a slope that no pair of them does, and its 3-sigma test is on the line (a
        brake the wall ahead measured at a stated 2.3 mm a 15 Hz step is not fine)."""
        out = []
        for i in frames:
            vel = self._mp_vel[i]
            if self._forward_measured(i) and vel[2][0] > 0:
                out.append((vel[0], float(vel[1][0]), float(vel[2][0])))
        return out

    def _velocity(self, step):
        """The newest frame's ``step`` ``(pose (3,), covariance (3, 3))`` (None for the first
        frame) as ``(t, v (2,), n (2,), fine (2,))``: its midpoint (s), base_link velocity
        (m/s), the velocity's stated variance and whether it was measured finely enough to
        show an acceleration below ``motion_prior_accel`` from one step to the next (a
        guessed step never is); None for the first frame and repeated stamps."""
        i = len(self._mp_stamps) - 1
        dt = self._mp_stamps[i] - self._mp_stamps[i - 1] if i >= 1 else 0.0
        if step is None or not dt > 0:
            return None
        s, var = np.asarray(step[0][:2], float), np.diag(step[1])[:2].copy()
        n = var / dt ** 2
        # two such steps' velocity change has less noise than the cap's change, (cap dt)^2
        fine = n < 0.5 * (self.cfg.motion_prior_accel * dt) ** 2
        return 0.5 * (self._mp_stamps[i] + self._mp_stamps[i - 1]), s / dt, n, fine

    def _prior_accel(self, k: int) -> np.ndarray:
        """(2,) m/s^2: the base_link acceleration (x, y) the prior on step ``k`` allows,
        within ``[motion_prior_min_accel, motion_prior_accel]``: the RMS velocity change of
        consecutive fine steps (:meth:`_velocity`) within ``2 motion_prior_window`` frames,
        weighted by their inverse noise (the upper bound when fewer than three pairs were
        fine), and at least the mean acceleration across the gap step ``k`` is in
        (:meth:`_gap_accel`). Their noise stays in: stated sigmas are conservative (a
        braking partial step said 2.1-3.5 mm and erred 0.1-0.5), so taking it out would call a
        braking base cruising."""
        c = self.cfg
        h = 2 * c.motion_prior_window
        steps = self._mp_vel[max(1, k - h):min(k + h, len(self._mp_vel) - 1) + 1]
        a = np.full(2, c.motion_prior_accel)
        for ax in range(2):
            fine = [(t, v[ax], n[ax]) for t, v, n, f in filter(None, steps) if f[ax]]
            if len(fine) < 4:
                continue
            t, v, n = (np.array(x) for x in zip(*fine))
            a[ax] = _rms_velocity_change(t, v, n, np.arange(len(t) - 1), np.arange(1, len(t)))
        return np.clip(np.maximum(a, self._gap_accel(k)), min(c.motion_prior_min_accel, c.motion_prior_accel),
                       c.motion_prior_accel)

    def _gap_prior_accel(self, k: int, accel: np.ndarray) -> np.ndarray:
        """(2,) m/s^2: :meth:`_prior_accel`'s ``accel`` (2,) for a prior on a step in a gap, or
        next to one, with the forward axis refitted where fine steps (:meth:`_velocity`) that an
        estimator measured lie on both sides: to velocity changes between them at least
        ``motion_prior_gap_baseline_s`` apart (each to the first one that far on), from the
        window's fine steps and at least the five nearest on each side of ``k`` (pairs across
        the gap say what the gap did). Their noise then counts a few times less and a
        sustained change of speed (a brake) as much: consecutive fine steps' changes are
        mostly noise (3 mm steps at 10 Hz: ~0.4 m/s^2), and at that looseness two partial
        steps that a few 3-D matches measured at half their length (3 sigmas) pulled a
        60-step gap's speed down with them (a held-out low-texture L ended 19 cm shorter than
        its raw odometry). Partial steps that walls or the depth alignment measured finely
        are left out: where they are most of the steps (a textureless L), held to the speed
        of the few measured ones the turn came out 0.74 -> 1.21 % off. Sideways a weaving
        base's velocity turns with it: that axis keeps ``accel``. A gap at the start of a run
        has no "before": :meth:`_start_gap_accel`."""
        if self._in_start_gap(k):
            return self._start_gap_accel(k, accel)
        fine = self._mp_fine_estimated
        j = bisect.bisect_left(fine, k)
        if not 0 < j < len(fine):
            return accel
        c = self.cfg
        h = 2 * c.motion_prior_window
        idx = fine[min(bisect.bisect_left(fine, max(1, k - h)), j - 5 if j > 5 else 0):
                   max(bisect.bisect_right(fine, k + h), j + 5)]
        a = c.motion_prior_accel
        if len(idx) >= 4:
            t, v, n = (np.array(x) for x in zip(*((self._mp_vel[i][0], self._mp_vel[i][1][0], self._mp_vel[i][2][0])
                                                   for i in idx)))
            # each to the first at least the baseline on (steps exactly that far apart count)
            nxt = np.searchsorted(t, t + c.motion_prior_gap_baseline_s * (1.0 - 1e-6))
            i0 = np.flatnonzero(nxt < len(t))
            i0, i1 = (i0, nxt[i0]) if len(i0) >= 3 else (np.arange(len(t) - 1), np.arange(1, len(t)))
            a = _rms_velocity_change(t, v, n, i0, i1)
        # The gap's own change of speed within a third of a sigma a step: held to its mean
        # acceleration at one sigma, the robust kernel found it cheaper to put a speed-up
        # into one step at the gap's end than to spread it (a 0.4 -> 0.8 m/s ramp, 51 cm off).
        return self._with_forward_accel(k, accel, a)

    def _with_forward_accel(self, k: int, accel: np.ndarray, a: float) -> np.ndarray:
        """``accel`` (2,) with its forward axis ``a`` (m/s^2), at least 3 times the mean
        acceleration across the gap step ``k`` is in (:meth:`_gap_accel`), within
        ``[motion_prior_min_accel, motion_prior_accel]``."""
        c = self.cfg
        out = np.array(accel, dtype=float)
        out[0] = min(max(a, 3.0 * float(self._gap_accel(k)[0]), c.motion_prior_min_accel), c.motion_prior_accel)
        return out

    def _in_start_gap(self, k: int) -> bool:
        """Whether the prior on step ``k`` belongs to a gap at the start of a run (there is no
        "before"): it ties a step before the first one whose forward speed was measured
        (:meth:`_forward_measured`), or one of the measured steps whose windows give the
        speed after the gap (:meth:`_start_windows`;
        all of them while those windows are incomplete). False where the gap was no longer
        than ``motion_prior_window`` steps: the window ties it to the measured steps after it,
        as any other gap. The windows tie 2 s of measured steps at the acceleration they show
        between them, and a base speeding up from rest over those seconds is bent by it: on
        lturn_s8701 (8700 set; one partial first step, then 0 -> 0.44 m/s in 1 s) the
        smoothed start lost 10 mm that the raw chain kept (0.08 -> 0.25 % of the path)."""
        first = self._mp_measured[0] if self._mp_measured else None
        if not self.hold_start_gap or self.cfg.motion_prior_gap_baseline_s <= 0:
            return False
        if first is not None and first <= 1 + self.cfg.motion_prior_window:
            return False
        end = self._mp_sw["end"]
        return first is None or end is None or k <= end

    def _start_windows(self, count: int = 4) -> list | None:
        """``(t, v, n)`` (s, m/s, (m/s)^2) of the first ``count`` windows of steps whose
        forward speed was measured (:meth:`_forward_measured`) after a gap at the start, in
        order, each spanning at least ``motion_prior_gap_baseline_s``: the base_link forward
        velocity over the window (its summed displacement over its summed duration) and that
        velocity's noise variance.
        None until that many windows have arrived. Whole windows, not single steps: a
        20 Hz direction-plus-point step states ~5 mm, a velocity noise of ~0.1 m/s that
        hides what a cruising base does. Each step is read once (the scan resumes)."""
        sw = self._mp_sw
        if not self._mp_measured or len(sw["out"]) >= count:
            return sw["out"] if len(sw["out"]) >= count else None
        acc = sw["acc"]  # displacement, duration, variance, time-weighted midpoint
        for i in range(max(sw["next"], self._mp_measured[0]), len(self._mp_vel)):
            sw["next"] = i + 1
            vel = self._mp_vel[i]
            if not self._forward_measured(i):
                continue
            dt = self._mp_stamps[i] - self._mp_stamps[i - 1]
            acc += (vel[1][0] * dt, dt, vel[2][0] * dt * dt, vel[0] * dt)
            if acc[1] >= self.cfg.motion_prior_gap_baseline_s * (1.0 - 1e-6):
                sw["out"].append((acc[3] / acc[1], acc[0] / acc[1], acc[2] / acc[1] ** 2))
                acc[:] = 0.0
                if len(sw["out"]) == count:
                    sw["end"] = i
                    return sw["out"]
        return None

    def _start_gap_accel(self, k: int, accel: np.ndarray) -> np.ndarray:
        """(2,) m/s^2: :meth:`_prior_accel`'s ``accel`` for a prior in a gap at the start of
        a run, with the forward axis refitted to the velocity changes between the windows
        of measured steps after the gap (:meth:`_start_windows`), their stated noise taken
        out, and at least 3 times the gap's own mean acceleration. At the loose upper bound
        the speed carried back to the first frame was that of the first few partial steps
        that measured some of it, each to ~100 % of a 10 mm step, and of the one measured
        step next to the gap: a textureless corridor whose end wall came into range after
        250 frames (straight_s8303) was put 0.90 m too far (4 mm a step over the first 160).
        Unlike a gap between measured steps (:meth:`_gap_prior_accel`) nothing on the other
        side checks the speed carried over, so the prior is only as loose as the base's
        measured acceleration: with the noise kept in, 5 mm steps at 20 Hz read as 0.03-0.13
        m/s^2 (median 0.09) and the gap of tests/test_backend_graph.py erred 0.19 m RMS over
        10 seeds, against 0.13 with it taken out."""
        win = self._start_windows()
        if win is None:  # the run ended first (a solve's flush): the windows that did arrive
            win = self._mp_sw["out"] if len(self._mp_sw["out"]) >= 2 else None
        if win is None:
            return accel
        t, v, n = (np.array(x) for x in zip(*win))
        a = _rms_velocity_change(t, v, n, np.arange(len(t) - 1), np.arange(1, len(t)), noise_out=True)
        return self._with_forward_accel(k, accel, a)

    def _gap_accel(self, k: int) -> np.ndarray:
        """(2,) m/s^2, per axis: where steps that are not fine (:meth:`_velocity`) lie
        between the last fine step before step ``k`` and the first from ``k`` on, the mean
        acceleration between those two (the gap's steps must span the change of speed
        measured across it); else 0."""
        out = np.zeros(2)
        for ax in range(2):
            fine = self._mp_fine[ax]
            j = bisect.bisect_left(fine, k)  # fine[j - 1] < k <= fine[j]
            if 0 < j < len(fine) and fine[j] - fine[j - 1] > 1:
                (tb, vb, _, _), (ta, va, _, _) = self._mp_vel[fine[j - 1]], self._mp_vel[fine[j]]
                out[ax] = abs(va[ax] - vb[ax]) / (ta - tb)
        return out

    def _new_instance(self, yaw: float, graph, values) -> int:
        i = self.n_inst
        self.n_inst += 1
        self._inst_yaw.append(float(yaw))
        values.insert(M(i), manhattan_value(yaw, self.cfg.manhattan_factor))
        if self.cfg.manhattan_factor == "native":
            graph.add(manhattan_anchor(i))
            self.counts["manhattan_anchor"] += 1
        return i

    def _instance_for(self, j: int, pose: int, graph, values) -> int:
        """Instance of frame ``j`` to link pose ``pose`` to; opens and ties a new one when
        the current one is full or the frame is being revisited."""
        size = self.cfg.manhattan_instance_size
        cur = self.inst_of_frame[j]
        if size and self._inst_links[j] and (self._inst_links[j] >= size or pose - self._inst_last[j] > size):
            if self.instance_estimate is not None and not values.exists(M(cur)):
                yaw = self.instance_estimate(cur)
            elif values.exists(M(cur)):
                yaw = self._yaw_of(values, cur)
            else:
                yaw = self._inst_yaw[cur]
            new = self._new_instance(yaw, graph, values)
            graph.add(manhattan_tie(cur, new, self._tie_sigma, self.cfg.manhattan_factor))
            self.counts["manhattan_tie"] += 1
            self.inst_of_frame[j] = cur = new
            self._inst_links[j] = 0
        self._inst_links[j] += 1
        self._inst_last[j] = max(self._inst_last[j], pose)
        return cur

    def _yaw_of(self, values: gtsam.Values, inst: int) -> float:
        if self.cfg.manhattan_factor == "native":
            return values.atPose2(M(inst)).theta()
        return values.atRot2(M(inst)).theta()

    def check_relative(self, i: int, j: int, pose, information, what: str = "add_relative"):
        _check_pair(i, j, self.n, what, "of the graph")
        return (_check_pose(pose, f"{what} pose"),
                self.step_information(_check_information(information, f"{what} information"), ""))

    # ------------------------------------------------------------------ loop closures
    def new_closure(self, i: int, j: int, pose, information, info: dict | None) -> _Closure:
        """Validate and record a closure (its information gets the closure sigma floors)."""
        _check_pair(i, j, self.n, "add_closure", "of the graph")
        p = _check_pose(pose, "add_closure pose")
        inf = _floored(_check_information(information, "add_closure information"), self._closure_floor)
        info = dict(info or {})
        clash = sorted(set(info) & set(_CLOSURE_KEYS))
        if clash:
            raise ValueError(f"add_closure: info may not use the reserved key(s) {clash}; rename them")
        c = _Closure(len(self.closures), int(i), int(j), p, inf, info)
        self.closures.append(c)
        return c

    def closure_factor(self, c: _Closure, robust: bool):
        """``BetweenFactorPose2(X(i), X(j))``, Gaussian or with the closure kernel."""
        noise = step_noise(c.information)
        if robust:
            noise = robust_noise(noise, self.cfg.closure_robust_kernel, self.cfg.closure_robust_parameter)
        return gtsam.BetweenFactorPose2(X(c.i), X(c.j), gtsam.Pose2(*c.pose), noise)

    def judge_closures(self, values: gtsam.Values) -> _Closure | None:
        """Set every closure's Mahalanobis residual at ``values``; return the active closure
        with the largest one if it exceeds ``closure_max_error_sigmas`` (else None)."""
        worst = None
        for c in self.closures:
            between = values.atPose2(X(c.i)).between(values.atPose2(X(c.j)))
            # the BetweenFactor's error: Logmap(measured^-1 * T_i^-1 T_j), tangent [x, y, theta]
            e = gtsam.Pose2.Logmap(gtsam.Pose2(*c.pose).between(between))
            c.residual = float(math.sqrt(max(float(e @ c.information @ e), 0.0)))
            if c.status == "active" and (worst is None or c.residual > worst.residual):
                worst = c
        limit = self.cfg.closure_max_error_sigmas
        return worst if worst is not None and limit > 0 and worst.residual > limit else None

    def remove_closure(self, c: _Closure, solve: str) -> None:
        """Mark ``c`` removed, the reason naming the ``solve`` that showed its residual."""
        n = sum(1 for o in self.closures if o.status == "active")
        c.status = "removed"
        c.reason = (f"residual {c.residual:.1f} sigma > closure_max_error_sigmas "
                    f"{self.cfg.closure_max_error_sigmas:g} after the {solve} solve (worst of {n} active closures)")

    def reinstate_closures(self) -> list[_Closure]:
        """Make every removed closure active again, to be judged afresh with all the others
        (one judged alone, e.g. the first of a loop, may fit once later ones share its pull);
        returns them."""
        back = [c for c in self.closures if c.status == "removed"]
        for c in back:
            c.status, c.reason = "active", None
        return back

    def active_closures(self) -> list[_Closure]:
        return [c for c in self.closures if c.status == "active"]

    def closure_dicts(self) -> list[dict]:
        """One dict per closure, in order (see :meth:`PlanarPoseGraph.closures`)."""
        out = []
        for c in self.closures:
            d = {"id": c.id, "i": c.i, "j": c.j, "pose": [float(v) for v in c.pose],
                 "sigma": [float(v) for v in np.sqrt(np.diag(np.linalg.inv(c.information)))],
                 "status": c.status, "residual_sigmas": c.residual, "reason": c.reason}
            d.update(c.info)
            out.append(d)
        return out

    def poses_from(self, values: gtsam.Values) -> np.ndarray:
        """(N, 3) poses ``X(0..N-1)`` from ``values``."""
        allp = gtsam.utilities.extractPose2(values)
        # Values iterate in key order; M(.) sorts before X(.), so the poses are the tail.
        out = np.asarray(allp[len(allp) - self.n:], dtype=np.float64)
        out[:, 2] = wrap_angle(out[:, 2])
        return out

    def frames_from(self, values: gtsam.Values | None) -> list[tuple[int, float, int]]:
        out = []
        for j, n_obs in enumerate(self.assoc.n_obs):
            if values is None:
                yaw = float(self.assoc.frame_yaws()[j])
            else:
                yaw = self._yaw_of(values, self.inst_of_frame[j])
            out.append((j, float(wrap_quarter(yaw)), int(n_obs)))
        return out

    def downweighted(self, values: gtsam.Values) -> dict[str, int]:
        """Robust factors whose IRLS weight is below 0.5 at ``values``, by kind."""
        cfg = self.cfg
        out: Counter = Counter()
        for kind, f in self.robust:
            noise = f.noiseModel()
            u = noise.noise().mahalanobisDistance(f.unwhitenedError(values))
            par = {"manhattan": cfg.manhattan_robust_parameter,
                   "wall": cfg.wall_robust_parameter}.get(kind, cfg.step_robust_parameter)
            if robust_weight(cfg.robust_kernel, par, u) < 0.5:
                out[kind] += 1
        return dict(out)

    def stats(self) -> dict:
        a = self.assoc_counts
        return {
            "poses": self.n,
            "factors": dict(self.counts),
            "manhattan_frames": self.assoc.n_frames,
            "manhattan_instances": self.n_inst,
            "associations": int(a["associated"]),
            "new_frames": int(a["new_frames"]),
            "rejected": int(a["rejected"]),
            "ignored": int(a["ignored"]),
            "pending": self.assoc.n_pending,
            "drift_associations": self.assoc.drift_associations,
            "closures": {"added": len(self.closures), "active": len(self.active_closures()),
                         "removed": sum(1 for c in self.closures if c.status == "removed")},
            "closure_time_s": self.closure_time,
            "walls": {"landmarks": len(self.walls.walls), **self.walls.counts},
        }


class PlanarPoseGraph:
    """Batch planar pose graph (offline default).

    >>> g = PlanarPoseGraph()
    >>> for r in frame_results: g.add_frame(r)
    >>> poses = g.optimize()          # (N, 3) T_odom_base

    ``associator``: a :class:`ManhattanAssociator` (or subclass) to use instead of the
    default one built from ``config``, e.g. one that consults the front-end's track ids.
    """

    def __init__(self, config: BackendConfig | None = None, *,
                 associator: ManhattanAssociator | None = None):
        self.config = config or BackendConfig()
        self._b = _GraphBuilder(self.config, associator)
        self._graph = gtsam.NonlinearFactorGraph()
        self._initial = gtsam.Values()
        self._result: gtsam.Values | None = None
        self._without_closures: gtsam.Values | None = None
        self._solve: dict = {}
        self._prunable: list[int] = []    # indices of Manhattan links and extra relative factors
        self._pruned: Counter = Counter()
        self._link_of: dict = {}          # factor index -> ManhattanLink
        #: (factor count, values, poses) of the last optimize(): factors are only appended (or
        #: emptied by a solve), so the first ``count`` are the graph that was solved
        self._solved: tuple | None = None
        self._joint = None                 # gtsam.Marginals on _solved, built on first use

    def __len__(self) -> int:
        return self._b.n

    def add_frame(self, result: FrameResult, odometry=None) -> int:
        """Add one front-end frame (its step from the previous one and its Manhattan
        observations) and, when given, the wheel odometry's step into it
        (:class:`planar_vo.backend.wheel.OdometryStep`); returns the frame's index in the graph."""
        graph, values, k = self._b.frame(result, odometry=odometry)
        base = self._graph.size()
        links = iter(self._b.last_links)
        for i in range(graph.size()):
            if _is_manhattan_link(graph.at(i)):
                self._prunable.append(base + i)
                self._link_of[base + i] = next(links)
        self._graph.push_back(graph)
        self._initial.insert(values)
        self._result = None
        return k

    def manhattan_links(self) -> list[ManhattanLink]:
        """The Manhattan rotation factors the last :meth:`add_frame` added, as
        :class:`ManhattanLink` (pose, local frame id, ``measured`` = ``m_frame - theta_pose``
        in rad with its 90-degree branch resolved, sigma in rad); a new local frame's links
        may name earlier poses."""
        return list(self._b.last_links)

    def add_relative(self, i: int, j: int, pose, information) -> None:
        """Extra factor ``T_base_i_base_j = pose`` (3,) with (3, 3) ``information`` (e.g. a loop closure)."""
        p, info = self._b.check_relative(i, j, pose, information)
        self._prunable.append(self._graph.size())
        self._graph.add(self._b.relative_factor(i, j, p, info, "relative"))
        self._result = None

    def add_closure(self, i: int, j: int, pose, information, *, info: dict | None = None) -> int:
        """Loop closure ``T_base_i_base_j = pose`` (3,) ``(x, y, theta)`` with (3, 3)
        ``information`` (Pose2 tangent order ``[x, y, theta]``; sigmas floored at
        ``closure_min_sigma_xy`` / ``closure_min_sigma_theta_deg``).

        Solved robustly and removed by :meth:`optimize` if its residual stays beyond
        ``closure_max_error_sigmas``. ``info`` (e.g. the verification's inliers) is kept and
        returned by :meth:`closures`. Returns the closure id (0, 1, ... in order added).
        """
        c = self._b.new_closure(i, j, pose, information, info)
        c.index = self._graph.size()
        self._graph.add(self._b.closure_factor(c, robust=True))
        self._result = None
        return c.id

    def closures(self) -> list[dict]:
        """One dict per closure ever added, in order: ``id, i, j, pose [x, y, theta],
        sigma [sx, sy, stheta]`` (of the information used), ``status`` ('active' | 'removed'),
        ``residual_sigmas`` (Mahalanobis distance of its residual at the last solution, None
        before any), ``reason`` (None, or why it was removed), then the caller's ``info``."""
        return self._b.closure_dicts()

    def solve_without_closures(self) -> np.ndarray:
        """(N, 3) float64 ``T_odom_base`` of the graph without its loop closures: the first
        stage of :meth:`optimize` (Manhattan pruning included), which solves it anyway."""
        if self._result is None:
            self.optimize()
        return self._b.poses_from(self._without_closures)

    def optimize(self) -> np.ndarray:
        """Batch Levenberg-Marquardt over the whole graph; (N, 3) float64 ``T_odom_base``.

        With closures: first the graph without them (Manhattan pruning included), then every
        closure ever added (removed ones again too: the decision depends on the set of
        closures, not on the order of calls) is judged against that solution
        (:meth:`_solve_closures`)."""
        if self._b.n == 0:
            return np.zeros((0, 3))
        cfg = self.config
        t0 = time.perf_counter()
        self._b.reinstate_closures()
        self._graph.push_back(self._b.flush())
        closures = self._b.closures
        for c in closures:
            self._graph.remove(c.index)
        error_initial = float(self._graph.error(self._initial))
        self._result, iterations, error = _lm(self._graph, self._initial, cfg)
        if cfg.prune_sigmas > 0 and self._prune(self._result):
            self._result, its, error = _lm(self._graph, self._result, cfg)
            iterations += its
        self._without_closures = self._result  # the solution evaluate shows as "smoothed, no loops"
        if closures:
            t1 = time.perf_counter()
            its, error = self._solve_closures(self._result)
            iterations += its
            self._b.closure_time += time.perf_counter() - t1
        self._solve = {"iterations": iterations, "time_s": time.perf_counter() - t0,
                       "error_initial": error_initial, "error_final": error,
                       "pruned": dict(self._pruned)}
        self._solved, self._joint = (self._graph.size(), self._result, self._b.n), None
        return self._b.poses_from(self._result)

    def _solve_closures(self, start: gtsam.Values) -> tuple[int, float]:
        """Add the active closures to ``start``, the solution of the graph without them
        (whose closure slots are empty): select them all-Gaussian (:func:`_select_closures`),
        then solve with the closure kernel from the Gaussian solution; if a closure's residual
        then exceeds ``closure_max_error_sigmas``, remove the worst and select again from
        ``start``. Returns ``(iterations, final error)``."""
        cfg = self.config
        iterations = 0
        while True:
            gauss, its = _select_closures(self._b, self._graph, start, set())
            iterations += its
            active = self._b.active_closures()
            if not active:
                self._result = start
                return iterations, float(self._graph.error(start))
            for c in active:
                self._graph.replace(c.index, self._b.closure_factor(c, robust=True))
            self._result, its, error = _lm(self._graph, gauss, cfg)
            iterations += its
            worst = self._b.judge_closures(self._result)
            if worst is None:
                return iterations, error
            self._b.remove_closure(worst, "robust")
            for c in active:
                self._graph.remove(c.index)

    def _prune(self, values: gtsam.Values) -> int:
        """Remove prunable factors beyond ``prune_sigmas`` at ``values``; a removed Manhattan
        link is re-associated (frame and branch) against the solution when it then fits
        within the gate, so a wrong association costs no information. Returns the count."""
        cfg = self.config
        keep, n = [], 0
        frame_yaws = [self._b._yaw_of(values, i) for i in self._b.inst_of_frame]
        gate_max = math.radians(cfg.gate_max_deg)
        for idx in self._prunable:
            f = self._graph.at(idx)
            noise = f.noiseModel()
            base = noise.noise() if cfg.robust_kernel != "none" else noise
            if base.mahalanobisDistance(f.unwhitenedError(values)) <= cfg.prune_sigmas:
                keep.append(idx)
                continue
            self._graph.remove(idx)
            n += 1
            link = self._link_of.pop(idx, None)
            if link is None:
                self._pruned["relative"] += 1
                continue
            self._pruned["manhattan"] += 1
            theta = values.atPose2(X(link.pose)).theta()
            best = None
            for j, m in enumerate(frame_yaws):
                d = m - theta - link.measured
                b = round(d / (0.5 * math.pi))
                r = abs(math.remainder(d - b * 0.5 * math.pi, 2 * math.pi))
                if r <= gate_max and r <= cfg.gate_sigmas * link.sigma and (best is None or r < best[0]):
                    best = (r, j, link.measured + b * 0.5 * math.pi)
            if best is not None:
                _, j, measured = best
                new_idx = self._graph.size()
                self._graph.add(manhattan_factor(link.pose, self._b.inst_of_frame[j], measured, link.sigma,
                                                 kind=cfg.manhattan_factor, kernel=cfg.robust_kernel,
                                                 parameter=cfg.manhattan_robust_parameter))
                self._pruned["reassociated"] += 1
                keep.append(new_idx)
                self._link_of[new_idx] = type(link)(link.pose, j, measured, link.sigma)
        self._prunable = keep
        return n

    def _values(self) -> gtsam.Values:
        if self._result is None:
            self.optimize()
        return self._result

    def raw_poses(self) -> np.ndarray:
        """(N, 3) float64: the front-end steps chained from the origin (no back-end)."""
        return np.array(self._b.raw).reshape(-1, 3)

    def initial_poses(self) -> np.ndarray:
        """(N, 3) float64: the initial values (steps chained with the filtered Manhattan yaw)."""
        return np.array(self._b.guess).reshape(-1, 3)

    def marginal_covariances(self) -> np.ndarray:
        """(N, 3, 3) float64 marginal covariance of each pose at the optimum, in its Pose2
        tangent space (body frame, ``[x, y, theta]``); optimises first if needed."""
        values = self._values()
        marg = gtsam.Marginals(self._graph, values)
        return np.stack([marg.marginalCovariance(X(k)) for k in range(self._b.n)])

    def relative_covariance(self, i: int, j: int) -> np.ndarray:
        """(3, 3) float64 covariance of ``T_base_i_base_j`` (tangent ``[x, y, theta]`` at
        ``T_base_i_base_j``) at the last :meth:`optimize`, from the joint marginal of
        ``X(i), X(j)``; raises RuntimeError before any :meth:`optimize`."""
        return self.relative_covariances(i, [j])[0]

    def relative_covariances(self, i: int, js) -> np.ndarray:
        """(len(js), 3, 3) float64: :meth:`relative_covariance` of ``i`` to each of ``js``
        from one joint marginal (cheaper than one call per pair, e.g. for proximity search)."""
        if self._solved is None:
            raise RuntimeError("relative_covariance: the batch graph has no solution yet; call optimize() first")
        count, values, n = self._solved
        for j in js:
            _check_pair(i, j, n, "relative_covariance", "of the last solution")
        if self._joint is None:
            graph = gtsam.NonlinearFactorGraph()
            for k in range(count):
                if self._graph.at(k) is not None:
                    graph.add(self._graph.at(k))
            self._joint = gtsam.Marginals(graph, values)
        return _relative_covariances(self._joint.jointMarginalCovariance, values.atPose2, i, js)

    def manhattan_frames(self) -> list[tuple[int, float, int]]:
        """``(id, yaw_world, n_observations)`` per local Manhattan frame; ``yaw_world`` (rad)
        is the frame's heading in odom modulo 90 deg, in [-pi/4, pi/4), at the optimum if
        :meth:`optimize` ran, else from the association filter."""
        return self._b.frames_from(self._result)

    @property
    def stats(self) -> dict:
        """Graph sizes, association counts and, after a solve, iterations, time, errors and
        robust down-weighting (factors with IRLS weight < 0.5, by kind)."""
        s = self._b.stats()
        s.update(self._solve)
        if self._result is not None:
            s["downweighted"] = self._b.downweighted(self._result)
        return s

    @property
    def graph(self) -> gtsam.NonlinearFactorGraph:
        return self._graph

    @property
    def initial(self) -> gtsam.Values:
        return self._initial


class IncrementalPlanarPoseGraph:
    """Streaming planar pose graph on iSAM2: each :meth:`add_frame` hands iSAM2 only the
    new factors and values. Same factors and association as :class:`PlanarPoseGraph`."""

    def __init__(self, config: BackendConfig | None = None, *,
                 associator: ManhattanAssociator | None = None):
        self.config = config or BackendConfig()
        cfg = self.config
        params = gtsam.ISAM2Params()
        thr = gtsam.ISAM2ThresholdMap()
        th = math.radians(cfg.isam2_relinearize_theta_deg)
        thr.insert(("x", np.array([cfg.isam2_relinearize_xy, cfg.isam2_relinearize_xy, th])))
        # M(.): native instances are Pose2 with an unused (pinned) translation; Rot2 otherwise.
        thr.insert(("m", np.array([1.0, 1.0, th]) if cfg.manhattan_factor == "native" else np.array([th])))
        thr.insert(("w", np.array([cfg.isam2_relinearize_xy])))  # W(.): a wall's offset (m)
        params.setRelinearizeThreshold(thr)
        params.relinearizeSkip = cfg.isam2_relinearize_skip
        params.setFactorization(cfg.isam2_factorization)
        gn = gtsam.ISAM2GaussNewtonParams()
        gn.setWildfireThreshold(cfg.isam2_wildfire_threshold)
        params.setOptimizationParams(gn)
        self._isam = gtsam.ISAM2(params)
        self._b = _GraphBuilder(cfg, associator, hold_start_gap=False)
        self._b.instance_estimate = self._instance_estimate
        self._pending = gtsam.NonlinearFactorGraph()
        self._new_closures: list[_Closure] = []  # added, not yet handed to iSAM2
        self._time = 0.0
        self._updates = 0

    def __len__(self) -> int:
        return self._b.n

    def _instance_estimate(self, inst: int) -> float:
        if self.config.manhattan_factor == "native":
            return self._isam.calculateEstimatePose2(M(inst)).theta()
        return self._isam.calculateEstimateRot2(M(inst)).theta()

    def add_frame(self, result: FrameResult, odometry=None) -> int:
        """Add one frame (and its wheel odometry step, as in :meth:`PlanarPoseGraph.add_frame`)
        and update iSAM2 with its new factors and values; returns its index."""
        t0 = time.perf_counter()
        k = self._b.n
        prev = None
        if k > 0:
            p = self._isam.calculateEstimatePose2(X(k - 1))
            prev = np.array([p.x(), p.y(), p.theta()])
        graph, values, k = self._b.frame(result, prev, odometry)
        self._push(graph, values)
        if self._new_closures:
            self._timed_settle()
        self._time += time.perf_counter() - t0
        self._updates += 1
        return k

    def manhattan_links(self) -> list[ManhattanLink]:
        """As :meth:`PlanarPoseGraph.manhattan_links`."""
        return list(self._b.last_links)

    def add_relative(self, i: int, j: int, pose, information) -> None:
        """Queue an extra relative factor; it reaches iSAM2 with the next update."""
        p, info = self._b.check_relative(i, j, pose, information)
        self._pending.add(self._b.relative_factor(i, j, p, info, "relative"))

    def add_closure(self, i: int, j: int, pose, information, *, info: dict | None = None) -> int:
        """Loop closure, as :meth:`PlanarPoseGraph.add_closure`; returns its id.

        Queued: it reaches iSAM2 with the next :meth:`add_frame`, :meth:`update` or
        :meth:`estimate`, is judged there (worst first beyond ``closure_max_error_sigmas``,
        removed from iSAM2 if so) and its status in :meth:`closures` is then final for now.
        """
        c = self._b.new_closure(i, j, pose, information, info)
        self._new_closures.append(c)
        return c.id

    def closures(self) -> list[dict]:
        """As :meth:`PlanarPoseGraph.closures`; residuals at the last closure check (None for
        closures still queued)."""
        return self._b.closure_dicts()

    def solve_without_closures(self) -> np.ndarray:
        """(N, 3) float64 ``T_odom_base`` of iSAM2's factors without the loop closures, by
        batch Levenberg-Marquardt from the chained initial values (iSAM2 itself cannot
        un-learn them): for evaluate's side-by-side, not used by the run."""
        # A copy sharing the factors (a graph's clone() clones each factor, which a Python
        # CustomFactor -- wall offsets, the motion prior -- cannot do).
        closures = {c.index for c in self._b.closures if c.status == "active" and c.index is not None}
        graph = _gaussian_copy(self._isam.getFactorsUnsafe(), closures, gaussian=False)
        values = gtsam.Values(self._isam.getLinearizationPoint())
        for k, p in enumerate(self._b.guess):
            values.update(X(k), gtsam.Pose2(*map(float, p)))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.lm_max_iterations)
        return self._b.poses_from(gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize())

    def _push(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, *, force: bool = False) -> None:
        """One iSAM2 update with ``graph``, ``values`` and the queued relative factors."""
        if self._pending.size():
            graph.push_back(self._pending)
            self._pending = gtsam.NonlinearFactorGraph()
        self._isam.update(graph, values, force_relinearize=force)

    def _passes(self) -> None:
        """Relinearisation passes until no variable moves beyond the thresholds (at most
        ``closure_isam2_max_passes``)."""
        for _ in range(self.config.closure_isam2_max_passes):
            res = self._isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), force_relinearize=True)
            self._updates += 1
            if res.getVariablesRelinearized() == 0:
                break

    def _swap(self, add: list[_Closure], drop: list[_Closure], robust: bool) -> None:
        """One iSAM2 update that adds ``add`` (closure kernel if ``robust``, else Gaussian)
        and removes the factors of ``drop`` (by the indices iSAM2 gave them)."""
        g = gtsam.NonlinearFactorGraph()
        for c in add:
            g.add(self._b.closure_factor(c, robust))
        res = self._isam.update(g, gtsam.Values(), [c.index for c in drop])
        for c in drop:
            c.index = None
        for c, idx in zip(add, res.getNewFactorsIndices()):
            c.index, c.robust = int(idx), robust
        self._updates += 1

    def _timed_settle(self) -> None:
        t0 = time.perf_counter()
        self._settle_closures()
        self._b.closure_time += time.perf_counter() - t0

    def _settle_closures(self) -> None:
        """Judge the queued and active closures as the batch graph does: select them on an
        all-Gaussian copy of iSAM2's factors from its current estimate
        (:func:`_select_closures`); then in iSAM2 remove the rejected, add the accepted new
        ones Gaussian, converge, give them the closure kernel (at the drifted estimate a
        true closure's residual is tens of sigma, where that kernel would hardly pull),
        converge; if a residual is then beyond ``closure_max_error_sigmas``, remove the
        worst and start again. A new closure that already fits the estimate within
        ``closure_robust_parameter`` (kernel weight >= 0.5) goes in robust at once, without
        extra relinearisation passes.

        The selection (a Levenberg-Marquardt solve of the whole graph) is skipped when every
        queued closure fits: its residual, or else its innovation (:meth:`_innovation`), within
        the limit. A lone closure's residual after the selection's solve never exceeds its
        innovation, which never exceeds its residual now, so the selection would keep it
        (the check after the robust solve still runs)."""
        limit = self.config.closure_max_error_sigmas
        self._b.judge_closures(self._isam.calculateBestEstimate())
        select = limit > 0 and any(c.residual > limit and self._innovation(c) > limit for c in self._new_closures)
        while True:
            queued, self._new_closures = self._new_closures, []
            if select:
                in_isam = {c.index for c in self._b.active_closures() if c.index is not None}
                _select_closures(self._b, self._isam.getFactorsUnsafe(), self._isam.calculateBestEstimate(),
                                 in_isam)
                self._b.judge_closures(self._isam.calculateBestEstimate())
            gone = [c for c in self._b.closures if c.status == "removed" and c.index is not None]
            new = [c for c in queued if c.status == "active"]
            near = [c for c in new if c.residual <= self.config.closure_robust_parameter]
            far = [c for c in new if c not in near]
            if near:
                self._swap(near, [], robust=True)
            if gone or far:
                self._swap(far, gone, robust=False)
            if gone or far or not queued:
                # the estimate moves far (or this is a re-check): converge before judging;
                # closures that fit already are left to iSAM2's own relinearisation schedule
                self._passes()
            gauss = [c for c in self._b.active_closures() if not c.robust]
            if gauss:
                self._swap(gauss, gauss, robust=True)
                self._passes()
            worst = self._b.judge_closures(self._isam.calculateBestEstimate())
            if worst is None:
                return
            self._b.remove_closure(worst, "robust")
            select = True

    def update(self, iterations: int = 1) -> None:
        """Flush queued factors, then run ``iterations`` relinearisation passes that ignore
        ``isam2_relinearize_skip`` (variables still move only if their delta exceeds the
        thresholds); no new information is added. Then, when the graph has closures, they
        are judged again (:meth:`_settle_closures`)."""
        t0 = time.perf_counter()
        for _ in range(iterations):
            self._push(gtsam.NonlinearFactorGraph(), gtsam.Values(), force=True)
        if self._new_closures or self._b.active_closures():
            self._timed_settle()
        self._time += time.perf_counter() - t0
        self._updates += iterations

    def estimate(self, flush: bool = True) -> np.ndarray:
        """(N, 3) float64 current iSAM2 estimate of ``T_odom_base`` per frame.

        ``flush``: first run one :meth:`update` pass (queued factors, and the relinearisation
        the skip interval may have deferred for the newest frames) with every closure ever
        added judged afresh (removed ones included, as :meth:`PlanarPoseGraph.optimize`
        does); then a full back-substitution (not limited by the wildfire threshold).
        """
        if self._b.n == 0:
            return np.zeros((0, 3))
        if flush and self._b.closures:
            # every closure ever added judged afresh, as the batch graph does: a closure
            # removed when it was alone may fit now that later ones share its pull
            self._new_closures += self._b.reinstate_closures()
        if flush:
            self._pending.push_back(self._b.flush())
        if flush or self._pending.size() or self._new_closures:
            self.update()
        return self._b.poses_from(self._isam.calculateBestEstimate())

    def latest(self) -> np.ndarray:
        """(3,) float64 current estimate of the newest pose (cheap: no full back-substitution)."""
        p = self._isam.calculateEstimatePose2(X(self._b.n - 1))
        return np.array([p.x(), p.y(), p.theta()])

    def raw_poses(self) -> np.ndarray:
        """(N, 3) float64: the front-end steps chained from the origin."""
        return np.array(self._b.raw).reshape(-1, 3)

    def marginal_covariances(self) -> np.ndarray:
        """(N, 3, 3) float64 iSAM2 marginal covariances (Pose2 tangent space, body frame)."""
        if self._pending.size() or self._new_closures:
            self.update()
        return np.stack([self._isam.marginalCovariance(X(k)) for k in range(self._b.n)])

    def relative_covariance(self, i: int, j: int) -> np.ndarray:
        """(3, 3) float64 covariance of ``T_base_i_base_j`` at the current estimate, from
        iSAM2's joint marginal of ``X(i), X(j)`` (queued factors are flushed first)."""
        return self.relative_covariances(i, [j])[0]

    def relative_covariances(self, i: int, js) -> np.ndarray:
        """(len(js), 3, 3) float64: :meth:`relative_covariance` of ``i`` to each of ``js``
        from one joint marginal (one call for many candidates costs far less than one per pair)."""
        for j in js:
            _check_pair(i, j, self._b.n, "relative_covariance", "of the graph")
        if self._pending.size() or self._new_closures:
            self.update()
        return self._relative_covariances(i, js)

    def _relative_covariances(self, i: int, js) -> np.ndarray:
        return _relative_covariances(self._isam.jointMarginalCovariance, self._isam.calculateEstimatePose2, i, js)

    def _innovation(self, c: _Closure) -> float:
        """Mahalanobis distance of closure ``c``'s residual at the current estimate against
        its own covariance plus the estimate's covariance of ``T_base_i_base_j``."""
        between = self._isam.calculateEstimatePose2(X(c.i)).between(self._isam.calculateEstimatePose2(X(c.j)))
        r = gtsam.Pose2.Logmap(gtsam.Pose2(*c.pose).between(between))
        cov = self._relative_covariances(c.i, [c.j])[0] + np.linalg.inv(c.information)
        return float(math.sqrt(max(float(r @ np.linalg.solve(cov, r)), 0.0)))

    def manhattan_frames(self) -> list[tuple[int, float, int]]:
        """``(id, yaw_world, n_observations)`` per local frame at the current estimate."""
        return self._b.frames_from(self._isam.calculateEstimate() if self._b.n else None)

    @property
    def stats(self) -> dict:
        s = self._b.stats()
        s.update({"updates": self._updates, "time_s": self._time,
                  "time_per_update_s": self._time / max(self._updates, 1)})
        return s

    def downweighted(self) -> dict[str, int]:
        """Robust factors with IRLS weight < 0.5 at the current estimate, by kind."""
        return self._b.downweighted(self._isam.calculateEstimate())
