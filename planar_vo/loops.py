"""Loop closure during a run: keyframes, candidates, verification, closure factors.

The pipeline offers every processed frame to :class:`LoopCloser`. It keeps a keyframe
each time the robot has travelled ``keyframe_distance_m`` or turned ``keyframe_angle_deg``
since the last one (:func:`planar_vo.frontend.places.make_keyframe`: ORB corners lifted to
3-D in the levelled frame, the frame's Manhattan observations; no image is kept). For
each new keyframe two sources name candidate earlier keyframes:

* **appearance**: the place-recognition index (:class:`planar_vo.frontend.places.PlaceIndex`);
* **proximity**: earlier keyframes the robot may be near, given the odometry chain's pose
  and its uncertainty (as RTAB-Map's proximity detection does with the graph): the
  chain's relative pose ``T_base_a_base_now`` and its covariance, composed step by step
  from the front-end's stated step covariances. The chain ignores the graph's other
  constraints, so this gate is wider (more conservative) than the graph's marginals.

Keyframes closer than ``recent_path_m`` of travelled path are never candidates (they
are the same stretch of corridor, seen moments ago). Each candidate is verified with the
paper's estimators (:func:`planar_vo.frontend.places.verify_closure`) with the odometry's
prediction as its prior (a look-alike place elsewhere is rejected there): the chain with
measured steps' sigmas scaled, guessed steps' at their own bounds
(:func:`step_prior_covariance`), and the headings held by the Manhattan frames linked at
the keyframes (:class:`_HeldChain`). A verified closure must also agree with the latest
closure accepted a short drive back (:meth:`LoopCloser._consistency`). An accepted one
becomes a robust closure factor in the graph, which removes closures that the solution
does not support. A keyframe that closed a loop is not kept (``forget_closed``). Every
candidate is listed in the report with its verdict and reason.
"""
from __future__ import annotations

import functools
import math
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import gtsam
import numpy as np

from planar_vo.config import LoopConfig
from planar_vo.core.geometry import largest_sigma, se2_compose, se2_inverse, wrap_angle
from planar_vo.core.steps import STATUS_BRIDGED, STATUS_PARTIAL
from planar_vo.core.types import CameraIntrinsics
from planar_vo.frontend.config import FrontendConfig, PlaceConfig
from planar_vo.frontend.places import (OUT_OF_VIEW, Keyframe, PlaceIndex, make_keyframe, prior_distance,
                                      verify_closure)


def compose_covariance(cov_ab: np.ndarray, T_bc, cov_bc: np.ndarray) -> np.ndarray:
    """(..., 3, 3) covariance of ``T_ac = T_ab * T_bc`` in gtsam.Pose2's tangent convention
    (right perturbation, ``[x, y, theta]``), given the two parts' covariances (independent).

    ``cov_ab``: (..., 3, 3); ``T_bc``: (3,) pose; ``cov_bc``: (3, 3). First order:
    ``Ad(T_bc^-1) cov_ab Ad(T_bc^-1)^T + cov_bc``.
    """
    A = gtsam.Pose2(*map(float, T_bc)).inverse().AdjointMap()
    return A @ cov_ab @ A.T + cov_bc


