"""Wall landmarks: which wall a frame's wall observation is, and when it becomes a factor.

A vertical wall seen from many poses is one line in odom: its offset bounds the drift
across it (a corridor's side walls the lateral drift, an end wall in range the drift
along). The Manhattan rotation factors already fix the walls' direction; this module only
decides identity, from three facts the front-end hands over per frame
(:class:`planar_vo.core.steps.WallObservation`):

* the wall's normal, relative to the observations of a local Manhattan frame the frame is
  linked to, fixes the frame ``j`` and the axis ``0..3`` (``normal = m_j + axis * pi/2``);
  a wall more than ``wall_axis_tol_deg`` off every axis is no Manhattan wall and is skipped;
* its offset, carried to odom by the frame's initial pose, is within ``wall_gate_m`` of
  the offset a landmark on the same frame and axis was last seen at;
* that landmark was seen within the last ``wall_window_m`` of travel. Older ones are not
  searched: after a loop the chained pose has drifted by more than the gate, and a loop
  is the closures' job, so a wall seen again after a long absence starts a new landmark.

A sighting becomes a factor only when its landmark was also seen in the frame before:
a wall the plane detector finds in one frame alone is a poor fit (on an unseen L turn, a
plane at the corner where the side wall ends, 36 mm proud of it at 5 mm stated, made the
smoothed run 0.13 % of the path worse than raw), so it is associated but never a factor.
A landmark gets a factor only every ``wall_spacing_m`` of travel (and at its first
sighting): frames at 30 Hz see the same wall through the same depth errors, and the
offsets' errors correlated between nearby frames would otherwise be counted thirty times
a metre. Association runs every frame all the same, so the track is never lost. The last
sighting of a wall also becomes a factor -- when the wall leaves the window, or at the
solve (:meth:`WallMap.flush`) -- so the steps after the last spaced factor, up to half a
metre of them at the end of a log or before a wall goes out of view, stay tied to it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.steps import WallObservation

HALF_PI = 0.5 * math.pi


@dataclass
class WallLandmark:
    """One wall line: ``n . (p - anchor) = d`` with ``n`` at ``m_frame + axis * pi/2``
    (``d`` lives in the graph; its initial value is the first sighting's offset).

    ``frame``: the local Manhattan frame (association index); ``axis``: 0..3;
    ``anchor``: (2,) odom point where it was first seen;
    ``last_d``: the offset predicted at the last sighting (the gate's reference);
    ``last_travel``: the travel (m) at that sighting, ``last_factor`` at the last factor;
    ``pending``: its latest sighting that is not a factor yet (:class:`WallMatch`), or None;
    only a sighting in the frame after another (``last_k``: graph frame of the last one).
    """

    frame: int
    axis: int
    anchor: np.ndarray
    last_d: float
    last_travel: float
    last_factor: float
    pending: "WallMatch | None" = None
    last_k: int = -1


@dataclass
class WallMatch:
    """One observation to turn into a factor: graph frame ``pose``, the Manhattan
    ``instance`` it is linked to, landmark ``wall``, its ``frame``/``axis``, the
    ``anchor``, and the observation's offset ``measured`` and sigma (floored); ``new`` when
    it opens the landmark (the caller inserts ``measured`` as the landmark's initial value:
    seen from its anchor, the wall is that far away)."""

    pose: int
    instance: int
    wall: int
    frame: int
    axis: int
    anchor: np.ndarray
    measured: float
    sigma: float
    new: bool


class WallMap:
    """Associates wall observations with landmarks (module docstring); no GTSAM in here."""

    def __init__(self, config):
        self.cfg = config
        self.walls: list[WallLandmark] = []
        self.travel = 0.0
        self._last_xy: np.ndarray | None = None
        self._active: list[int] = []   # landmarks seen within the window
        self._tol = math.radians(config.wall_axis_tol_deg)
        self.counts = {"observations": 0, "associated": 0, "new": 0, "skipped_axis": 0, "factors": 0}

    def observe(self, k: int, pose: np.ndarray, walls: list[WallObservation], links, inst_of: dict) -> list[WallMatch]:
        """Matches for graph frame ``k`` at initial pose ``pose`` (3,) ``T_odom_base``, given
        its Manhattan links to this pose (``measured = m_frame - theta_pose``, branch
        resolved) and the instance each linked frame uses (``inst_of``). Returns the
        observations that become factors now (last sightings of walls leaving the window
        included, at their own frames)."""
        xy = np.asarray(pose[:2], dtype=float)
        if self._last_xy is not None:
            self.travel += float(np.hypot(*(xy - self._last_xy)))
        self._last_xy = xy
        out: list[WallMatch] = []
        keep = []
        for i in self._active:
            if self.travel - self.walls[i].last_travel <= self.cfg.wall_window_m:
                keep.append(i)
            elif self.walls[i].pending is not None:
                out.append(self._take(self.walls[i]))
        self._active = keep
        used: set[int] = set()
        for w in sorted(walls, key=lambda w: -w.support):
            self.counts["observations"] += 1
            fa = self._frame_axis(w.normal_yaw, links)
            if fa is None:
                self.counts["skipped_axis"] += 1
                continue
            frame, axis, measured_m = fa
            inst = inst_of[frame]
            a = pose[2] + measured_m + axis * HALF_PI     # the wall normal's odom heading
            n = np.array([math.cos(a), math.sin(a)])
            lid = self._find(frame, axis, n, xy, w.offset, used)
            sigma = math.hypot(w.sigma, self.cfg.wall_min_sigma_m)
            if lid is None:
                self.walls.append(WallLandmark(frame, axis, xy.copy(), float(w.offset), self.travel, self.travel,
                                               last_k=k))
                lid = len(self.walls) - 1
                self._active.append(lid)
                self.counts["new"] += 1
                used.add(lid)
                out.append(WallMatch(k, inst, lid, frame, axis, xy.copy(), float(w.offset), sigma, True))
                continue
            used.add(lid)
            L = self.walls[lid]
            self.counts["associated"] += 1
            L.last_d = float(w.offset + n @ (xy - L.anchor))
            L.last_travel = self.travel
            confirmed, L.last_k = L.last_k == k - 1, k
            if confirmed:  # else a lone sighting: the last confirmed one stays pending
                L.pending = WallMatch(k, inst, lid, frame, axis, L.anchor, float(w.offset), sigma, False)
            if L.pending is not None and self.travel - L.last_factor >= self.cfg.wall_spacing_m:
                out.append(self._take(L))
        self.counts["factors"] += len(out)
        return out

    def flush(self) -> list[WallMatch]:
        """Every landmark's latest sighting that is not a factor yet (at a solve: the last
        ones before the end of the data), as factors now."""
        out = [self._take(L) for L in self.walls if L.pending is not None]
        self.counts["factors"] += len(out)
        return out

    def _take(self, L: WallLandmark) -> WallMatch:
        m, L.pending = L.pending, None
        L.last_factor = L.last_travel
        return m

    def _frame_axis(self, normal_yaw: float, links) -> tuple[int, int, float] | None:
        """``(frame, axis, measured)`` of the link whose axes the wall normal is nearest."""
        best = None
        for link in links:
            q = (normal_yaw - link.measured) / HALF_PI
            axis = round(q)
            r = abs(q - axis) * HALF_PI
            if r <= self._tol and (best is None or r < best[0]):
                best = (r, link.frame, axis % 4, link.measured)
        return None if best is None else best[1:]

    def _find(self, frame: int, axis: int, n: np.ndarray, xy: np.ndarray, offset: float, used: set[int]) -> int | None:
        best, best_gap = None, self.cfg.wall_gate_m
        for lid in self._active:
            L = self.walls[lid]
            if L.frame != frame or L.axis != axis or lid in used:
                continue
            gap = abs(offset + float(n @ (xy - L.anchor)) - L.last_d)
            if gap <= best_gap:
                best, best_gap = lid, gap
        return best
