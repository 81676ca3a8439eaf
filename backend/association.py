"""Manhattan-frame data association: which local frame (and which 90-degree branch) an
observation belongs to, and when a new local frame is born.

Association runs against a yaw-only Kalman filter over ``[theta_current, m_0, ..., m_J-1]``.
The heading part of the pose graph is linear (steps add yaw, Manhattan factors tie
``m_j - theta_k`` to a measurement), so this filter is the exact recursive solution of that
sub-problem up to the robust kernel and the x/y-theta cross-terms of the step
information; it gives the predicted residual and its variance for gating at O(J^2) per
frame, independent of the graph size. Batch and incremental graphs share it, so they
build identical graphs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.backend.config import BackendConfig
from planar_vo.backend.factors import HALF_PI, TWO_PI, robust_weight
from planar_vo.core.steps import ManhattanObservation


@dataclass
class ManhattanLink:
    """One rotation factor to add: ``wrap(m_frame - theta_pose - measured)``, std ``sigma`` (rad)."""

    pose: int
    frame: int
    measured: float
    sigma: float


@dataclass
class AssociationOutcome:
    """What one frame's observations produced."""

    links: list[ManhattanLink] = field(default_factory=list)
    new_frames: list[tuple[int, float]] = field(default_factory=list)  # (id, initial world yaw)
    associated: int = 0
    rejected: int = 0         # candidates that expired (their observations are dropped)
    ignored: int = 0          # below manhattan_min_score, or unmatched under the policy
    theta_correction: float = 0.0  # filtered heading after minus before this frame's updates


@dataclass
class _Candidate:
    yaw: float                                   # world heading of its first observation
    members: list[tuple[int, float, float, float]]  # (pose, yaw_obs, sigma, theta_at_pose)
    last_pose: int
    target: int | None = None                    # a known frame the members drifted from (drift candidate)


def _quarter(a: float) -> float:
    return (a + 0.25 * math.pi) % HALF_PI - 0.25 * math.pi