@dataclass
class _Chain:
    """The odometry chain since the run start: path length, and per keyframe the relative
    pose and covariance keyframe -> now (composed incrementally)."""

    path_m: float = 0.0
    seg_pose: np.ndarray = field(default_factory=lambda: np.zeros(3))   # last keyframe -> now
    seg_cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    kf_rel: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))       # (K, 3) keyframe -> last keyframe
    kf_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))    # (K, 3, 3)
    kf_path: list = field(default_factory=list)
    #: the same covariances with each step's covariance weighted for the verification prior
    #: (:meth:`step`'s ``prior_cov``)
    seg_prior: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    kf_prior: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    #: per keyframe, the segment from the previous one: (pose (3,), prior covariance (3, 3))
    kf_seg: list = field(default_factory=list)

    def step(self, pose: np.ndarray, cov: np.ndarray, prior_cov: np.ndarray | None = None) -> None:
        """One step ``pose`` (3,) with (3, 3) ``cov``; ``prior_cov``: the covariance it
        contributes to the verification prior (default ``cov``)."""
        self.path_m += float(math.hypot(pose[0], pose[1]))
        self.seg_cov = compose_covariance(self.seg_cov, pose, cov)
        self.seg_prior = compose_covariance(self.seg_prior, pose, cov if prior_cov is None else prior_cov)
        self.seg_pose = se2_compose(self.seg_pose, pose)

    def relative_to_now(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K, 3)`` poses ``T_base_kf_base_now`` and their ``(K, 3, 3)`` covariances."""
        if not len(self.kf_rel):
            return self.kf_rel, self.kf_cov
        rel = np.array([se2_compose(r, self.seg_pose) for r in self.kf_rel])
        return rel, compose_covariance(self.kf_cov, self.seg_pose, self.seg_cov)

    def prior_to_now(self) -> np.ndarray:
        """``(K, 3, 3)`` the verification prior's covariances of :meth:`relative_to_now`'s poses."""
        if not len(self.kf_prior):
            return self.kf_prior
        return compose_covariance(self.kf_prior, self.seg_pose, self.seg_prior)

    def between(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """``T_kf_i_kf_j`` (3,) and its prior covariance (3, 3) along the chain, keyframe
        positions ``i``, ``j`` (the segments between them composed; inverted when ``j < i``)."""
        lo, hi = min(i, j), max(i, j)
        pose, cov = np.zeros(3), np.zeros((3, 3))
        for seg_pose, seg_cov in self.kf_seg[lo + 1:hi + 1]:
            cov = compose_covariance(cov, seg_pose, seg_cov)
            pose = se2_compose(pose, seg_pose)
        if j >= i:
            return pose, cov
        A = gtsam.Pose2(*map(float, pose)).AdjointMap()   # covariance of the inverse
        return se2_inverse(pose), A @ cov @ A.T

    def new_keyframe(self, rel: np.ndarray, cov: np.ndarray, prior: np.ndarray | None = None) -> None:
        """The current frame becomes a keyframe: every earlier keyframe's relative pose and
        covariances become ``rel``, ``cov`` (:meth:`relative_to_now`) and ``prior``
        (:meth:`prior_to_now`, default ``cov``), and the segment restarts."""
        self.kf_rel = np.vstack([rel, np.zeros((1, 3))])
        self.kf_cov = np.concatenate([cov, np.zeros((1, 3, 3))])
        self.kf_prior = np.concatenate([cov if prior is None else prior, np.zeros((1, 3, 3))])
        self.kf_path.append(self.path_m)
        self.kf_seg.append((self.seg_pose, self.seg_prior))
        self.seg_pose, self.seg_cov, self.seg_prior = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))


#: Verdict reason of a closure that disagrees with the latest closure accepted a short drive back.
INCONSISTENT = "inconsistent"
#: Closures whose earlier keyframes are further apart than this many keyframes are not
#: compared (the chain between them costs a composition per keyframe; 100 = 50 m of path).
CONSISTENCY_MAX_KEYFRAMES = 100

#: A keyframe's Manhattan link whose innovation is beyond this many sigmas is not used by
#: :class:`_HeldChain` (the graph's robust kernel and pruning deal with such links there).
HELD_GATE_SIGMAS = 5.0


def _compose_many(T: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(K, 3) ``T_k * d_k`` for SE(2) poses ``T`` (K, 3) and ``d`` (K, 3) or (3,)."""
    c, s = np.cos(T[:, 2]), np.sin(T[:, 2])
    d = np.broadcast_to(d, T.shape)
    return np.column_stack([T[:, 0] + c * d[:, 0] - s * d[:, 1], T[:, 1] + s * d[:, 0] + c * d[:, 1],
                            wrap_angle(T[:, 2] + d[:, 2])])


