"""Scenes for the synthetic renderer (:mod:`planar_vo.sim.synth`): floor plans, decorations,
triangle meshes and the robot's nominal path.

World frame: z up, floor at z = 0, metres. A layout is built from a corridor centre line
(a polyline whose corners become circular arcs of the robot's path); walls are its
offsets at +-width/2 extruded to the ceiling, listed as rings with the free space on the
left of every edge. Walls, doors and posters on them carry the id of their local
Manhattan frame (world heading of one wall direction, modulo 90 degrees).

Surface coordinates: every surface is a planar rectangle ``origin + u * axis_u + v *
axis_v`` with ``0 <= u <= size[0]``, ``0 <= v <= size[1]``; ``normal = axis_u x axis_v``
points into the free space (toward a viewer). For vertical surfaces ``axis_v`` is up and
``axis_u`` is the viewer's right, so decals appear unmirrored.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

LABEL_NONE, LABEL_FLOOR, LABEL_WALL, LABEL_CEILING, LABEL_OTHER = range(5)
LAYOUTS = ("straight", "lturn", "loop", "two_frames", "hall", "building", "aliased")
#: Layouts whose path is a closed ring, driven ``laps`` times (``path_length`` of
#: :func:`build_scene` is then one lap).
CLOSED_LAYOUTS = ("loop", "building")
#: ``building``: the lap (m) a log is sized for by default (:func:`planar_vo.sim.synth.frames_for_laps`).
BUILDING_LAP_M = 40.0
#: ``building``: poster and door designs used, few so that they repeat along the ring.
BUILDING_POSTER_DESIGNS, BUILDING_DOOR_DESIGNS = 5, 2
#: ``aliased``: shortest stretch (m) of the two look-alike corridors.
ALIASED_MIN_MODULE_M = 3.0
MAT_FLOOR, MAT_WALL, MAT_CEILING, MAT_CONCRETE, MAT_POSTER, MAT_DOOR, MAT_BOX = range(7)
MATERIAL_NAMES = ("floor", "wall", "ceiling", "concrete", "poster", "door", "box")

_Z = np.array([0.0, 0.0, 1.0])
#: wall paints as BGR multipliers of the white base: white, warm beige, pale blue, pale green, grey
_PAINTS = ((1.0, 1.0, 1.0), (0.86, 0.94, 1.0), (1.0, 0.95, 0.86), (0.88, 1.0, 0.9), (0.93, 0.93, 0.93))


@dataclass
class Surface:
    """A textured planar rectangle (see the module docstring for its coordinates).

    ``mframe``: local Manhattan frame id for walls (and decals on them), else -1.
    ``design``: decal design index (posters, doors, box faces). ``tint``: BGR multiplier
    of the material colour. ``offset``: texture offset (m) of periodic materials.
    """

    label: int
    material: int
    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size: tuple[float, float]
    mframe: int = -1
    design: int = 0
    tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    offset: tuple[float, float] = (0.0, 0.0)

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_u, self.axis_v)

    def corners(self) -> np.ndarray:
        """(4, 3) corners, counter-clockwise seen from the normal side."""
        o, su, sv = self.origin, self.size[0] * self.axis_u, self.size[1] * self.axis_v
        return np.array([o, o + su, o + su + sv, o + sv])


# ------------------------------------------------------------------------------ path

def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _left(d) -> np.ndarray:
    return np.array([-d[1], d[0]])


class RoundedPath:
    """A polyline whose corners are replaced by circular arcs, parametrised by arc length.

    ``points`` (M, 2); ``radius``: arc radius at every corner. A closed path starts at the
    middle of its first edge. Raises ``ValueError`` if an arc does not fit its edges.
    """

    def __init__(self, points, radius: float, closed: bool = False):
        P = np.asarray(points, float)
        self.points, self.radius, self.closed = P, float(radius), closed
        M = len(P)
        corners = list(range(1, M)) + [0] if closed else list(range(1, M - 1))
        start = 0.5 * (P[0] + P[1]) if closed else P[0]
        d0 = _unit(P[1] - P[0])
        # segments: (kind, point, direction | centre, start angle, turn sign, length, start heading)
        self.segments: list[tuple] = []
        self._heading = math.atan2(d0[1], d0[0])  # unwrapped heading at the end of the last segment
        cur = start
        for j, i in enumerate(corners):
            pnext = P[(i + 1) % M]
            d_in, d_out = _unit(P[i] - P[i - 1]), _unit(pnext - P[i])
            delta = math.atan2(d_in[0] * d_out[1] - d_in[1] * d_out[0], float(d_in @ d_out))
            T = self.radius * math.tan(abs(delta) / 2.0)
            a = P[i] - T * d_in
            room = np.linalg.norm(pnext - P[i]) / (1.0 if (j == len(corners) - 1 and not closed) else 2.0)
            if (a - cur) @ d_in < -1e-9 or T > room + 1e-9:
                raise ValueError(f"corner {i} of the path: radius {radius} m does not fit the edges")
            self._line(cur, a)
            if abs(delta) > 1e-12:
                sgn = 1.0 if delta > 0 else -1.0
                c = a + sgn * self.radius * _left(d_in)
                a0 = math.atan2(a[1] - c[1], a[0] - c[0])
                self.segments.append(("arc", a, c, a0, sgn, self.radius * abs(delta), self._heading))
                self._heading += delta
            cur = P[i] + T * d_out
        self._line(cur, start if closed else P[-1])
        lengths = np.array([sg[5] for sg in self.segments])
        self.starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        self.length = float(lengths.sum())

    def _line(self, a, b) -> None:
        ln = float(np.linalg.norm(b - a))
        if ln > 1e-9:
            self.segments.append(("line", a, (b - a) / ln, 0.0, 0.0, ln, self._heading))

    def evaluate(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions (n, 2), headings (n,) and signed curvatures (n,) at arc lengths ``s`` (n,).

        Headings are continuous along the path (not wrapped); a closed path takes ``s``
        modulo its length.
        """
        s = np.atleast_1d(np.asarray(s, float))
        s = np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)
        k = np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.segments) - 1)
        pos, head, curv = np.zeros((len(s), 2)), np.zeros(len(s)), np.zeros(len(s))
        for j, (kind, p, dc, a0, sgn, _, h0) in enumerate(self.segments):
            m = k == j
            ds = s[m] - self.starts[j]
            if kind == "line":
                pos[m] = p + ds[:, None] * dc
                head[m] = h0
            else:
                ang = a0 + sgn * ds / self.radius
                pos[m] = dc + self.radius * np.stack([np.cos(ang), np.sin(ang)], -1)
                head[m] = h0 + sgn * ds / self.radius
                curv[m] = sgn / self.radius
        return pos, head, curv

    def samples(self, step: float = 0.1) -> np.ndarray:
        """(n, 2) points every ``step`` metres along the path."""
        return self.evaluate(np.linspace(0.0, self.length, max(2, int(self.length / step) + 1)))[0]


