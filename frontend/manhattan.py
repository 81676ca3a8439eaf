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
from planar_vo.core.geometry import wrap_quarter


@dataclass
class LocalFrame:
    """One local Manhattan frame seen in one image.

    ``heading``: rad in [-pi/4, pi/4), in the levelled camera's 2-D frame. ``sigma``: its
    standard deviation (rad). ``score``: image-area fraction of its walls.
    ``walls``: indices of its walls in the input list. ``track_id``: set by the tracker.
    ``sigma_fit``: the part of ``sigma`` that changes from image to image (the walls' fit
    noise; the systematic terms and the floor are common to consecutive views of the same
    walls and cancel in a heading difference).
    ``prev_heading``: the track's reference heading carried into the previous frame (for
    the direction-plus-point yaw, eq. 1), else None for a new track; ``prev_sigma`` its
    std, ``prev_sigma_fit`` its image-to-image part and ``prev_score`` the score it was
    observed with. ``age``: consecutive frames the
    track has been seen (a wall entering the view gives biased headings at first).
    ``width``: the widest of its walls (m, :attr:`Plane.width`). ``compass_heading`` and
    ``compass_sigma``: the same as ``heading`` and ``sigma`` from the walls at least
    ``min_wall_width_m`` wide, when it has one (:func:`_compass`): the back-end's heading.
    """

    heading: float
    sigma: float
    score: float
    walls: list[int] = field(default_factory=list)
    track_id: int = -1
    prev_heading: float | None = None
    prev_sigma: float = math.inf  # std (rad) of prev_heading: its observation and the steps it was carried
    prev_score: float = 0.0       # score of the observation prev_heading comes from
    #: the track's heading in the previous frame (observed there, else carried): the
    #: frame-to-frame rotation the 3-D matches see, whatever the chain's earlier errors
    prev_local: float | None = None
    age: int = 1  # consecutive frames the track has been seen, this one included
    sigma_fit: float = math.inf
    prev_sigma_fit: float = math.inf
    width: float = 0.0  # widest of its walls (m, Plane.width)
    #: heading and sigma from its compass walls only (_compass): what the back-end takes;
    #: ``heading`` and ``sigma`` unless given
    compass_heading: float | None = None
    compass_sigma: float | None = None

    def __post_init__(self) -> None:
        if self.compass_heading is None:
            self.compass_heading, self.compass_sigma = self.heading, self.sigma

    def step_sigma(self) -> float:
        """Std (rad) of the direction-plus-point yaw ``heading - prev_heading`` (eq. 1): the
        two views' image-to-image parts, plus what the steps the reference was carried over
        added. Their common part (systematic, levelling) cancels in the difference."""
        return math.hypot(self.sigma_fit, self.prev_sigma_fit)


def group_walls(walls: list[Plane], config: ManhattanConfig | None = None) -> list[LocalFrame]:
    """Group vertical planes into local Manhattan frames, dominant (highest score) first.

    Greedy over walls by decreasing area: a wall joins the first frame whose heading is
    within ``group_tol_deg`` (modulo 90 degrees) and within ``group_sigmas`` of their
    combined sigmas, else opens a new one. A frame's heading and sigma come from
    :func:`_mean_heading`, floored at ``min_sigma_deg`` (levelling and model errors the
    fit does not see); so do its ``compass_heading`` and ``compass_sigma``, over its compass
    walls only (:func:`_compass`).
    """
    c = config or ManhattanConfig()
    tol = math.radians(c.group_tol_deg)
    floor_sigma = math.radians(c.min_sigma_deg)
    order = sorted(range(len(walls)), key=lambda i: -walls[i].support)
    groups: list[list[int]] = []
    centres: list[float] = []
    sigmas: list[float] = []
    for i in order:
        h = float(wrap_quarter(walls[i].yaw))
        for g, (members, centre) in enumerate(zip(groups, centres)):
            d = abs(float(wrap_quarter(h - centre)))
            # within the tolerance and consistent with the walls already in (largest
            # first): a box or door 2 deg off the corridor is its own frame, not noise
            if d < tol and d <= c.group_sigmas * math.hypot(walls[i].yaw_sigma, sigmas[g]):
                members.append(i)
                centres[g], sigmas[g], _ = _mean_heading([walls[j] for j in members], centre, floor_sigma)
                break
        else:
            groups.append([i])
            centres.append(h)
            sigmas.append(max(walls[i].yaw_sigma, floor_sigma))
    frames = []
    for members, centre in zip(groups, centres):
        ws = [walls[j] for j in members]
        heading, sigma, sigma_fit = _mean_heading(ws, centre, floor_sigma)
        wide = _compass(ws, c)
        compass, compass_sigma = (heading, sigma) if len(wide) == len(ws) else \
            _mean_heading(wide, centre, floor_sigma)[:2]
        frames.append(LocalFrame(float(wrap_quarter(heading)), sigma, float(sum(w.support for w in ws)),
                                 list(members), sigma_fit=sigma_fit, width=max(w.width for w in ws),
                                 compass_heading=float(wrap_quarter(compass)), compass_sigma=compass_sigma))
    frames.sort(key=lambda f: -f.score)
    return frames