class _HeldChain:
    """Per earlier keyframe ``a``, the relative pose ``T_base_a_base_now`` and its covariance
    with the headings held by the Manhattan frames the graph linked at the keyframes: an
    error-state Kalman filter per keyframe over ``[pose error (3, right perturbation, as
    gtsam.Pose2), phi_j errors]``, ``phi_j = m_j - theta_a`` the heading of local frame ``j``
    in ``a``'s frame. Predicted by the chain's segments, updated at every keyframe by its
    links ``measured = m_j - theta_k`` (Sec. 2.1's drift-free rotation: two keyframes that
    see the same walls know their relative heading to the walls' sigmas, whatever the path
    between). The chain alone lets the heading sigma grow along the path, and the
    translation sigma with path length times it; this is the marginal a keyframe-only
    graph with Manhattan factors would give for the pair (using only what lies between them).
    All keyframes at once: (K, 3 + J) arrays, J local frames seen."""

    def __init__(self) -> None:
        self.pose = np.zeros((0, 3))         # (K, 3) T_a_lastkf
        self.phi = np.zeros((0, 0))          # (K, J) rad, NaN where a has not met frame j yet
        self.P = np.zeros((0, 3, 3))         # (K, 3 + J, 3 + J)

    def _grow(self, j: int) -> None:
        J = self.phi.shape[1]
        if j < J:
            return
        K, n = len(self.pose), j + 1 - J
        self.phi = np.hstack([self.phi, np.full((K, n), np.nan)])
        self.P = np.pad(self.P, ((0, 0), (0, n), (0, n)))

    def predict(self, seg_pose: np.ndarray, seg_cov: np.ndarray) -> None:
        """Every keyframe's relative pose moves on by the segment ``seg_pose`` (3,) with (3, 3) ``seg_cov``."""
        if not len(self.pose):
            return
        A = gtsam.Pose2(*map(float, seg_pose)).inverse().AdjointMap()
        self.pose = _compose_many(self.pose, seg_pose)
        P = self.P
        P[:, :3, :] = np.einsum("ij,kjl->kil", A, P[:, :3, :])
        P[:, :, :3] = np.einsum("kli,ji->klj", P[:, :, :3], A)
        P[:, :3, :3] += seg_cov

    def observe(self, j: int, measured: float, sigma: float) -> None:
        """A link of the newest keyframe to local frame ``j``: ``m_j - theta_now = measured`` (rad), std ``sigma``."""
        self._grow(j)
        if not len(self.pose):
            return
        P, f = self.P, 3 + j
        new = np.isnan(self.phi[:, j])
        # first sight of frame j from keyframe a: it enters the state (phi_j = theta + measured)
        self.phi[new, j] = self.pose[new, 2] + measured
        P[new, f, :] = P[new, 2, :]
        P[new, :, f] = P[new, :, 2]
        P[new, f, f] = P[new, 2, 2] + sigma * sigma
        old = np.flatnonzero(~new)
        Ph = P[old, :, f] - P[old, :, 2]                       # (M, D): P h, h = e_phi_j - e_theta
        S = Ph[:, f] - Ph[:, 2] + sigma * sigma
        nu = wrap_angle(measured - (self.phi[old, j] - self.pose[old, 2]))
        ok = nu * nu <= HELD_GATE_SIGMAS ** 2 * S
        old, Ph, S, nu = old[ok], Ph[ok], S[ok], nu[ok]
        G = Ph / S[:, None]
        dx = G * nu[:, None]
        self.pose[old] = _compose_many(self.pose[old], dx[:, :3])
        self.phi[old] = self.phi[old] + np.where(np.isnan(self.phi[old]), 0.0, dx[:, 3:])
        P[old] -= G[:, :, None] * Ph[:, None, :]

    def new_keyframe(self, links: list) -> None:
        """Append the newest keyframe (relative pose zero) with its own links ``(j, measured, sigma)``."""
        for j, _, _ in links:
            self._grow(j)
        D = 3 + self.phi.shape[1]
        P = np.zeros((1, D, D))
        phi = np.full((1, self.phi.shape[1]), np.nan)
        for j, measured, sigma in links:
            phi[0, j], P[0, 3 + j, 3 + j] = measured, sigma * sigma
        self.pose = np.vstack([self.pose, np.zeros((1, 3))])
        self.phi = np.vstack([self.phi, phi])
        self.P = np.concatenate([self.P, P])


@dataclass
class Candidate:
    """One candidate pair (earlier keyframe ``a``, new keyframe ``b``) and its verdict."""

    a: int                 # frame index of the earlier keyframe
    b: int                 # frame index of the new keyframe
    source: str            # "appearance", "proximity" or "both"
    score: float | None = None         # appearance score
    mahalanobis: float | None = None   # proximity: squared distance of the gate
    odometry_d2: float | None = None   # verified pose against the chain: squared Mahalanobis distance
    verdict: str = ""      # "accepted", "rejected", later "removed" by the graph
    reason: str = ""
    matches: int = 0
    inliers: int = 0
    spread_m: float = 0.0
    pose: list | None = None           # T_base_a_base_b (x, y, theta) when verified
    sigma: list | None = None
    closure_id: int | None = None
    verify_ms: float = 0.0
    prior_sigma_m: float | None = None  # the odometry prior's largest translation sigma (scaled)
    chain_sigma_m: float | None = None  # the same for the chain alone (without the Manhattan frames)
    consistency_d2: float | None = None  # against the latest nearby closure (LoopCloser._consistency)