# ----------------------------------------------------------------------------- scene

@dataclass
class Scene:
    """Surfaces of one layout plus what the renderer and the trajectory need.

    ``manhattan_headings``: world heading (rad) of each local Manhattan frame, by id.
    ``path``: the robot's nominal path (corridor centre line with rounded corners).
    ``lamps``: (K, 2) ceiling lamp positions (x, y) for the light map.
    ``look_alike``: ``aliased`` only: ``(x0, x1, shift)``, the stretch ``x0 <= x <= x1`` of
    corridor A (on ``y = 0``) that reappears, identical, moved by ``shift`` (2,) (corridor B).
    """

    layout: str
    surfaces: list[Surface]
    manhattan_headings: list[float]
    path: RoundedPath
    lamps: np.ndarray
    ceiling_height: float
    bounds: tuple[float, float, float, float]
    look_alike: tuple | None = None

    def mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``vertices`` (4S, 3) float32, ``triangles`` (2S, 3) uint32, ``tri_surface`` (2S,) int32."""
        V = np.concatenate([s.corners() for s in self.surfaces]).astype(np.float32)
        base = 4 * np.arange(len(self.surfaces), dtype=np.uint32)[:, None]
        F = np.concatenate([base + np.array([0, 1, 2], np.uint32), base + np.array([0, 2, 3], np.uint32)], 1)
        return V, F.reshape(-1, 3), np.repeat(np.arange(len(self.surfaces), dtype=np.int32), 2)


def _offset_polyline(P: np.ndarray, off: float, closed: bool) -> np.ndarray:
    """Offset of a polyline to its left by ``off`` metres (miter joins)."""
    M = len(P)
    edges = [(i, (i + 1) % M) for i in range(M if closed else M - 1)]
    normals = [_left(_unit(P[b] - P[a])) for a, b in edges]
    out = []
    for i in range(M):
        if closed:
            n0, n1 = normals[i - 1], normals[i]
        else:
            n0 = normals[max(i - 1, 0)]
            n1 = normals[min(i, len(normals) - 1)]
        out.append(P[i] + off * (n0 + n1) / (1.0 + float(n0 @ n1)))
    return np.array(out)


class _Builder:
    def __init__(self, layout: str, rng: np.random.Generator, height: float, headings: list[float]):
        self.layout, self.rng, self.h, self.headings = layout, rng, height, headings
        self.surfaces: list[Surface] = []
        self.walls: list[tuple[np.ndarray, np.ndarray, int, np.ndarray]] = []  # q0, q1, mframe, tint
        self.boxes: list[tuple[np.ndarray, float]] = []  # footprint centre, radius
        # pale paint colours (BGR multipliers), one per local Manhattan frame
        pick = rng.permutation(len(_PAINTS))
        self.paints = [np.array(_PAINTS[pick[k % len(_PAINTS)]]) for k in range(len(headings))]

    def frame_of(self, d) -> int:
        ang = math.atan2(d[1], d[0])
        diffs = [abs(float((ang - h + math.pi / 4) % (math.pi / 2) - math.pi / 4)) for h in self.headings]
        k = int(np.argmin(diffs))
        if diffs[k] > math.radians(1.0):
            raise ValueError(f"wall direction {math.degrees(ang):.1f} deg matches no Manhattan frame of "
                             f"layout {self.layout!r}")
        return k

    def ring(self, Q: np.ndarray) -> None:
        """Walls along a closed ring of 2-D points, free space on the left of each edge."""
        for i in range(len(Q)):
            self.wall(Q[i], Q[(i + 1) % len(Q)])

    def wall(self, q0, q1) -> None:
        """One wall from ``q0`` to ``q1`` (2-D), free space on its left; tint and texture offset drawn."""
        q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
        ln = float(np.linalg.norm(q1 - q0))
        if ln < 1e-6:
            return
        d = (q1 - q0) / ln
        k = self.frame_of(d)
        tint = self.paints[k] * (1.0 + self.rng.normal(0.0, 0.01))
        self.surfaces.append(Surface(
            LABEL_WALL, MAT_WALL, np.array([q1[0], q1[1], 0.0]), np.array([-d[0], -d[1], 0.0]), _Z.copy(),
            (ln, self.h), mframe=k, tint=tint, offset=(float(self.rng.uniform(0, 5.12)), 0.0)))
        self.walls.append((q0, q1, k, tint))

    def floor_and_ceiling(self, margin: float = 0.5) -> tuple[float, float, float, float]:
        pts = np.array([w[0] for w in self.walls])
        x0, y0 = pts.min(0) - margin
        x1, y1 = pts.max(0) + margin
        self.surfaces.append(Surface(LABEL_FLOOR, MAT_FLOOR, np.array([x0, y0, 0.0]), np.array([1.0, 0, 0]),
                                     np.array([0, 1.0, 0]), (x1 - x0, y1 - y0),
                                     offset=tuple(self.rng.uniform(0, 10.24, 2))))
        # axis_u = y, axis_v = x: normal = y x x = -z, facing down into the room
        self.surfaces.append(Surface(LABEL_CEILING, MAT_CEILING, np.array([x0, y0, self.h]), np.array([0, 1.0, 0]),
                                     np.array([1.0, 0, 0]), (y1 - y0, x1 - x0)))
        return (float(x0), float(y0), float(x1), float(y1))

    def decorate_walls(self, n_posters: int, n_doors: int, door_p=0.22, poster_p=0.42, door_proud=0.012,
                       poster_proud=0.004, walls=None) -> None:
        """Doors and posters (standing ``door_proud`` / ``poster_proud`` m out) along every wall
        longer than 1 m (of ``walls``, default all)."""
        rng = self.rng
        for q0, q1, k, tint in (self.walls if walls is None else walls):
            ln = float(np.linalg.norm(q1 - q0))
            if ln < 1.0:
                continue
            d = (q1 - q0) / ln
            n = _left(d)
            u_axis = np.array([-d[0], -d[1], 0.0])
            pos = rng.uniform(0.25, 0.9)
            while pos < ln - 0.35:
                r = rng.random()
                if r < door_p and pos + 0.9 < ln - 0.35:
                    w, hh, bottom, off = 0.9, min(2.05, self.h - 0.15), 0.0, door_proud
                    mat, design = MAT_DOOR, int(rng.integers(n_doors))
                elif r < door_p + poster_p:
                    w = float(rng.uniform(0.4, 0.9))
                    hh = float(min(w * rng.uniform(0.75, 1.35), 1.0))
                    bottom = float(min(rng.uniform(1.0, 1.45), self.h - 0.1 - hh))
                    off, mat, design = poster_proud, MAT_POSTER, int(rng.integers(n_posters))
                    if pos + w > ln - 0.35:
                        break
                else:
                    pos += float(rng.uniform(0.4, 1.2))
                    continue
                foot = q1 - d * pos + n * off  # the wall's u runs from q1 toward q0
                self.surfaces.append(Surface(LABEL_WALL, mat, np.array([foot[0], foot[1], bottom]), u_axis.copy(),
                                             _Z.copy(), (w, hh), mframe=k, design=design, tint=tint))
                pos += w + float(rng.uniform(0.3, 1.5))

    def add_box(self, centre, yaw: float, sx: float, sy: float, sz: float, z0: float, n_designs: int) -> None:
        """A box (4 sides and a top) with footprint ``sx`` x ``sy`` turned by ``yaw``, base at ``z0``."""
        c, s = math.cos(yaw), math.sin(yaw)
        ax, ay = np.array([c, s]), np.array([-s, c])
        for nrm, half, width in ((ax, sx / 2, sy), (-ax, sx / 2, sy), (ay, sy / 2, sx), (-ay, sy / 2, sx)):
            u = _left(nrm)  # viewer's right when facing the face
            mid = centre + nrm * half
            o = mid - u * width / 2
            self.surfaces.append(Surface(LABEL_OTHER, MAT_BOX, np.array([o[0], o[1], z0]), np.array([u[0], u[1], 0.0]),
                                         _Z.copy(), (width, sz), design=int(self.rng.integers(n_designs))))
        o = centre - ax * sx / 2 - ay * sy / 2
        self.surfaces.append(Surface(LABEL_OTHER, MAT_BOX, np.array([o[0], o[1], z0 + sz]), np.array([ax[0], ax[1], 0.0]),
                                     np.array([ay[0], ay[1], 0.0]), (sx, sy), design=int(self.rng.integers(n_designs))))

    def _fits(self, corners: np.ndarray, centre, radius: float, path_pts: np.ndarray, clearance: float) -> bool:
        dist = np.linalg.norm(path_pts[None, :, :] - np.vstack([corners, centre])[:, None, :], axis=2)
        if dist.min() < clearance:
            return False
        return all(np.linalg.norm(centre - c) > radius + r + 0.05 for c, r in self.boxes)

    def boxes_along_walls(self, per_metre: float, path_pts, clearance: float, n_designs: int, walls=None) -> None:
        rng = self.rng
        for q0, q1, _, _ in (self.walls if walls is None else walls):
            ln = float(np.linalg.norm(q1 - q0))
            if ln < 1.6:
                continue
            d = (q1 - q0) / ln
            n = _left(d)
            for _ in range(int(rng.poisson(per_metre * ln))):
                sx, sy, sz = rng.uniform(0.2, 0.4), rng.uniform(0.3, 0.6), rng.uniform(0.2, 0.6)
                along = rng.uniform(0.6, ln - 0.6)
                yaw = math.atan2(n[1], n[0]) + rng.uniform(-0.12, 0.12)
                centre = q0 + d * along + n * (rng.uniform(0.02, 0.05) + sx / 2 + 0.03)
                self._place_box(centre, yaw, sx, sy, sz, path_pts, clearance, n_designs)

    def _place_box(self, centre, yaw, sx, sy, sz, path_pts, clearance, n_designs) -> bool:
        c, s = math.cos(yaw), math.sin(yaw)
        ax, ay = np.array([c, s]), np.array([-s, c])
        corners = np.array([centre + ax * a * sx / 2 + ay * b * sy / 2 for a in (-1, 1) for b in (-1, 1)])
        radius = 0.5 * math.hypot(sx, sy)
        if not self._fits(corners, centre, radius, path_pts, clearance):
            return False
        self.boxes.append((np.asarray(centre), radius))
        self.add_box(centre, yaw, sx, sy, sz, 0.0, n_designs)
        if self.rng.random() < 0.25:  # a smaller box stacked on top
            f = self.rng.uniform(0.6, 0.9)
            self.add_box(centre + self.rng.uniform(-0.03, 0.03, 2), yaw + self.rng.uniform(-0.2, 0.2),
                         sx * f, sy * f, sz * self.rng.uniform(0.5, 1.0), sz, n_designs)
        return True

    def pillar(self, centre, radius: float, n_facets: int = 20) -> None:
        """A round pillar as ``n_facets`` flat facets (label other, concrete)."""
        ang = 2 * np.pi * np.arange(n_facets + 1) / n_facets
        q = centre + radius * np.stack([np.cos(ang), np.sin(ang)], -1)
        flen = float(np.linalg.norm(q[1] - q[0]))
        for k in range(n_facets):
            u = (q[k + 1] - q[k]) / flen
            self.surfaces.append(Surface(LABEL_OTHER, MAT_CONCRETE, np.array([q[k][0], q[k][1], 0.0]),
                                         np.array([u[0], u[1], 0.0]), _Z.copy(), (flen, self.h),
                                         offset=(k * flen, 0.0)))
        self.boxes.append((np.asarray(centre, float), radius))


def _polyline_samples(P: np.ndarray, step: float, closed: bool) -> np.ndarray:
    """(n, 2) points every ``step`` metres along a polyline (starting ``step / 2`` in)."""
    Q = np.vstack([P, P[:1]]) if closed else P
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.arange(step / 2, cum[-1], step)
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    t = ((s - cum[k]) / seg[k])[:, None]
    return Q[k] * (1 - t) + Q[k + 1] * t


def _corridor_rings(P: np.ndarray, width: float, closed: bool) -> list[np.ndarray]:
    left, right = _offset_polyline(P, width / 2, closed), _offset_polyline(P, -width / 2, closed)
    if closed:
        return [right, left[::-1]]
    return [np.vstack([right, left[::-1]])]


_MIN_LOOP_WIDTH = 1.4


def _loop_min_half(turn_radius: float, corridor_width: float) -> float:
    """Least ``a + b`` (m) of the ``loop`` layout's centre-line rectangle: the short side
    ``b = 0.4 (a + b)`` keeps an inner block of 0.6 m beside a corridor of up to
    ``_MIN_LOOP_WIDTH``, and both sides hold the two quarter arcs of their corners
    (tangent length ``r`` each, so ``a, b >= 2 r``; ``build_scene`` lengthens ``b`` to ``2 r``)."""
    return max((min(corridor_width, _MIN_LOOP_WIDTH) + 0.6) / 0.4, 4.0 * turn_radius)


def _building_sides(lap: float, r: float, w: float) -> tuple[float, float, float, float]:
    """``(A, B, nx, ny)`` (m) of the ``building`` centre line: an A x B rectangle (A along x)
    with an nx x ny notch cut from one corner, whose rounded path is ``lap`` metres long.

    The notch keeps the perimeter 2 (A + B); each of the six 90 deg corners shortens the
    path by ``r (2 - pi / 2)``."""
    half = (lap + 6.0 * r * (2.0 - math.pi / 2)) / 2.0
    A, B = 0.6 * half, 0.4 * half
    return A, B, 0.35 * A, 0.4 * B


def _building_min_lap(r: float, w: float) -> float:
    """Shortest lap (m) of ``building``: every edge holds its two arcs (>= 2 r) and the block
    is at least 0.6 m thick next to the notch (B - ny, A - nx >= w + 0.6)."""
    need_b = max(2.0 * r / 0.4, (w + 0.6) / 0.6)          # ny = 0.4 B, B - ny = 0.6 B
    need_a = max(2.0 * r / 0.35, (w + 0.6) / 0.65)        # nx = 0.35 A, A - nx = 0.65 A
    half = max(need_b / 0.4, need_a / 0.6)
    return 2.0 * half - 6.0 * r * (2.0 - math.pi / 2)


def _aliased_gaps(r: float, w: float) -> tuple[float, float, float]:
    """``(g, g2, D)`` of ``aliased``: corridor A's look-alike stretch ends ``g`` before the
    connector's centre line, B's starts ``g2`` after it (past the arc), and the connector is
    ``D`` long (its two arcs and a 0.6 m straight)."""
    return w / 2 + 0.3, r + w / 2 + 0.3, 2.0 * r + 0.6


def _aliased_module(path_length: float, r: float, w: float) -> float:
    """Length (m) of each of the two look-alike corridor stretches of ``aliased``."""
    g, g2, D = _aliased_gaps(r, w)
    return (path_length - g - g2 - D + 4.0 * r - math.pi * r) / 2.0


def min_path_length(layout: str, turn_radius: float = 0.9, corridor_width: float = 2.0,
                    laps: float = 1.0) -> float:
    """Shortest path (m) a layout can be built for (``laps`` times a lap for closed layouts)."""
    r = turn_radius
    if layout == "building":
        return laps * _building_min_lap(r, corridor_width)
    if layout == "aliased":
        g, g2, D = _aliased_gaps(r, corridor_width)
        return 2.0 * ALIASED_MIN_MODULE_M + g + g2 + D - 4.0 * r + math.pi * r
    return {"straight": 0.5, "lturn": 2 * r + 1.0, "two_frames": 2 * r + 1.0,
            "loop": laps * (2 * _loop_min_half(r, corridor_width) - 8 * r + 2 * math.pi * r),
            "hall": math.pi * 1.5 + 2.0}[layout]


def build_scene(layout: str, path_length: float, seed: int, *, corridor_width: float = 2.0,
                ceiling_height: float = 2.6, turn_radius: float = 0.9, clearance: float = 0.57,
                n_posters: int = 24, n_doors: int = 4, n_box_designs: int = 12, door_proud: float = 0.012,
                poster_proud: float = 0.004, box_density: float = 0.2, branch_angle_deg: float = 60.0) -> Scene:
    """Build ``layout`` for a path of ``path_length`` metres (one lap of the closed layouts
    ``loop`` and ``building``; deterministic for ``seed``).

    ``clearance``: minimum distance (m) of boxes and pillars from the nominal path.
    Raises ``ValueError`` if the path is too short for the layout.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"layout {layout!r} is not one of {LAYOUTS}")
    need = min_path_length(layout, turn_radius, corridor_width)
    if path_length < need:
        raise ValueError(f"layout {layout!r} needs a path of at least {need:.1f} m, got {path_length:.1f} m")
    rng = np.random.default_rng([int(seed), 1031])
    r, w, L = turn_radius, corridor_width, path_length
    if layout in ("building", "aliased"):
        build = _build_building if layout == "building" else _build_aliased
        return build(rng, L, r, w, ceiling_height, clearance, n_posters, n_doors, n_box_designs, door_proud,
                     poster_proud, box_density)
    headings = [0.0]
    closed = False
    h = ceiling_height
    if layout == "straight":
        P = np.array([[0.0, 0.0], [L, 0.0]])
        C = np.array([[-3.0, 0.0], [L + 6.0, 0.0]])
    elif layout in ("lturn", "two_frames"):
        turn = math.pi / 2 if layout == "lturn" else math.radians(branch_angle_deg)
        if layout == "two_frames":
            headings = [0.0, turn]
        T = r * math.tan(turn / 2)
        Lp = L + 2 * T - r * turn
        a = max(0.55 * Lp, T + 0.3)
        b = Lp - a
        d2 = np.array([math.cos(turn), math.sin(turn)])
        P = np.array([[0.0, 0.0], [a, 0.0], [a, 0.0] + b * d2])
        C = np.array([[-3.0, 0.0], [a, 0.0], [a, 0.0] + (b + 6.0) * d2])
    elif layout == "loop":
        s = (L + 8 * r - 2 * math.pi * r) / 2  # a + b of the centre-line rectangle
        # the short side holds two quarter arcs (tangent length r each): a wide corner radius
        # (a fast robot, speed / max_yaw_rate) on a short lap needs more than 0.4 s
        b = max(0.4 * s, 2.0 * r)
        a = s - b
        w = min(w, b - 0.6)  # keep a solid inner block of at least 0.6 m
        P = np.array([[-a / 2, 0.0], [a / 2, 0.0], [a / 2, b], [-a / 2, b]])
        C, closed = P, True
    else:  # hall: a U-turn in an open hall
        ru = 1.5
        a = (L - math.pi * ru) / 2
        P = np.array([[0.0, 0.0], [a + ru, 0.0], [a + ru, 2 * ru], [0.0, 2 * ru]])
        h = max(ceiling_height, 4.0)
    path = RoundedPath(P, 1.5 if layout == "hall" else r, closed=closed)
    B = _Builder(layout, rng, h, headings)
    path_pts = path.samples(0.1)
    if layout == "hall":
        x0, x1 = -4.5, P[1, 0] + 3.0  # walls come into range at the U-turn only
        y0, y1 = -5.5, 2 * 1.5 + 5.5
        B.ring(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
        bounds = B.floor_and_ceiling()
        B.decorate_walls(n_posters, n_doors, door_p=0.15, poster_p=0.3, door_proud=door_proud,
                         poster_proud=poster_proud)
        B.boxes_along_walls(0.15, path_pts, clearance, n_box_designs)
        sp = 3.6
        off = rng.uniform(0, sp, 2)
        for gx in np.arange(x0 + 1.2 + off[0] % sp, x1 - 1.0, sp):
            for gy in np.arange(y0 + 1.2 + off[1] % sp, y1 - 1.0, sp):
                c = np.array([gx, gy])
                if np.linalg.norm(path_pts - c, axis=1).min() > 1.2:
                    B.pillar(c, 0.25)
        tries = 0
        placed = 0
        target = int(round((x1 - x0) * (y1 - y0) / 10.0))
        while placed < target and tries < 20 * target:
            tries += 1
            c = np.array([rng.uniform(x0 + 0.5, x1 - 0.5), rng.uniform(y0 + 0.5, y1 - 0.5)])
            if B._place_box(c, rng.uniform(-np.pi, np.pi), rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.7),
                            rng.uniform(0.25, 0.8), path_pts, 0.9, n_box_designs):
                placed += 1
        lx = np.arange(x0 + 2.0, x1 - 1.0, 4.0)
        ly = np.arange(y0 + 2.0, y1 - 1.0, 4.0)
        lamps = np.stack(np.meshgrid(lx, ly), -1).reshape(-1, 2)
    else:
        for ring in _corridor_rings(C, w, closed):
            B.ring(ring)
        bounds = B.floor_and_ceiling()
        B.decorate_walls(n_posters, n_doors, door_proud=door_proud, poster_proud=poster_proud)
        B.boxes_along_walls(box_density, path_pts, clearance, n_box_designs)
        lamps = _polyline_samples(C, 2.4, closed)
    return Scene(layout, B.surfaces, headings, path, lamps, h, bounds)