def _compass(walls: list[Plane], config: ManhattanConfig) -> list[Plane]:
    """The walls of one frame that give the heading the back-end takes (its
    ``compass_heading``): those at least ``min_wall_width_m`` wide (:attr:`Plane.width`),
    or all of them when none is.

    Box faces and pillar facets are vertical planes turned by any angle; one within the
    grouping tolerance of a corridor's walls joins their frame but is not part of the
    building's grid. Weighted in by its sigma -- a near face's is as small as a long
    wall's -- a box 2 deg off pulled a corridor's heading by 1-1.5 deg in the frames it
    joined, and the graph's drift-free yaw took that heading. The steps keep the heading
    of every wall (``heading``): a heading *difference* between two views of the same
    faces is as good as a wall's, while a wall whose width wavers about the threshold
    (0.8-1.5 m: occluded, door layers) would enter and leave the compass frame by frame
    and jitter the steps' yaw by 0.1 deg (a tuning L turn: raw 0.18 -> 0.72 %).
    """
    wide = [w for w in walls if w.width >= config.min_wall_width_m]
    return wide or walls


def _mean_heading(walls: list[Plane], ref: float, floor_sigma: float) -> tuple[float, float, float]:
    """``(heading, sigma, sigma_fit)``: the heading near ``ref`` from the walls' headings,
    weighted by their own sigmas; its sigma, inflated by the walls' scatter when they
    disagree beyond those sigmas and floored; and the image-to-image part of that sigma
    (the same weights over the walls' fit sigmas, :attr:`Plane.yaw_sigma_fit`).

    A wall's ``yaw_sigma`` carries a systematic term that grows as its angular extent
    shrinks, so a small box face or a far patch cannot outvote a long wall; weighting by
    area instead let such patches (2 deg off, 1-3 % of the image) pull the heading and
    inflate its sigma tenfold.
    """
    d = np.array([float(wrap_quarter(w.yaw - ref)) for w in walls])
    wt = 1.0 / np.maximum(np.array([w.yaw_sigma for w in walls]), 1e-6) ** 2
    mean = float((wt * d).sum() / wt.sum())
    var = 1.0 / float(wt.sum())
    if len(walls) > 1:
        chi2 = float((wt * (d - mean) ** 2).sum())
        var *= max(1.0, chi2 / (len(walls) - 1))
    fit = np.array([w.yaw_sigma_fit for w in walls])
    var_fit = float((wt ** 2 * fit ** 2).sum()) / float(wt.sum()) ** 2
    return ref + mean, max(math.sqrt(var), floor_sigma), math.sqrt(var_fit)