class LoopCloser:
    """Keyframes, candidates and verification for one run; accepted closures go to ``graph``
    (:meth:`add_closure` of either pose graph).

    ``intrinsics``: the colour camera; ``T_base_cam``: (4, 4) mount; ``seed``: verification's
    RANSAC seed (each pair gets ``seed + pair number``, so a run is reproducible);
    ``frontend``: the run's front-end settings (depth range, corner lifting);
    ``background``: keyframes are made and verified on a worker thread (:meth:`offer`;
    call :meth:`flush` before solving the graph).
    """

    def __init__(self, intrinsics: CameraIntrinsics, T_base_cam: np.ndarray, config: LoopConfig,
                 places: PlaceConfig, graph, seed: int = 0, frontend: FrontendConfig | None = None,
                 background: bool = False):
        self.intrinsics, self.T_base_cam = intrinsics, np.asarray(T_base_cam, dtype=float)
        # keyframe points are lifted as the odometry lifts its corners (same depth range and filter)
        fe = frontend or FrontendConfig()
        self._lift = {"feature_config": fe.features, "depth_range": (fe.min_depth, fe.max_depth)}
        self.config, self.places, self.graph, self.seed = config, places, graph, seed
        self.index = PlaceIndex(places)
        #: every keyframe in order; None where the keyframe was not kept (``forget_closed``)
        self.keyframes: list[Keyframe | None] = []
        self.keyframe_frames: list[int] = []      # pose index of every keyframe
        self._indexed: list[int] = []             # PlaceIndex position -> keyframe position
        self.candidates: list[Candidate] = []
        self._chain = _Chain()
        self._held = _HeldChain() if config.prior_heading == "manhattan" else None
        #: accepted closures in order: (keyframe position a, keyframe position b, pose (3,), covariance (3, 3))
        self._closed: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        self._now: tuple = ()     # the new keyframe's chain poses and prior covariances while it is verified
        self.time_s: dict[str, float] = {"keyframes": 0.0, "candidates": 0.0, "verify": 0.0}
        #: CPU seconds of the keyframe work done on the background thread (``background``)
        self.background_cpu_s = 0.0
        self._background = background
        self._pending: Future | None = None
        self._to_add: list[tuple[Candidate, tuple]] = []  # closures verified, not yet in the graph

    def offer(self, frame, result, R_lev_cam: np.ndarray) -> None:
        """The pipeline's frame ``frame`` (RGBDFrame) with its front-end ``result``, after the
        graph has added it (the graph's pose index is ``result``'s order in the run).

        With ``background``, a due keyframe is made, matched and verified on a worker
        thread while the caller goes on to the next frame (ORB releases the interpreter
        lock); its closures reach the graph at the next :meth:`offer` or :meth:`flush`,
        in the same order, so the batch solution is the one the synchronous closer gives
        (the factors are appended one frame later)."""
        self.flush()
        if result.step is not None:
            cov = _covariance(result.step.information)
            self._chain.step(np.asarray(result.step.pose, float), cov,
                             step_prior_covariance(cov, result.step.status, self.config))
        if self.keyframe_frames and not self._keyframe_due():
            return
        # what the keyframe reads of the graph, read here: the caller adds the next frame to
        # the graph while the worker runs
        index, graph_links = len(self.graph) - 1, self.graph.manhattan_links() if self._held is not None else []
        if not self._background:
            self._keyframe(frame, result, R_lev_cam, index, graph_links)
            self._add_verified()
            return
        self._pending = _worker().submit(self._timed_keyframe, frame, result, R_lev_cam, index, graph_links)

    def flush(self) -> None:
        """Finish the keyframe the worker is on, if any, and add its closures to the graph
        (a worker's error is raised here)."""
        if self._pending is not None:
            error = self._pending.exception()  # waits; an interrupt here leaves the job pending
            self._pending = None
            if error is not None:
                raise error
        self._add_verified()

    def _timed_keyframe(self, *args) -> None:
        c0 = time.thread_time()
        try:
            self._keyframe(*args)
        finally:
            self.background_cpu_s += time.thread_time() - c0

    def _add_verified(self) -> None:
        for cand, (a, b, pose, information) in self._to_add:
            cand.closure_id = self.graph.add_closure(a, b, pose, information,
                                                     info={"inliers": cand.inliers, "source": cand.source})
        self._to_add.clear()

    def _keyframe(self, frame, result, R_lev_cam: np.ndarray, index: int, graph_links: list) -> None:
        """Make the frame a keyframe (pose ``index``), name and verify its candidates."""
        t0 = time.perf_counter()
        gray = cv2.cvtColor(frame.color, cv2.COLOR_BGR2GRAY) if frame.color.ndim == 3 else frame.color
        kf = make_keyframe(index, frame.stamp, gray, frame.depth.astype(np.float32, copy=False),
                           self.intrinsics, R_lev_cam, result.manhattan, self.places, **self._lift)
        t1 = time.perf_counter()
        self.time_s["keyframes"] += t1 - t0
        rel, cov = self._chain.relative_to_now()  # every keyframe -> now, once per keyframe
        prior_cov = self._chain.prior_to_now()
        links = self._held_update(kf.index, graph_links)
        found = self._candidates(kf, rel, cov)
        t2 = time.perf_counter()
        self.time_s["candidates"] += t2 - t1
        self._now = (rel, prior_cov)
        for pos, cand in found:
            prior = ((rel[pos], prior_cov[pos]) if self._held is None
                     else (self._held.pose[pos], self._held.P[pos, :3, :3]))
            self._verify(self.keyframes[pos], kf, cand, prior, chain_cov=cov[pos], pos=pos)
        self.time_s["verify"] += time.perf_counter() - t2
        self._chain.new_keyframe(rel, cov, prior_cov)
        if self._held is not None:
            self._held.new_keyframe(links)
        self.keyframe_frames.append(kf.index)
        if self.config.forget_closed and any(c.verdict == "accepted" for _, c in found):
            self.keyframes.append(None)  # the place is known: its older keyframe stands for it
            return
        self.keyframes.append(kf)
        self._indexed.append(len(self.keyframes) - 1)
        self.index.add(kf)

    def _held_update(self, index: int, graph_links: list) -> list[tuple[int, float, float]]:
        """Move the Manhattan-held relative poses to the new keyframe (pose ``index``) and
        update them with its links (of ``graph_links``, the graph's last ``manhattan_links``);
        returns the links ``(frame, measured, sigma)``."""
        if self._held is None:
            return []
        links = [(int(lk.frame), float(lk.measured), float(lk.sigma)) for lk in graph_links
                 if lk.pose == index]
        self._held.predict(self._chain.seg_pose, self._chain.seg_prior)
        # the walls' sigmas are stated by a fit, as the measured steps': scaled alike
        links = [(j, m, self.config.odometry_sigma_scale * s) for j, m, s in links]
        for j, measured, sigma in links:
            self._held.observe(j, measured, sigma)
        return links

    def _keyframe_due(self) -> bool:
        c, ch = self.config, self._chain
        return (math.hypot(ch.seg_pose[0], ch.seg_pose[1]) >= c.keyframe_distance_m
                or abs(float(wrap_angle(ch.seg_pose[2]))) >= math.radians(c.keyframe_angle_deg))

    def _candidates(self, kf: Keyframe, rel: np.ndarray, cov: np.ndarray) -> list[tuple[int, Candidate]]:
        """Earlier keyframes (positions in :attr:`keyframes`) named by appearance or by
        proximity, at least ``recent_path_m`` of path back; one :class:`Candidate` each.
        ``rel``, ``cov``: :meth:`_Chain.relative_to_now`."""
        c, ch = self.config, self._chain
        eligible = int(np.searchsorted(ch.kf_path, ch.path_m - c.recent_path_m, side="right"))
        if eligible == 0:
            return []
        found: dict[int, Candidate] = {}
        if c.appearance_candidates:
            max_index = self.keyframe_frames[eligible - 1]
            for ipos, score in self.index.query(kf, max_index, c.appearance_candidates):
                pos = self._indexed[ipos]
                found[pos] = Candidate(self.keyframes[pos].index, kf.index, "appearance", score=float(score))
        for pos, d2 in self._near(rel[:eligible], cov[:eligible]):
            cand = found.get(pos)
            if cand is None:
                found[pos] = Candidate(self.keyframes[pos].index, kf.index, "proximity", mahalanobis=d2)
            else:
                cand.source, cand.mahalanobis = "both", d2
        self.candidates.extend(found.values())
        return sorted(found.items())

    def _near(self, rel: np.ndarray, cov: np.ndarray) -> list[tuple[int, float]]:
        """Up to ``proximity_candidates`` of the eligible keyframes (``rel`` (K, 3), ``cov``
        (K, 3, 3): their chain poses and covariances to now) whose place the chain says the
        robot may be at now: ``(position, squared Mahalanobis distance)``."""
        c = self.config
        if not c.proximity_candidates:
            return []
        S = cov[:, :2, :2] + c.view_radius_m ** 2 * np.eye(2)
        t = rel[:, :2]
        d2 = np.einsum("ki,ki->k", t, np.linalg.solve(S, t[..., None])[..., 0])
        turn_ok = np.abs(wrap_angle(rel[:, 2])) <= (math.radians(c.view_angle_deg)
                                                    + 3.0 * np.sqrt(np.maximum(cov[:, 2, 2], 0.0)))
        kept = np.array([kf is not None for kf in self.keyframes[:len(rel)]], dtype=bool)
        ok = np.flatnonzero((d2 <= c.proximity_chi2) & turn_ok & kept)
        best = ok[np.argsort(d2[ok])[:c.proximity_candidates]]
        return [(int(k), float(d2[k])) for k in best]

    def _consistency(self, pa: int, pose: np.ndarray, cov: np.ndarray) -> float | None:
        """Squared Mahalanobis distance of a verified closure ``T_a_now`` (``pose`` (3,), ``cov``
        (3, 3); ``a`` at keyframe position ``pa``) from its prediction through the latest
        closure ``(a', b')`` accepted within ``consistency_path_m`` of path back: ``T_a_a'``
        (chain, first pass) * ``T_a'_b'`` (that closure) * ``T_b'_now`` (chain). Two closures
        a short drive apart must agree, as ORB-SLAM's consistency groups ask, but metrically:
        on low texture the chain's guessed steps leave the odometry prior metres wide, and a
        look-alike place a texture period away passed it. None without such a closure."""
        c, ch = self.config, self._chain
        if not c.consistency_path_m:
            return None
        rel, prior = self._now
        for qa, qb, zpose, zcov in reversed(self._closed):
            now = qb >= len(rel)   # a closure of the same new keyframe
            if not now and ch.path_m - ch.kf_path[qb] > c.consistency_path_m:
                return None
            if abs(qa - pa) > CONSISTENCY_MAX_KEYFRAMES:
                continue
            T_aa, C_aa = ch.between(pa, qa)
            T_bn, C_bn = (np.zeros(3), np.zeros((3, 3))) if now else (rel[qb], prior[qb])
            pred = se2_compose(se2_compose(T_aa, zpose), T_bn)
            C = compose_covariance(compose_covariance(C_aa, zpose, zcov), T_bn, C_bn)
            return prior_distance(pose, cov, (pred, C))
        return None

    def _verify(self, a: Keyframe, b: Keyframe, cand: Candidate, odometry_prior, chain_cov, pos: int) -> None:
        """Verify one pair; an accepted pair becomes a closure factor in the graph. The
        odometry's relative pose and covariance ``odometry_prior`` ((3,), (3, 3): the chain's,
        or held by the Manhattan frames, ``prior_heading``; measured steps' sigmas scaled by
        ``odometry_sigma_scale``, guessed ones' by ``guessed_sigma_scale``) is the
        verification's prior: a place that
        looks the same somewhere else (repeated doors and posters) is ``prior_mismatch``,
        which a redescending graph kernel could not always tell (the chain's robust steps
        give way instead of the closure)."""
        t0 = time.perf_counter()
        prior = odometry_prior
        check = verify_closure(a, b, self.T_base_cam, self.places, seed=self.seed + len(self.candidates),
                               prior=prior)
        cand.verify_ms = 1000.0 * (time.perf_counter() - t0)
        cand.matches, cand.inliers, cand.spread_m = int(check.matches), int(check.inliers), float(check.spread_m)
        cand.verdict, cand.reason = ("accepted" if check.accepted else "rejected"), check.reason
        cand.odometry_d2 = check.prior_d2
        cand.prior_sigma_m = largest_sigma(prior[1][:2, :2])
        cand.chain_sigma_m = self.config.odometry_sigma_scale * largest_sigma(chain_cov[:2, :2])
        if check.pose is not None:
            cand.pose = [float(v) for v in check.pose]
        if not check.accepted:
            return
        cand.consistency_d2 = self._consistency(pos, check.pose, check.covariance)
        if cand.consistency_d2 is not None and cand.consistency_d2 > self.places.prior_gate_chi2:
            cand.verdict, cand.reason = "rejected", INCONSISTENT
            return
        self._closed.append((pos, len(self.keyframe_frames), np.asarray(check.pose, float), check.covariance))
        cand.sigma = [float(v) for v in np.sqrt(np.diag(_covariance(check.information)))]
        self._to_add.append((cand, (a.index, b.index, check.pose, check.information)))

    def report(self) -> dict:
        """The ``loop_closure`` section of ``report.json`` (call after the graph is solved:
        closures the graph removed are marked ``removed`` with its reason)."""
        self.flush()
        removed = {}
        if hasattr(self.graph, "closures"):
            removed = {c["id"]: c.get("reason") for c in self.graph.closures() if c.get("status") == "removed"}
        for cand in self.candidates:
            if cand.closure_id in removed:
                cand.verdict, cand.reason = "removed", removed[cand.closure_id] or "residual"
        verdicts: dict[str, int] = {}
        reasons: dict[str, int] = {}
        for cand in self.candidates:
            verdicts[cand.verdict] = verdicts.get(cand.verdict, 0) + 1
            if cand.verdict != "accepted":
                reasons[cand.reason] = reasons.get(cand.reason, 0) + 1
        return {"keyframes": len(self.keyframe_frames), "keyframes_kept": len(self._indexed),
                "keyframe_memory_mb": round(sum(kf.nbytes for kf in self.keyframes if kf is not None) / 2 ** 20
                                            + self.index.nbytes / 2 ** 20, 2),
                "keyframe_frames": list(self.keyframe_frames),
                "candidates": len(self.candidates),
                "by_source": _count(c.source for c in self.candidates),
                # the candidates matched and checked: not those the prior put out of view
                "verified": sum(c.reason != OUT_OF_VIEW for c in self.candidates),
                "accepted": verdicts.get("accepted", 0),
                "rejected": verdicts.get("rejected", 0), "removed_by_graph": verdicts.get("removed", 0),
                "not_accepted_by_reason": reasons,
                "time_s": {k: round(v, 4) for k, v in self.time_s.items()},
                "list": [vars(c) for c in self.candidates]}

    def accepted(self) -> list[tuple[int, int]]:
        """``(a, b)`` pose indices of the closures in the final solution."""
        self.flush()
        return [(c.a, c.b) for c in self.candidates if c.verdict == "accepted"]