def _build_building(rng, L, r, w, h, clearance, n_posters, n_doors, n_box_designs, door_proud, poster_proud,
                    box_density) -> Scene:
    """``building``: a ring of corridors round a block with a notch cut from one corner, one
    lap ``L`` metres; the path starts in the middle of the longest side (so a robot driving
    more than a lap revisits its start on a straight). Doors and posters come from
    ``BUILDING_DOOR_DESIGNS`` / ``BUILDING_POSTER_DESIGNS`` designs only, so they repeat."""
    need = _building_min_lap(r, w)
    if L < need - 1e-9:
        raise ValueError(f"layout 'building' needs a lap of at least {need:.1f} m, got {L:.1f} m")
    A, B_, nx, ny = _building_sides(L, r, w)
    # counter-clockwise, free space on the left; the notch takes the corner at (A/2, B)
    P = np.array([[-A / 2, 0.0], [A / 2, 0.0], [A / 2, B_ - ny], [A / 2 - nx, B_ - ny], [A / 2 - nx, B_],
                  [-A / 2, B_]])
    path = RoundedPath(P, r, closed=True)
    B = _Builder("building", rng, h, [0.0])
    for ring in _corridor_rings(P, w, True):
        B.ring(ring)
    bounds = B.floor_and_ceiling()
    B.decorate_walls(min(n_posters, BUILDING_POSTER_DESIGNS), min(n_doors, BUILDING_DOOR_DESIGNS),
                     door_proud=door_proud, poster_proud=poster_proud)
    B.boxes_along_walls(box_density, path.samples(0.1), clearance, n_box_designs)
    return Scene("building", B.surfaces, [0.0], path, _polyline_samples(P, 2.4, True), h, bounds)