class ManhattanAssociator:
    """Gating, branch choice and frame creation for Manhattan observations.

    Call :meth:`start` for the first frame, then per frame :meth:`predict` with the step's
    yaw and yaw variance followed by :meth:`observe` with that frame's observations.
    """

    def __init__(self, config: BackendConfig):
        self.cfg = config
        self._x = np.zeros(1)          # [theta, m_0, ...] (rad)
        self._P = np.zeros((1, 1))
        self.n_obs: list[int] = []     # observations linked per frame
        self._candidates: list[_Candidate] = []
        self._min_var = math.radians(config.manhattan_min_sigma_deg) ** 2
        self._gate_max = math.radians(config.gate_max_deg)
        self._cand_gate = math.radians(config.new_frame_gate_deg)
        self._same_frame = math.radians(config.same_frame_deg)
        self.drift_associations = 0    # associated beyond the sigma gate by same_frame_deg

    # ------------------------------------------------------------------ state
    @property
    def theta(self) -> float:
        return float(self._x[0])

    @property
    def n_frames(self) -> int:
        return len(self._x) - 1

    def frame_yaws(self) -> np.ndarray:
        """(J,) float64 filtered world headings of the frames (rad)."""
        return self._x[1:].copy()

    def start(self, theta: float = 0.0, variance: float = 0.0) -> None:
        self._x[0] = theta
        self._P[0, 0] = variance

    def predict(self, dtheta: float, variance: float) -> None:
        """Move the filter to the next pose: ``theta += dtheta`` with yaw variance ``variance``."""
        self._x[0] = math.remainder(self._x[0] + dtheta, TWO_PI)
        self._P[0, 0] += variance

    # ------------------------------------------------------------ association
    def observe(self, pose: int, observations: list[ManhattanObservation]) -> AssociationOutcome:
        """Associate one frame's observations (dominant first); returns factors to add."""
        cfg = self.cfg
        out = AssociationOutcome()
        theta_before = self.theta
        used: set[int] = set()
        for i, obs in enumerate(observations):
            yaw, sigma = float(obs.yaw), float(obs.sigma)
            if not (math.isfinite(yaw) and math.isfinite(sigma) and sigma > 0):
                raise ValueError(f"ManhattanObservation {i} of frame {pose} has yaw={obs.yaw!r}, "
                                 f"sigma={obs.sigma!r}; need finite yaw and sigma > 0")
            if obs.score < cfg.manhattan_min_score:
                out.ignored += 1
                continue
            var = max(sigma * sigma, self._min_var)
            j, measured, drifted = self._best_frame(yaw, var, used)
            if j is None and self._seen_here(yaw, used):
                out.ignored += 1
                continue
            if drifted is not None:
                self._candidate(pose, yaw, math.sqrt(var), out, used, target=drifted)
                continue
            if j is not None:
                used.add(j)
                self._update(j, measured, var)
                self.n_obs[j] += 1
                out.links.append(ManhattanLink(pose, j, measured, math.sqrt(var)))
                out.associated += 1
                continue
            if cfg.new_frame_policy == "never" or (cfg.new_frame_policy == "dominant" and i > 0):
                out.ignored += 1
                continue
            self._candidate(pose, yaw, math.sqrt(var), out, used)
        out.rejected += self._expire(pose)
        out.theta_correction = math.remainder(self.theta - theta_before, TWO_PI)
        return out

    def _best_frame(self, yaw: float, var: float, used: set[int]):
        """Frame index and ``measured = yaw + b*pi/2`` with the smallest gated residual, and
        None; or ``(None, 0, j)`` where the observation is beyond every gate but within
        ``same_frame_deg`` of frame ``j`` (a drift candidate of ``j``)."""
        best, best_u, best_meas = None, math.inf, 0.0
        theta, P = self._x[0], self._P
        nearest, nearest_r = None, math.inf
        for j in range(self.n_frames):
            if j in used:
                continue
            d = self._x[j + 1] - theta - yaw
            b = round(d / HALF_PI)
            r = math.remainder(d - b * HALF_PI, TWO_PI)
            # variance of the predicted heading of frame j relative to the robot (not of the
            # heading in odom, which a long bridge at the start leaves unknown while the
            # frame's relative heading is well known)
            s = P[j + 1, j + 1] + P[0, 0] - 2.0 * P[0, j + 1] + var
            u = abs(r) / math.sqrt(s)
            # When that is uncertain (a bridged stretch since the frame was seen), widen the
            # degree cap with it, never past 40 deg, where the 90-degree branch is ambiguous.
            cap = min(max(self._gate_max, 3.0 * math.sqrt(s)), math.radians(40.0))
            if abs(r) <= cap and u <= self.cfg.gate_sigmas and u < best_u:
                best, best_u, best_meas = j, u, yaw + b * HALF_PI
            if abs(r) < nearest_r:
                nearest, nearest_r, nearest_meas = j, abs(r), yaw + b * HALF_PI
        # Local frames of one building are far apart; one a few degrees from a known frame
        # is that frame seen with a drifted heading (steps biased or bridged), not a new one.
        # But a wrong sighting -- a box face or a pillar a few degrees off the walls -- gives
        # the same innovation, so such sightings join the frame only with the evidence a new
        # frame needs (:meth:`_candidate`): two sightings of a box 2.8 deg off the walls,
        # 470 frames after the last wall, linked one by one, turned the smoothed heading
        # 2.5 deg about one direction-plus-point step (hall_s8905, 8900 set: final yaw
        # -0.64 deg raw, +1.94 deg smoothed).
        if best is None and nearest is not None and nearest_r <= self._same_frame:
            return None, 0.0, nearest
        return best, best_meas, None

    def _seen_here(self, yaw: float, used: set[int]) -> bool:
        """Whether ``yaw`` lies within ``same_frame_deg`` of a frame this pose already observed.

        A second wall group a few degrees from the dominant one (a door frame, a box, a
        wall bent by depth noise) is the same local frame seen twice, not a new one; with
        one link per frame and pose it would otherwise start a candidate, and three such
        groups a few poses apart made a frame (straight_s6300, docs/bench).
        """
        theta = self._x[0]
        return any(abs(_quarter(self._x[j + 1] - theta - yaw)) <= self._same_frame for j in used)

    def _update(self, j: int, measured: float, var: float) -> None:
        """Robust Kalman update with ``z = m_j - theta`` (Sec. 2.1's alignment made a filter)."""
        x, P = self._x, self._P
        h = np.zeros(len(x))
        h[0], h[j + 1] = -1.0, 1.0
        Ph = P @ h
        s0 = float(h @ Ph)
        nu = math.remainder(measured - (x[j + 1] - x[0]), TWO_PI)
        # Same kernel as the graph: IRLS weight on the whitened innovation inflates R.
        w = robust_weight(self.cfg.robust_kernel, self.cfg.manhattan_robust_parameter,
                          abs(nu) / math.sqrt(s0 + var))
        s = s0 + var / max(w, 1e-12)
        k = Ph / s
        self._x = x + k * nu
        self._x[0] = math.remainder(self._x[0], TWO_PI)
        self._P = P - np.outer(k, Ph)

    def _candidate(self, pose: int, yaw: float, sigma: float, out: AssociationOutcome,
                   used: set[int], target: int | None = None) -> None:
        """Start or extend a candidate: of a new frame, or (``target``) of sightings of a
        known frame that the chained heading has drifted from. Either is promoted once
        ``new_frame_min_observations`` consistent sightings arrived within
        ``new_frame_window`` frames (:meth:`_promote`), and dropped otherwise."""
        theta = self.theta
        for c in self._candidates:
            if c.last_pose == pose or c.target != target:
                continue  # one observation per frame and candidate
            if abs(_quarter(c.yaw - theta - yaw)) <= self._cand_gate:
                c.members.append((pose, yaw, sigma, theta))
                c.last_pose = pose
                if len(c.members) >= self.cfg.new_frame_min_observations:
                    self._promote(c, out, used)
                return
        c = _Candidate(yaw=math.remainder(theta + yaw, TWO_PI), members=[(pose, yaw, sigma, theta)],
                       last_pose=pose, target=target)
        self._candidates.append(c)
        if self.cfg.new_frame_min_observations <= 1:
            self._promote(c, out, used)

    def _promote(self, c: _Candidate, out: AssociationOutcome, used: set[int]) -> None:
        """Turn a candidate into a frame: augment the filter, emit all its factors. A drift
        candidate joins its target frame instead (:meth:`_join`)."""
        self._candidates.remove(c)
        if c.target is not None:
            self._join(c, out, used)
            return
        pose, yaw, sigma, theta = c.members[-1]
        m0 = math.remainder(theta + yaw, TWO_PI)
        j = self.n_frames
        n = len(self._x)
        x = np.append(self._x, m0)
        P = np.zeros((n + 1, n + 1))
        P[:n, :n] = self._P
        P[n, :n] = P[:n, n] = self._P[0]
        P[n, n] = self._P[0, 0] + sigma * sigma
        self._x, self._P = x, P
        self.n_obs.append(len(c.members))
        used.add(j)
        out.new_frames.append((j, m0))
        for p, y, s, th in c.members:
            b = round((m0 - th - y) / HALF_PI)
            out.links.append(ManhattanLink(p, j, y + b * HALF_PI, s))
        out.associated += len(c.members)

    def _join(self, c: _Candidate, out: AssociationOutcome, used: set[int]) -> None:
        """Link a drift candidate's sightings to its target frame, each on the 90-degree
        branch nearest the heading it was seen at, and correct the filter with them."""
        j, theta = c.target, self.theta
        for p, y, s, th in c.members:
            b = round((self._x[j + 1] - th - y) / HALF_PI)
            out.links.append(ManhattanLink(p, j, y + b * HALF_PI, s))
            # m_j - theta now = (m_j - theta then) - (the steps' yaw since, as chained)
            self._update(j, y + b * HALF_PI - math.remainder(theta - th, TWO_PI), s * s)
        used.add(j)
        self.n_obs[j] += len(c.members)
        self.drift_associations += len(c.members)
        out.associated += len(c.members)

    def _expire(self, pose: int) -> int:
        keep, dropped = [], 0
        for c in self._candidates:
            if pose - c.members[0][0] >= self.cfg.new_frame_window:
                dropped += len(c.members)
            else:
                keep.append(c)
        self._candidates = keep
        return dropped

    @property
    def n_pending(self) -> int:
        return sum(len(c.members) for c in self._candidates)
