"""Local Manhattan frames from vertical planes, and their tracking across frames (Sec. 2.1).

Walls whose normals are parallel or perpendicular (within ``group_tol_deg``) belong to one
local Manhattan frame; a frame is scored by the image area of its walls and the highest
score is the dominant frame. Headings are in the 2-D frame of the levelled camera
(x forward, y left, counter-clockwise positive, as :attr:`Plane.yaw`) and wrapped to
[-pi/4, pi/4) -- a Manhattan frame fixes a heading only modulo 90 degrees.

Tracking resolves that ambiguity between frames: a track keeps the frame's heading in
the latest levelled camera frame; the next frame's headings are compared with the
heading predicted by a yaw prior (``heading - yaw``), and after the step is estimated the
unseen tracks are carried forward with it. Several local frames (corridors meeting at
other angles than 90 degrees) are tracked side by side.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.frontend.config import ManhattanConfig
from planar_vo.frontend.planes import Plane
from planar_vo.geometry import wrap_quarter


@dataclass
class LocalFrame:
    """One local Manhattan frame seen in one image.

    ``heading``: rad in [-pi/4, pi/4), in the levelled camera's 2-D frame. ``sigma``: its
    standard deviation (rad). ``score``: image-area fraction of its walls.
    ``walls``: indices of its walls in the input list. ``track_id``: set by the tracker.
    ``prev_heading``: the same track's heading in the previous frame, when it was seen
    there (for the direction-plus-point yaw), else None. ``age``: consecutive frames the
    track has been seen (a wall entering the view gives biased headings at first).
    """

    heading: float
    sigma: float
    score: float
    walls: list[int] = field(default_factory=list)
    track_id: int = -1
    prev_heading: float | None = None
    age: int = 1  # consecutive frames the track has been seen, this one included


def group_walls(walls: list[Plane], config: ManhattanConfig | None = None) -> list[LocalFrame]:
    """Group vertical planes into local Manhattan frames, dominant (highest score) first.

    Greedy over walls by decreasing area: a wall joins the first frame whose heading is
    within ``group_tol_deg`` (modulo 90 degrees), else opens a new one. A frame's heading is
    the area-weighted mean of its walls' (wrapped) headings; its sigma combines the
    propagated fit sigma and the walls' weighted scatter, floored at ``min_sigma_deg``
    (levelling and model errors the fit does not see).
    """
    c = config or ManhattanConfig()
    tol = math.radians(c.group_tol_deg)
    floor_sigma = math.radians(c.min_sigma_deg)
    order = sorted(range(len(walls)), key=lambda i: -walls[i].support)
    groups: list[list[int]] = []
    centres: list[float] = []
    for i in order:
        h = float(wrap_quarter(walls[i].yaw))
        for g, (members, centre) in enumerate(zip(groups, centres)):
            if abs(float(wrap_quarter(h - centre))) < tol:
                members.append(i)
                centres[g] = _mean_heading([walls[j] for j in members], centre, floor_sigma)[0]
                break
        else:
            groups.append([i])
            centres.append(h)
    frames = []
    for members, centre in zip(groups, centres):
        ws = [walls[j] for j in members]
        heading, sigma = _mean_heading(ws, centre, floor_sigma)
        frames.append(LocalFrame(float(wrap_quarter(heading)), sigma, float(sum(w.support for w in ws)),
                                 list(members)))
    frames.sort(key=lambda f: -f.score)
    return frames


def _mean_heading(walls: list[Plane], ref: float, floor_sigma: float) -> tuple[float, float]:
    """Area-weighted mean heading near ``ref`` and its sigma (fit sigma + walls' scatter)."""
    d = np.array([float(wrap_quarter(w.yaw - ref)) for w in walls])
    # Area weights (Sec. 2.1 scores frames by area): fit sigmas of thousands of pixels are
    # tiny and would let a small box face outvote a wall.
    wt = np.array([w.support for w in walls])
    wt = wt / wt.sum()
    mean = float((wt * d).sum())
    fit_var = float((wt ** 2 * np.array([w.yaw_sigma for w in walls]) ** 2).sum())
    scatter_var = float((wt * (d - mean) ** 2).sum()) if len(walls) > 1 else 0.0
    return ref + mean, max(math.sqrt(fit_var + scatter_var), floor_sigma)


@dataclass
class _Track:
    id: int
    heading: float          # in the latest levelled camera frame, wrapped
    last_seen: int          # frame counter
    missed: int = 0
    age: int = 1            # consecutive frames seen


class ManhattanTracker:
    """Keeps local Manhattan frames across frames; see the module docstring."""

    def __init__(self, config: ManhattanConfig | None = None):
        self.config = config or ManhattanConfig()
        self._tracks: list[_Track] = []
        self._next_id = 0
        self._frame = -1

    @property
    def tracks(self) -> list[tuple[int, float]]:
        """(track id, heading in the latest levelled frame) of the live tracks."""
        return [(t.id, t.heading) for t in self._tracks]

    def associate(self, frames: list[LocalFrame], yaw_prior: float) -> None:
        """Give each frame a ``track_id`` (new ids for unmatched ones) and ``prev_heading``.

        ``frames``: this image's local frames, dominant first. ``yaw_prior``: expected
        yaw (rad) of the step from the previous image (e.g. constant velocity).
        """
        self._frame += 1
        gate = math.radians(self.config.track_gate_deg)
        free = list(self._tracks)
        for f in frames:
            best, best_err = None, gate
            for t in free:
                err = abs(float(wrap_quarter(f.heading - (t.heading - yaw_prior))))
                if err < best_err:
                    best, best_err = t, err
            if best is None:
                f.track_id, f.prev_heading = self._next_id, None
                self._next_id += 1
                continue
            free.remove(best)
            f.track_id = best.id
            consecutive = best.last_seen == self._frame - 1
            f.prev_heading = best.heading if consecutive else None
            f.age = best.age + 1 if consecutive else 1

    def commit(self, frames: list[LocalFrame], yaw_step: float) -> None:
        """After the step (yaw, rad) into this image is known: update, carry and prune tracks."""
        seen = {f.track_id: f for f in frames}
        kept = []
        for t in self._tracks:
            f = seen.pop(t.id, None)
            if f is not None:
                t.heading, t.last_seen, t.missed, t.age = f.heading, self._frame, 0, f.age
            else:
                t.heading = float(wrap_quarter(t.heading - yaw_step))
                t.missed += 1
            if t.missed <= self.config.max_missed:
                kept.append(t)
        for f in seen.values():
            kept.append(_Track(f.track_id, f.heading, self._frame))
        self._tracks = kept