def _minus_interval(q0: np.ndarray, q1: np.ndarray, lo: float, hi: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pieces of the x-aligned wall ``q0 -> q1`` outside ``lo <= x <= hi``, in the wall's direction."""
    a, b = sorted((float(q0[0]), float(q1[0])))
    keep = [(a, min(b, lo)), (max(a, hi), b)]
    pieces = [(np.array([x0, q0[1]]), np.array([x1, q0[1]])) for x0, x1 in keep if x1 - x0 > 1e-6]
    if q1[0] < q0[0]:
        pieces = [(p1, p0) for p0, p1 in reversed(pieces)]
    return pieces


def _translated(surfaces: list[Surface], shift) -> list[Surface]:
    """Copies of ``surfaces`` moved by ``shift`` (2-D): same sizes, designs, tints and texture offsets."""
    d = np.array([shift[0], shift[1], 0.0])
    return [Surface(s.label, s.material, s.origin + d, s.axis_u.copy(), s.axis_v.copy(), s.size, s.mframe,
                    s.design, s.tint.copy(), s.offset) for s in surfaces]


def _split_rect(rect, holes) -> list[tuple[float, float, float, float]]:
    """Rectangles ``(x0, y0, x1, y1)`` covering ``rect`` minus ``holes`` (inside it, disjoint in x)."""
    x0, y0, x1, y1 = rect
    out, x = [], x0
    for hx0, hy0, hx1, hy1 in sorted(holes):
        out += [(x, y0, hx0, y1), (hx0, y0, hx1, hy0), (hx0, hy1, hx1, y1)]
        x = hx1
    out.append((x, y0, x1, y1))
    return [r for r in out if r[2] - r[0] > 1e-6 and r[3] - r[1] > 1e-6]


def _tiled_floor_and_ceiling(B: _Builder, hole_a, shift) -> tuple[float, float, float, float]:
    """Floor and ceiling as rectangles with world-fixed texture, except that the rectangle
    ``hole_a`` moved by ``shift`` repeats the texture of ``hole_a`` (look-alike corridors)."""
    pts = np.array([q for w in B.walls for q in w[:2]])
    x0, y0 = pts.min(0) - 0.5
    x1, y1 = pts.max(0) + 0.5
    off = B.rng.uniform(0, 10.24, 2)
    hole_b = (hole_a[0] + shift[0], hole_a[1] + shift[1], hole_a[2] + shift[0], hole_a[3] + shift[1])
    rects = [(r, r) for r in _split_rect((x0, y0, x1, y1), [hole_a, hole_b]) + [hole_a]] + [(hole_b, hole_a)]
    for (rx0, ry0, rx1, ry1), (tx0, ty0, _, _) in rects:  # (where, whose texture)
        B.surfaces.append(Surface(LABEL_FLOOR, MAT_FLOOR, np.array([rx0, ry0, 0.0]), np.array([1.0, 0, 0]),
                                  np.array([0, 1.0, 0]), (rx1 - rx0, ry1 - ry0),
                                  offset=(float(off[0] + tx0 - x0), float(off[1] + ty0 - y0))))
        B.surfaces.append(Surface(LABEL_CEILING, MAT_CEILING, np.array([rx0, ry0, B.h]), np.array([0, 1.0, 0]),
                                  np.array([1.0, 0, 0]), (ry1 - ry0, rx1 - rx0),
                                  offset=(float(ty0 - y0), float(tx0 - x0))))
    return (float(x0), float(y0), float(x1), float(y1))


def _build_aliased(rng, L, r, w, h, clearance, n_posters, n_doors, n_box_designs, door_proud, poster_proud,
                   box_density) -> Scene:
    """``aliased``: two corridors that look the same at different places (perceptual aliasing).

    The path drives east along corridor A, turns left into a short connector and right into
    corridor B, parallel to A and further east, and never comes back. A stretch of ``La``
    metres of B (from ``g2`` past the connector) is a copy of the first ``La`` metres of A
    moved by ``(xb, D)``: walls with their texture offsets and tints, doors, posters, boxes,
    floor and ceiling tiles and lamps; seen with the same heading, so a place recogniser
    that matches B to A is wrong (no place of B is a place of A)."""
    La = _aliased_module(L, r, w)
    if La < ALIASED_MIN_MODULE_M - 1e-9:
        raise ValueError(f"layout 'aliased' needs two corridors of at least {ALIASED_MIN_MODULE_M} m, "
                         f"got {La:.1f} m")
    g, g2, D = _aliased_gaps(r, w)
    X1 = La + g
    xb = X1 + g2
    shift = np.array([xb, D])
    path = RoundedPath(np.array([[0.0, 0.0], [X1, 0.0], [X1, D], [xb + La, D]]), r)
    path_pts = path.samples(0.1)
    B = _Builder("aliased", rng, h, [0.0])
    n0 = len(B.surfaces)
    B.wall((0.0, -w / 2), (La, -w / 2))  # corridor A's right wall, then its left (free space on the left)
    B.wall((La, w / 2), (0.0, w / 2))
    module = list(B.walls)
    B.decorate_walls(n_posters, n_doors, door_proud=door_proud, poster_proud=poster_proud, walls=module)
    B.boxes_along_walls(box_density, path_pts, clearance, n_box_designs, walls=module)
    B.surfaces.extend(_translated(B.surfaces[n0:], shift))
    B.boxes.extend([(c + shift, rad) for c, rad in B.boxes])
    B.walls.extend([(q0 + shift, q1 + shift, k, t) for q0, q1, k, t in module])
    # B ends in a wall as far past its look-alike stretch as the connector's far wall is past A's,
    # so that the view down the corridor ends alike too
    C = np.array([[-3.0, 0.0], [X1, 0.0], [X1, D], [xb + La + g + w / 2, D]])
    rest = _aliased_other_walls(B, C, w, La, xb, D)
    B.decorate_walls(n_posters, n_doors, door_proud=door_proud, poster_proud=poster_proud, walls=rest)
    B.boxes_along_walls(box_density, path_pts, clearance, n_box_designs, walls=rest)
    bounds = _tiled_floor_and_ceiling(B, (0.0, -w / 2, La, w / 2), shift)
    lamps_a = np.column_stack([np.arange(1.2, La, 2.4), np.zeros(len(np.arange(1.2, La, 2.4)))])
    others = _polyline_samples(C, 2.4, False)
    far = np.array([not ((abs(p[1]) < 1e-6 and -1.2 < p[0] < La + 1.2)
                         or (abs(p[1] - D) < 1e-6 and xb - 1.2 < p[0] < xb + La + 1.2)) for p in others])
    lamps = np.vstack([lamps_a, lamps_a + shift, others[far]])
    return Scene("aliased", B.surfaces, [0.0], path, lamps, h, bounds, (0.0, La, shift))


def _aliased_other_walls(B: _Builder, C: np.ndarray, w: float, La: float, xb: float, D: float) -> list:
    """Walls of the Z-shaped corridor ``C`` except the two look-alike stretches; returns them."""
    Q = _corridor_rings(C, w, False)[0]
    rest = []
    for i in range(len(Q)):
        pieces = [(Q[i], Q[(i + 1) % len(Q)])]
        if abs(Q[i][1] - Q[(i + 1) % len(Q)][1]) < 1e-9:  # along x: may hold a look-alike stretch
            if abs(abs(Q[i][1]) - w / 2) < 1e-6:
                pieces = [p for a, b in pieces for p in _minus_interval(a, b, 0.0, La)]
            if abs(abs(Q[i][1] - D) - w / 2) < 1e-6:
                pieces = [p for a, b in pieces for p in _minus_interval(a, b, xb, xb + La)]
        for a, b in pieces:
            n = len(B.walls)
            B.wall(a, b)
            rest.extend(B.walls[n:])
    return rest