@dataclass
class _Track:
    id: int
    heading: float          # in the latest levelled camera frame, wrapped
    last_seen: int          # frame counter
    missed: int = 0
    age: int = 1            # consecutive frames seen
    # Reference for the step yaw: the last good observation, carried into the latest
    # frame by the steps since (their yaw variances summed in ref_var).
    ref_heading: float = 0.0
    ref_sigma: float = math.inf
    ref_sigma_fit: float = math.inf
    ref_score: float = 0.0
    ref_var: float = 0.0


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

    def associate(self, frames: list[LocalFrame], yaw_prior: float, yaw_prior_sigma: float = 0.0) -> None:
        """Give each frame a ``track_id`` (new ids for unmatched ones) and ``prev_heading``.

        ``frames``: this image's local frames, dominant first. ``yaw_prior``: expected
        yaw (rad) of the step from the previous image (e.g. constant velocity), with std
        ``yaw_prior_sigma`` (rad). When another track fits within three of those sigmas of
        the best one, the association is ambiguous: the frame keeps the track id but no
        ``prev_heading`` (no yaw is measured from it this frame).
        """
        self._frame += 1
        gate = math.radians(self.config.track_gate_deg)
        free = list(self._tracks)
        for f in frames:
            best, best_err = None, gate
            errs = []
            # tracks seen in the previous frame first: a carried one a degree away (a wall
            # group that split off for a while) must not take over the track in view
            for t in sorted(free, key=lambda t: t.missed):
                err = abs(float(wrap_quarter(f.heading - (t.heading - yaw_prior))))
                errs.append((t.missed, err))
                if err < best_err and (best is None or t.missed == best.missed):
                    best, best_err = t, err
            ambiguous = best is not None and sum(
                m == best.missed and e <= best_err + 3.0 * yaw_prior_sigma for m, e in errs) > 1
            if best is None:
                f.track_id, f.prev_heading = self._next_id, None
                self._next_id += 1
                continue
            free.remove(best)
            f.track_id = best.id
            consecutive = best.last_seen == self._frame - 1
            # The yaw telescopes along the track: measured against its reference, the
            # chained heading follows the Manhattan frame across frames where the step
            # came from elsewhere (their errors are in ref_var, hence in prev_sigma).
            f.prev_local = best.heading
            if math.isfinite(best.ref_sigma) and not ambiguous:
                f.prev_heading = best.ref_heading
                f.prev_sigma = math.sqrt(best.ref_sigma ** 2 + best.ref_var)
                f.prev_sigma_fit = math.sqrt(best.ref_sigma_fit ** 2 + best.ref_var)
                f.prev_score = best.ref_score
            f.age = best.age + 1 if consecutive and not ambiguous else 1

    def commit(self, frames: list[LocalFrame], yaw_step: float, yaw_var: float = 0.0,
               distrusted: frozenset[int] | set[int] = frozenset()) -> None:
        """After the step into this image is known (yaw, rad, and its variance, rad^2):
        update, carry and prune tracks. An observation becomes its track's reference when
        its sigma is at most ``ref_max_sigma_deg``; else the reference is carried.
        ``distrusted``: track ids whose observation here contradicted the step (vetoed):
        the track counts as seen, but its heading and reference are carried, so the next
        step is measured from the walls it followed, not from the jump."""
        seen = {f.track_id: f for f in frames}
        ref_max = math.radians(self.config.ref_max_sigma_deg)
        kept = []
        for t in self._tracks:
            f = seen.pop(t.id, None)
            if f is not None and t.id in distrusted:
                t.heading = float(wrap_quarter(t.heading - yaw_step))
                t.last_seen, t.missed, t.age = self._frame, 0, f.age
                f = None  # carry the reference below
            elif f is not None:
                t.heading, t.last_seen, t.missed, t.age = f.heading, self._frame, 0, f.age
            else:
                t.heading = float(wrap_quarter(t.heading - yaw_step))
                t.missed += 1
            if f is not None and f.sigma <= ref_max:
                t.ref_heading, t.ref_score, t.ref_var = f.heading, f.score, 0.0
                t.ref_sigma, t.ref_sigma_fit = f.sigma, f.sigma_fit
            else:
                t.ref_heading = float(wrap_quarter(t.ref_heading - yaw_step))
                t.ref_var += yaw_var
            if t.missed <= self.config.max_missed:
                kept.append(t)
        for f in seen.values():
            t = _Track(f.track_id, f.heading, self._frame)
            if f.sigma <= ref_max:
                t.ref_heading, t.ref_sigma, t.ref_sigma_fit, t.ref_score = f.heading, f.sigma, f.sigma_fit, f.score
            kept.append(t)
        self._tracks = kept
