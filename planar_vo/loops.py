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
paper's estimators (:func:`planar_vo.frontend.places.verify_closure`) with the chain's
prediction as its prior (a look-alike place elsewhere is rejected there); an accepted one
becomes a robust closure factor in the graph, which removes closures that the solution
does not support. A keyframe that closed a loop is not kept (``forget_closed``). Every
candidate is listed in the report with its verdict and reason.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import gtsam
import numpy as np

from planar_vo.config import LoopConfig
from planar_vo.core.geometry import largest_sigma, se2_compose, wrap_angle
from planar_vo.core.types import CameraIntrinsics
from planar_vo.frontend.config import FrontendConfig, PlaceConfig
from planar_vo.frontend.places import Keyframe, PlaceIndex, make_keyframe, verify_closure


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

    def step(self, pose: np.ndarray, cov: np.ndarray) -> None:
        self.path_m += float(math.hypot(pose[0], pose[1]))
        self.seg_cov = compose_covariance(self.seg_cov, pose, cov)
        self.seg_pose = se2_compose(self.seg_pose, pose)

    def relative_to_now(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K, 3)`` poses ``T_base_kf_base_now`` and their ``(K, 3, 3)`` covariances."""
        if not len(self.kf_rel):
            return self.kf_rel, self.kf_cov
        rel = np.array([se2_compose(r, self.seg_pose) for r in self.kf_rel])
        return rel, compose_covariance(self.kf_cov, self.seg_pose, self.seg_cov)

    def new_keyframe(self, rel: np.ndarray, cov: np.ndarray) -> None:
        """The current frame becomes a keyframe: every earlier keyframe's relative pose and
        covariance become ``rel``, ``cov`` (:meth:`relative_to_now`), and the segment restarts."""
        self.kf_rel = np.vstack([rel, np.zeros((1, 3))])
        self.kf_cov = np.concatenate([cov, np.zeros((1, 3, 3))])
        self.kf_path.append(self.path_m)
        self.seg_pose, self.seg_cov = np.zeros(3), np.zeros((3, 3))


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


class LoopCloser:
    """Keyframes, candidates and verification for one run; accepted closures go to ``graph``
    (:meth:`add_closure` of either pose graph).

    ``intrinsics``: the colour camera; ``T_base_cam``: (4, 4) mount; ``seed``: verification's
    RANSAC seed (each pair gets ``seed + pair number``, so a run is reproducible);
    ``frontend``: the run's front-end settings (depth range, corner lifting).
    """

    def __init__(self, intrinsics: CameraIntrinsics, T_base_cam: np.ndarray, config: LoopConfig,
                 places: PlaceConfig, graph, seed: int = 0, frontend: FrontendConfig | None = None):
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
        self.time_s: dict[str, float] = {"keyframes": 0.0, "candidates": 0.0, "verify": 0.0}

    def offer(self, frame, result, R_lev_cam: np.ndarray) -> None:
        """The pipeline's frame ``frame`` (RGBDFrame) with its front-end ``result``, after the
        graph has added it (the graph's pose index is ``result``'s order in the run)."""
        if result.step is not None:
            self._chain.step(np.asarray(result.step.pose, float), _covariance(result.step.information))
        if self.keyframe_frames and not self._keyframe_due():
            return
        t0 = time.perf_counter()
        gray = cv2.cvtColor(frame.color, cv2.COLOR_BGR2GRAY) if frame.color.ndim == 3 else frame.color
        kf = make_keyframe(len(self.graph) - 1, frame.stamp, gray, frame.depth.astype(np.float32, copy=False),
                           self.intrinsics, R_lev_cam, result.manhattan, self.places, **self._lift)
        t1 = time.perf_counter()
        self.time_s["keyframes"] += t1 - t0
        rel, cov = self._chain.relative_to_now()  # every keyframe -> now, once per keyframe
        found = self._candidates(kf, rel, cov)
        t2 = time.perf_counter()
        self.time_s["candidates"] += t2 - t1
        for pos, cand in found:
            self._verify(self.keyframes[pos], kf, cand, rel[pos], cov[pos])
        self.time_s["verify"] += time.perf_counter() - t2
        self._chain.new_keyframe(rel, cov)
        self.keyframe_frames.append(kf.index)
        if self.config.forget_closed and any(c.verdict == "accepted" for _, c in found):
            self.keyframes.append(None)  # the place is known: its older keyframe stands for it
            return
        self.keyframes.append(kf)
        self._indexed.append(len(self.keyframes) - 1)
        self.index.add(kf)

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

    def _verify(self, a: Keyframe, b: Keyframe, cand: Candidate, chain_pose, chain_cov) -> None:
        """Verify one pair; an accepted pair becomes a closure factor in the graph. The
        odometry chain's relative pose ``chain_pose`` (3,) with its covariance ``chain_cov``
        (3, 3), scaled by ``odometry_sigma_scale``, is the verification's prior: a place that
        looks the same somewhere else (repeated doors and posters) is ``prior_mismatch``,
        which a redescending graph kernel could not always tell (the chain's robust steps
        give way instead of the closure)."""
        t0 = time.perf_counter()
        prior = (chain_pose, self.config.odometry_sigma_scale ** 2 * chain_cov)
        check = verify_closure(a, b, self.T_base_cam, self.places, seed=self.seed + len(self.candidates),
                               prior=prior)
        cand.verify_ms = 1000.0 * (time.perf_counter() - t0)
        cand.matches, cand.inliers, cand.spread_m = int(check.matches), int(check.inliers), float(check.spread_m)
        cand.verdict, cand.reason = ("accepted" if check.accepted else "rejected"), check.reason
        cand.odometry_d2 = check.prior_d2
        cand.prior_sigma_m = largest_sigma(prior[1][:2, :2])
        if check.pose is not None:
            cand.pose = [float(v) for v in check.pose]
        if not check.accepted:
            return
        cand.sigma = [float(v) for v in np.sqrt(np.diag(_covariance(check.information)))]
        cand.closure_id = self.graph.add_closure(a.index, b.index, check.pose, check.information,
                                                 info={"inliers": cand.inliers, "source": cand.source})

    def report(self) -> dict:
        """The ``loop_closure`` section of ``report.json`` (call after the graph is solved:
        closures the graph removed are marked ``removed`` with its reason)."""
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
                "verified": len(self.candidates), "accepted": verdicts.get("accepted", 0),
                "rejected": verdicts.get("rejected", 0), "removed_by_graph": verdicts.get("removed", 0),
                "not_accepted_by_reason": reasons,
                "time_s": {k: round(v, 4) for k, v in self.time_s.items()},
                "list": [vars(c) for c in self.candidates]}

    def accepted(self) -> list[tuple[int, int]]:
        """``(a, b)`` pose indices of the closures in the final solution."""
        return [(c.a, c.b) for c in self.candidates if c.verdict == "accepted"]


def _count(items) -> dict[str, int]:
    out: dict[str, int] = {}
    for k in items:
        out[k] = out.get(k, 0) + 1
    return out


def _covariance(information: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of a (3, 3) information matrix (pseudo-inverse: bridged steps may
    carry zero information in a direction)."""
    return np.linalg.pinv(np.asarray(information, dtype=float))