def step_prior_covariance(cov: np.ndarray, status: str, config: LoopConfig) -> np.ndarray:
    """(3, 3) what a step with stated covariance ``cov`` (3, 3) and front-end ``status``
    contributes to the verification prior: measured steps (dpp, 2pt) scaled by
    ``odometry_sigma_scale`` (a fit's sigmas can be optimistic), guessed ones (partial,
    bridged) by ``guessed_sigma_scale`` (their sigmas are bounds already)."""
    guessed = status in (STATUS_PARTIAL, STATUS_BRIDGED)
    return (config.guessed_sigma_scale if guessed else config.odometry_sigma_scale) ** 2 * cov


def _count(items) -> dict[str, int]:
    out: dict[str, int] = {}
    for k in items:
        out[k] = out.get(k, 0) + 1
    return out


@functools.lru_cache(maxsize=1)
def _worker() -> ThreadPoolExecutor:
    """The one thread keyframes are made on (:meth:`LoopCloser.offer` with ``background``;
    a closer waits for its job before the next, so one thread serves every run)."""
    return ThreadPoolExecutor(1, thread_name_prefix="planar-vo-keyframes")


def _covariance(information: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of a (3, 3) information matrix (pseudo-inverse: bridged steps may
    carry zero information in a direction)."""
    return np.linalg.pinv(np.asarray(information, dtype=float))
