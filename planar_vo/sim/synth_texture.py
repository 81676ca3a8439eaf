"""Procedural textures for the synthetic corridor renderer (:mod:`planar_vo.sim.synth`).

Every material is a numpy/OpenCV-generated image with a mip pyramid, sampled by the
renderer at the hit point's surface coordinates, so texture stays fixed to the world
and features are trackable across frames:

* periodic materials (floor tiles, wall paint, ceiling tiles, concrete) at
  :data:`TEXEL` metres per texel, tiling without seams (noise is built on wrapped grids);
* a decal atlas of posters, doors and box faces, one cell per design, each cell
  stretched over its surface, with gutters so that coarse mip levels do not bleed.

``texture`` levels: ``low`` (faint mottling, grout only, washed-out posters), ``medium``
and ``rich`` (stronger noise, terrazzo chips, scuff marks, a chair rail). ``none`` needs
no images: the renderer paints :data:`FLAT_COLORS` per surface.
All colours are BGR, images ``(h, w, 3) uint8``. Deterministic for a seed.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: metres per texel of the periodic materials at mip level 0.
TEXEL = 0.005
#: texture ids (index into :attr:`TextureSet.textures`).
TEX_FLOOR, TEX_WALL, TEX_CEILING, TEX_CONCRETE, TEX_ATLAS = range(5)
TEXTURE_LEVELS = ("none", "low", "medium", "rich")

#: Mean BGR colour of each material; the whole surface colour for ``texture="none"``.
FLAT_COLORS = {
    "floor": (150.0, 163.0, 172.0),
    "wall": (222.0, 226.0, 228.0),
    "ceiling": (232.0, 232.0, 232.0),
    "concrete": (150.0, 152.0, 155.0),
    "box": (92.0, 138.0, 178.0),
}

_LEVEL = {  # appearance strength per level
    "low": dict(contrast=0.35, chips=0.0, scuffs=0, decal_contrast=0.45, blank=0.4, rail=False),
    "medium": dict(contrast=1.0, chips=0.015, scuffs=14, decal_contrast=1.0, blank=0.1, rail=False),
    "rich": dict(contrast=1.7, chips=0.04, scuffs=40, decal_contrast=1.0, blank=0.0, rail=True),
}

_CELL = 256         # decal cell size in texels (doors take two cells stacked)
_GUTTER = 8         # replicated border around each cell
_ATLAS_COLS = 8
N_POSTERS, N_DOORS, N_BOXES = 24, 4, 12


@dataclass
class Texture:
    """One material: ``levels[l]`` is the image at mip level ``l`` (half size per level).

    ``packed`` holds every level in one image (level 0 on the left, the others stacked
    in a column to its right), each framed by a 1-texel border (wrapped copies for
    periodic textures, replicated edges otherwise), so a single ``cv2.remap`` call can
    sample different levels per pixel. ``ox``/``oy`` (float32, per level) locate each
    level's texel (0, 0) in ``packed``; ``w``/``h`` are the level sizes.
    """

    levels: list[np.ndarray]
    periodic: bool

    def __post_init__(self) -> None:
        P = 1
        border = cv2.BORDER_WRAP if self.periodic else cv2.BORDER_REPLICATE
        h0, w0 = self.levels[0].shape[:2]
        rest_h = sum(lv.shape[0] + 2 * P for lv in self.levels[1:])
        rest_w = self.levels[1].shape[1] + 2 * P if len(self.levels) > 1 else 0
        packed = np.zeros((max(h0 + 2 * P, rest_h), w0 + 2 * P + rest_w, 3), np.uint8)
        ox, oy = [], []
        y = 0
        for i, lv in enumerate(self.levels):
            h, w = lv.shape[:2]
            x0, y0 = (0, 0) if i == 0 else (w0 + 2 * P, y)
            packed[y0:y0 + h + 2 * P, x0:x0 + w + 2 * P] = cv2.copyMakeBorder(lv, P, P, P, P, border)
            ox.append(x0 + P)
            oy.append(y0 + P)
            if i > 0:
                y += h + 2 * P
        self.packed = packed
        self.ox, self.oy = np.array(ox, np.float32), np.array(oy, np.float32)
        self.w = np.array([lv.shape[1] for lv in self.levels], np.float32)
        self.h = np.array([lv.shape[0] for lv in self.levels], np.float32)
        self.scale = np.array([0.5 ** i for i in range(len(self.levels))], np.float32)

    @property
    def shape(self) -> tuple[int, int]:
        return self.levels[0].shape[:2]


@dataclass
class TextureSet:
    """All materials of one scene. ``*_cells``: ``(x0, y0, w, h)`` texel boxes in the atlas."""

    level: str
    textures: list[Texture]
    poster_cells: list[tuple[int, int, int, int]]
    door_cells: list[tuple[int, int, int, int]]
    box_cells: list[tuple[int, int, int, int]]


# ----------------------------------------------------------------------------- noise

def periodic_noise(rng: np.random.Generator, h: int, w: int, cell: int) -> np.ndarray:
    """Smooth noise (h, w) float32, roughly unit variance, periodic with period (h, w).

    Value noise: a Gaussian grid with spacing ``cell`` texels, wrap-padded and upsampled
    bicubically, so the result tiles without a seam. ``h`` and ``w`` must be multiples of
    ``cell``.
    """
    if cell <= 1:
        return rng.standard_normal((h, w), dtype=np.float32)
    gh, gw = h // cell, w // cell
    pad = 2
    grid = np.pad(rng.standard_normal((gh, gw), dtype=np.float32), pad, mode="wrap")
    big = cv2.resize(grid, ((gw + 2 * pad) * cell, (gh + 2 * pad) * cell), interpolation=cv2.INTER_CUBIC)
    out = big[pad * cell: pad * cell + h, pad * cell: pad * cell + w]
    return out / max(float(out.std()), 1e-6)


def fbm(rng, h: int, w: int, cells, amps) -> np.ndarray:
    """Sum of :func:`periodic_noise` octaves (h, w) float32 with the given amplitudes."""
    out = np.zeros((h, w), np.float32)
    for c, a in zip(cells, amps):
        if a:
            out += np.float32(a) * periodic_noise(rng, h, w, c)
    return out


def _chips(rng, h: int, w: int, fraction: float, cell: int = 3) -> np.ndarray:
    """Boolean mask (h, w) of small blobs (a few texels) covering ~``fraction`` of the image."""
    if fraction <= 0:
        return np.zeros((h, w), bool)
    n = periodic_noise(rng, h, w, cell)
    return n > np.quantile(n[::7, ::7], 1.0 - fraction)


def _to_u8(img: np.ndarray) -> np.ndarray:
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def _pyramid(img: np.ndarray, n_levels: int) -> list[np.ndarray]:
    """Mip pyramid by 2x2 box averaging (keeps periodic images periodic)."""
    levels = [img]
    for _ in range(n_levels - 1):
        h, w = levels[-1].shape[:2]
        if h < 4 or w < 4:
            break
        levels.append(cv2.resize(levels[-1], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    return levels


# -------------------------------------------------------------------------- materials

def _floor(rng, p) -> np.ndarray:
    """Vinyl/terrazzo tiles: 0.64 m tiles (128 texels), grout, mottling, chips."""
    S, tile = 2048, 128
    c = p["contrast"]
    base = np.array(FLAT_COLORS["floor"], np.float32)
    nt = S // tile
    tile_jit = rng.normal(0.0, 9.0 * c, (nt, nt, 1)).astype(np.float32)
    tile_hue = rng.normal(0.0, 2.0 * c, (nt, nt, 3)).astype(np.float32)
    per_tile = np.repeat(np.repeat(tile_jit + tile_hue, tile, 0), tile, 1)
    mott = fbm(rng, S, S, (64, 16, 4), (6.0 * c, 5.0 * c, 3.5 * c))
    img = base + per_tile + mott[..., None] * np.array([0.9, 1.0, 1.05], np.float32)
    chips = p["chips"]
    if chips > 0:
        dark = _chips(rng, S, S, chips)
        light = _chips(rng, S, S, chips * 0.7)
        img[dark] -= np.float32(55.0)
        img[light] += np.float32(45.0)
    # grout: 2 texels (1 cm) at every tile boundary
    r = np.arange(S)
    g = ((r % tile) < 2).astype(np.float32)
    grout = np.maximum(g[:, None], g[None, :])
    img -= (grout * np.float32(30.0 * max(c, 0.5)))[..., None]
    return _to_u8(img)


def _wall(rng, p) -> np.ndarray:
    """Matt paint with mild noise, scuff marks, a 10 cm skirting board at the bottom.

    Rows run top-down; the renderer maps wall height ``v`` = 0 (floor) to the last row.
    """
    S = 1024
    c = p["contrast"]
    base = np.array(FLAT_COLORS["wall"], np.float32)
    n = fbm(rng, S, S, (128, 32, 8, 2), (3.0 * c, 2.5 * c, 2.0 * c, 1.2 * c))
    img = base + n[..., None]
    scuffs = np.zeros((S, S), np.uint8)
    for _ in range(p["scuffs"]):  # scuffs mostly below 1 m, where trolleys and shoes hit
        cx, cy = int(rng.integers(0, S)), int(S - 20 - rng.exponential(40.0))
        axes = (int(rng.uniform(3, 16)), int(rng.uniform(1, 3)))
        angle, shade = float(rng.uniform(-20, 20)), int(rng.uniform(15, 45) * min(c, 1.2))
        for dx in (-S, 0, S):  # drawn wrapped, so the texture stays periodic
            cv2.ellipse(scuffs, (cx + dx, cy), axes, angle, 0, 360, shade, -1, cv2.LINE_AA)
    img -= scuffs.astype(np.float32)[..., None]
    skirting = 20  # 10 cm
    sk = np.array((70.0, 72.0, 78.0), np.float32) + 4.0 * c * periodic_noise(rng, 32, S, 4)[:skirting, :, None]
    img[S - skirting:] = sk
    img[S - skirting - 1] -= 25.0  # top edge of the board
    if p["rail"]:  # chair rail at 0.9 m
        r0 = S - int(0.9 / TEXEL)
        img[r0 - 8: r0] = np.array((120.0, 150.0, 170.0), np.float32)
        img[r0 - 8] -= 20.0
    return _to_u8(img)


def _ceiling(rng, p) -> np.ndarray:
    S, tile = 1024, 128
    c = p["contrast"]
    img = np.array(FLAT_COLORS["ceiling"], np.float32) + fbm(rng, S, S, (32, 4), (2.0 * c, 2.0 * c))[..., None]
    g = ((np.arange(S) % tile) < 3).astype(np.float32)
    img -= (np.maximum(g[:, None], g[None, :]) * 40.0)[..., None]
    return _to_u8(img)


def _concrete(rng, p) -> np.ndarray:
    S = 512
    c = p["contrast"]
    img = np.array(FLAT_COLORS["concrete"], np.float32) + fbm(
        rng, S, S, (64, 16, 4, 1), (9.0 * c, 7.0 * c, 5.0 * c, 3.0 * c))[..., None]
    pores = _chips(rng, S, S, 0.01 * max(c, 0.3), cell=2)
    img[pores] -= 45.0
    return _to_u8(img)


def _rand_color(rng, lo=20, hi=235) -> tuple[int, int, int]:
    return tuple(int(v) for v in rng.integers(lo, hi, 3))


def _poster(rng, p) -> np.ndarray:
    """A random "image patch": photo-like field, graphic shapes, a notice or a chart."""
    S = _CELL
    kind = int(rng.integers(0, 4))
    if kind == 0:
        img = np.stack([fbm(rng, S, S, (64, 16), (50.0, 20.0)) for _ in range(3)], -1)
        img += np.array(_rand_color(rng, 60, 200), np.float32)
        img = _to_u8(img)
        for _ in range(int(rng.integers(3, 8))):
            cv2.circle(img, tuple(int(v) for v in rng.integers(20, S - 20, 2)), int(rng.integers(6, 40)),
                       _rand_color(rng), -1, cv2.LINE_AA)
    elif kind == 1:
        img = np.full((S, S, 3), _rand_color(rng, 120, 250), np.uint8)
        for _ in range(int(rng.integers(6, 14))):
            a, b = rng.integers(10, S - 10, 2), rng.integers(10, S - 10, 2)
            col = _rand_color(rng)
            if rng.random() < 0.5:
                cv2.rectangle(img, tuple(int(v) for v in a), tuple(int(v) for v in b), col,
                              -1 if rng.random() < 0.7 else 4, cv2.LINE_AA)
            else:
                cv2.circle(img, tuple(int(v) for v in a), int(rng.integers(8, 60)), col,
                           -1 if rng.random() < 0.7 else 4, cv2.LINE_AA)
    elif kind == 2:
        img = np.full((S, S, 3), 245, np.uint8)
        cv2.rectangle(img, (0, 0), (S, 46), _rand_color(rng, 20, 160), -1)
        y = 66
        while y < S - 20:
            x = 16
            while x < S - 30:
                wlen = int(rng.integers(10, 40))
                cv2.rectangle(img, (x, y), (min(x + wlen, S - 16), y + 7), (40, 40, 40), -1)
                x += wlen + int(rng.integers(6, 10))
            y += int(rng.integers(16, 26))
    else:
        img = np.full((S, S, 3), _rand_color(rng, 200, 250), np.uint8)
        n = int(rng.integers(4, 10))
        bw = (S - 50) // n
        for i in range(n):
            hgt = int(rng.integers(20, S - 60))
            cv2.rectangle(img, (30 + i * bw, S - 24 - hgt), (30 + (i + 1) * bw - 6, S - 24), _rand_color(rng), -1)
        cv2.line(img, (26, 16), (26, S - 22), (30, 30, 30), 3)
        cv2.line(img, (26, S - 22), (S - 12, S - 22), (30, 30, 30), 3)
    cv2.rectangle(img, (0, 0), (S - 1, S - 1), (250, 250, 250), 8)  # white paper margin
    return img


def _door(rng, p) -> np.ndarray:
    """Door leaf (cell 256 x 512 for 0.9 x 2.05 m): wood grain or paint, frame, handle, kick plate."""
    W, H = _CELL, 2 * _CELL
    c = max(p["contrast"], 0.3)
    if rng.random() < 0.6:
        wood = np.array(_rand_color(rng, 40, 90), np.float32) * np.array([0.6, 1.0, 1.6], np.float32)
        grain = cv2.resize(rng.standard_normal((24, 160)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
        img = wood + (10.0 * c * grain)[..., None]
    else:
        img = np.array(_rand_color(rng, 60, 220), np.float32) + fbm(rng, H, W, (64, 8), (2.0 * c, 1.5 * c))[..., None]
    img = _to_u8(img)
    frame_col = (235, 235, 235) if rng.random() < 0.5 else (60, 60, 64)
    cv2.rectangle(img, (0, 0), (W - 1, H - 1), frame_col, 14)
    cv2.rectangle(img, (14, H - 14 - 40), (W - 15, H - 15), (175, 178, 180), -1)  # kick plate
    hy = int(H * (1.0 - 1.0 / 2.05))
    cv2.rectangle(img, (W - 58, hy - 4), (W - 26, hy + 4), (190, 195, 200), -1, cv2.LINE_AA)
    cv2.circle(img, (W - 30, hy), 7, (150, 155, 160), -1, cv2.LINE_AA)
    if rng.random() < 0.4:  # narrow glass panel
        cv2.rectangle(img, (W // 2 - 20, 60), (W // 2 + 20, 200), (70, 60, 50), -1)
        cv2.rectangle(img, (W // 2 - 20, 60), (W // 2 + 20, 200), frame_col, 3)
    return img


def _box_face(rng, p) -> np.ndarray:
    """Cardboard with fibres, packing tape and sometimes a label or printed symbols."""
    S = _CELL
    c = max(p["contrast"], 0.3)
    img = np.array(FLAT_COLORS["box"], np.float32) + fbm(rng, S, S, (32, 4, 1), (5.0 * c, 4.0 * c, 2.0 * c))[..., None]
    img = _to_u8(img)
    if rng.random() < 0.7:
        y0 = int(rng.integers(90, 130))
        cv2.rectangle(img, (0, y0), (S, y0 + 36), (120, 165, 200), -1)
    if rng.random() < 0.6:
        x0, y0 = int(rng.integers(20, 120)), int(rng.integers(150, 190))
        cv2.rectangle(img, (x0, y0), (x0 + 110, y0 + 50), (240, 240, 240), -1)
        for k in range(3):
            cv2.rectangle(img, (x0 + 8, y0 + 8 + 14 * k), (x0 + int(rng.integers(40, 100)), y0 + 14 + 14 * k),
                          (30, 30, 30), -1)
    if rng.random() < 0.5:
        x0 = int(rng.integers(20, 180))
        cv2.arrowedLine(img, (x0, 80), (x0, 20), (30, 30, 40), 6, cv2.LINE_AA, tipLength=0.4)
    return img


def _fade(img: np.ndarray, amount: float, toward=(225.0, 228.0, 230.0)) -> np.ndarray:
    """Blend an image toward a flat colour (amount 1 = unchanged, 0 = flat)."""
    if amount >= 1.0:
        return img
    t = np.array(toward, np.float32)
    return _to_u8(t + (img.astype(np.float32) - t) * np.float32(amount))


def _atlas(rng, p):
    designs = ([("poster", _poster(rng, p)) for _ in range(N_POSTERS)]
               + [("box", _box_face(rng, p)) for _ in range(N_BOXES)]
               + [("door", _door(rng, p)) for _ in range(N_DOORS)])
    stride = _CELL + 2 * _GUTTER
    small = [d for d in designs if d[0] != "door"]
    rows_small = -(-len(small) // _ATLAS_COLS)
    rows_door = -(-N_DOORS // _ATLAS_COLS)
    Wt = _ATLAS_COLS * stride
    Ht = rows_small * stride + rows_door * (2 * _CELL + 2 * _GUTTER)
    atlas = np.zeros((Ht, Wt, 3), np.uint8)
    cells = {"poster": [], "box": [], "door": []}

    def put(img, x0, y0):
        h, w = img.shape[:2]
        padded = cv2.copyMakeBorder(img, _GUTTER, _GUTTER, _GUTTER, _GUTTER, cv2.BORDER_REPLICATE)
        atlas[y0 - _GUTTER: y0 + h + _GUTTER, x0 - _GUTTER: x0 + w + _GUTTER] = padded
        return (x0, y0, w, h)

    for i, (kind, img) in enumerate(small):
        r, col = divmod(i, _ATLAS_COLS)
        if kind == "poster" and rng.random() < p["blank"]:
            img = np.full_like(img, 238)  # a plain sheet: fewer features at low texture
        img = _fade(img, p["decal_contrast"])
        cells[kind].append(put(img, col * stride + _GUTTER, r * stride + _GUTTER))
    y_doors = rows_small * stride
    for i, (kind, img) in enumerate(d for d in designs if d[0] == "door"):
        r, col = divmod(i, _ATLAS_COLS)
        img = _fade(img, max(p["decal_contrast"], 0.7))
        cells["door"].append(put(img, col * stride + _GUTTER, y_doors + r * (2 * _CELL + 2 * _GUTTER) + _GUTTER))
    return atlas, cells


_CACHE: dict[tuple[str, int], TextureSet] = {}


def build_textures(level: str, seed: int) -> TextureSet | None:
    """All material textures for ``level`` (one of :data:`TEXTURE_LEVELS`); None for ``none``.

    Cached per ``(level, seed)`` (the two most recent), since tests and benchmarks render
    several sequences with the same look.
    """
    if level not in TEXTURE_LEVELS:
        raise ValueError(f"texture level {level!r} is not one of {TEXTURE_LEVELS}")
    if level == "none":
        return None
    key = (level, int(seed))
    if key in _CACHE:
        return _CACHE[key]
    p = _LEVEL[level]
    # one independent stream per material, so adding a material never changes the others
    rngs = [np.random.default_rng([int(seed), 7331, k]) for k in range(5)]
    textures = [
        Texture(_pyramid(_floor(rngs[0], p), 7), True),
        Texture(_pyramid(_wall(rngs[1], p), 7), True),
        Texture(_pyramid(_ceiling(rngs[2], p), 6), True),
        Texture(_pyramid(_concrete(rngs[3], p), 6), True),
    ]
    atlas, cells = _atlas(rngs[4], p)
    textures.append(Texture(_pyramid(atlas, 4), False))
    ts = TextureSet(level, textures, cells["poster"], cells["door"], cells["box"])
    if len(_CACHE) >= 2:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = ts
    return ts
