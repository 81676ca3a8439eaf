"""Randomized synthetic scenes: one seed, one draw of everything a single renderer fixes.

A method tuned on one renderer's look learns that look. :func:`randomized_config` draws,
from a seeded generator, the scene (corridor width, boxes, how far doors and posters stand
out of the walls, the angle between two corridors), the path (speed, frame rate and a
wobble of several superposed weaves, heading rates up to ~10 deg/s), the mount (height,
pitch, roll), the texture and lighting, and the sensor (depth noise growing with incidence,
holes at depth edges, Kinect v2 timing effects). ``planar-vo synth --randomize`` and
``planar-vo bench sweep`` use it; tune on one range of seeds, report on another. It also
draws the ``building`` and ``aliased`` layouts (loop closure), which the sweep does not run.

The ranges are :data:`RANGES`; every draw is recorded in the returned config (and so in
the log's metadata and the sweep's report), so a failing seed can be understood.
"""
from __future__ import annotations

import math
import numpy as np

from planar_vo.sim.synth import SynthConfig, min_path_length
from planar_vo.sim.synth_scene import BUILDING_LAP_M

#: Drawn uniformly within these (inclusive) unless stated otherwise.
RANGES = {
    "corridor_width": (1.6, 2.6),        # m
    "cam_height": (0.3, 1.2),            # m
    "pitch_deg": (0.0, 25.0),            # down
    "roll_deg": (-3.0, 3.0),
    "speed": (0.2, 0.8),                 # m/s
    "rate_hz": (10.0, 15.0, 20.0, 30.0),  # one of
    "texture": {"none": 0.05, "low": 0.25, "medium": 0.40, "rich": 0.30},  # probabilities
    "wobble_heading_deg": (1.0, 6.0),    # total heading amplitude of the superposed weaves
    "wobble_wavelength": (1.0, 5.0),     # m of travel per period, 2-3 components
    "max_heading_rate_deg_s": 10.0,      # the wobble is scaled down to stay below this
    "door_proud_m": (0.003, 0.010),
    "poster_proud_m": (0.003, 0.010),
    "box_density": (0.0, 0.5),           # per metre of wall
    "branch_angle_deg": (20.0, 70.0),    # two_frames only
    "depth_incidence": (0.0, 1.0),
    "edge_dropout": (0.3, 0.85),
    "dropout_rate": (0.0005, 0.005),
    "image_noise": (1.0, 4.0),           # grey levels
    "vignetting": (0.05, 0.4),
    "light_gain": (0.6, 1.25),
    "kinect2_effects": 0.5,              # probability of timing effects and auto-exposure
    "exposure_ms": (5.0, 20.0),
    "readout_ms": (0.0, 15.0),
    "color_delay_ms": (0.0, 16.0),
    "flying_pixels": (0.0, 0.5),
    # slow-downs within the cruise (``speed_dips=True`` only): one, and one more per this
    # many seconds of cruise on average (Poisson), each taking away a share of the speed
    # over a width, widened so that it brakes at most at the deceleration given
    "speed_dip_every_s": 30.0,
    "speed_dip_depth": (0.3, 1.0),       # share of the cruise speed; 1: a momentary stop
    "speed_dip_width_s": (1.5, 5.0),
    "speed_dip_max_decel": 0.6,          # m/s^2
}

#: Frames of a randomized log: at least this many, more when the path would be shorter
#: than the layout needs or than MIN_PATH_M (drift over a couple of metres says little).
MIN_FRAMES = 300
MIN_PATH_M = 6.0


def _u(rng: np.random.Generator, key: str) -> float:
    lo, hi = RANGES[key]
    return float(rng.uniform(lo, hi))


def _wobble(rng: np.random.Generator, speed: float) -> tuple:
    """2-3 weaves ``(amplitude m, wavelength m)`` whose heading amplitudes sum to the drawn
    total and whose peak heading rate stays below the cap at ``speed``."""
    n = int(rng.integers(2, 4))
    total = math.radians(_u(rng, "wobble_heading_deg"))
    share = rng.dirichlet(np.ones(n)) * total
    lam = rng.uniform(*RANGES["wobble_wavelength"], n)
    # heading of a weave A sin(2 pi s / L): amplitude atan(2 pi A / L), rate ~ 2 pi A / L * 2 pi v / L
    rate = float(np.sum(share * 2 * math.pi * speed / lam))
    # 0.85: the path fits whole periods, which shortens a wavelength by up to ~15 %
    cap = 0.85 * math.radians(RANGES["max_heading_rate_deg_s"])
    if rate > cap:
        share *= cap / rate
    return tuple((float(math.tan(h) * L / (2 * math.pi)), float(L)) for h, L in zip(share, lam))


def randomized_config(seed: int, layout: str, *, n_frames: int | None = None,
                      min_frames: int = MIN_FRAMES, speed_dips: bool = False) -> SynthConfig:
    """A :class:`SynthConfig` of ``layout`` with everything in :data:`RANGES` drawn from
    ``seed`` (deterministic). ``n_frames``: at least this many frames (default
    ``min_frames``); more when the drawn speed and rate would not drive the layout.
    ``speed_dips``: the base also slows down within the cruise (:func:`_speed_dips`), drawn
    from a generator of their own, so every other draw of the seed stays the same."""
    rng = np.random.default_rng([int(seed), 7919, sum(map(ord, layout))])
    width = _u(rng, "corridor_width")
    speed = _u(rng, "speed")
    rate = float(rng.choice(RANGES["rate_hz"]))
    tex = RANGES["texture"]
    texture = str(rng.choice(list(tex), p=list(tex.values())))
    fields = dict(
        layout=layout, seed=int(seed), speed=speed, rate_hz=rate, texture=texture, corridor_width=width,
        cam_height=_u(rng, "cam_height"), pitch_deg=_u(rng, "pitch_deg"), roll_deg=_u(rng, "roll_deg"),
        weave=0.0, weave_components=_wobble(rng, speed),
        door_proud_m=_u(rng, "door_proud_m"), poster_proud_m=_u(rng, "poster_proud_m"),
        box_density=_u(rng, "box_density"), branch_angle_deg=_u(rng, "branch_angle_deg"),
        depth_incidence=_u(rng, "depth_incidence"), edge_dropout=_u(rng, "edge_dropout"),
        dropout_rate=_u(rng, "dropout_rate"), image_noise=_u(rng, "image_noise"),
        vignetting=_u(rng, "vignetting"), light_gain=_u(rng, "light_gain"),
    )
    if rng.random() < RANGES["kinect2_effects"]:
        period_ms = 1000.0 / rate
        exposure = min(_u(rng, "exposure_ms"), 0.5 * period_ms)
        readout = min(_u(rng, "readout_ms"), 0.3 * period_ms)
        delay = min(_u(rng, "color_delay_ms"), 0.5 * (period_ms - exposure - readout))
        fields.update(exposure_ms=exposure, readout_ms=readout, color_delay_ms=delay, auto_exposure=True,
                      flicker=0.02, flying_pixels=_u(rng, "flying_pixels"))
    n = _frames_needed(fields, max(n_frames or 0, min_frames))
    if speed_dips:
        fields["speed_dips"] = _speed_dips(np.random.default_rng([int(seed), 7919, sum(map(ord, layout)), 31]),
                                           (n - 1) / rate, speed, SynthConfig.__dataclass_fields__["ramp_s"].default)
    return SynthConfig(**fields, n_frames=n)


def _speed_dips(rng: np.random.Generator, duration: float, speed: float, ramp: float) -> tuple:
    """``((centre, width_s, depth), ...)`` (:attr:`SynthConfig.speed_dips`) for a run of
    ``duration`` s cruising at ``speed`` m/s between ``ramp`` s ramps: one dip and on average
    one more per ``speed_dip_every_s`` of cruise, none overlapping another or a ramp (a draw
    that would is dropped, so a short cruise may keep fewer), each
    wide enough to brake at most at ``speed_dip_max_decel`` (a raised cosine of depth ``d``
    and width ``w`` brakes at up to ``pi d v / w``)."""
    cruise = duration - 2.0 * ramp
    out: list[tuple[float, float, float]] = []
    for _ in range(1 + int(rng.poisson(max(cruise, 0.0) / RANGES["speed_dip_every_s"]))):
        depth = _u(rng, "speed_dip_depth")
        width = max(_u(rng, "speed_dip_width_s"), math.pi * depth * speed / RANGES["speed_dip_max_decel"])
        lo, hi = ramp + 0.5 * width, duration - ramp - 0.5 * width
        if hi <= lo:
            continue
        c = float(rng.uniform(lo, hi))
        if all(abs(c - o[0] * duration) >= 0.5 * (width + o[1]) for o in out):
            out.append((c / duration, width, depth))
    return tuple(sorted(out))


def _frames_needed(fields: dict, n_frames: int) -> int:
    """``n_frames``, or more if the layout needs a longer path at the drawn speed and rate
    (SynthConfig's own default corner radius, ramp and yaw-rate limit)."""
    base = SynthConfig.__dataclass_fields__
    radius = max(base["turn_radius"].default, fields["speed"] / base["max_yaw_rate"].default)
    # the building ring keeps its default lap (tens of metres), driven its default laps
    laps = 1.5 if fields["layout"] == "building" else 1.0
    lap = BUILDING_LAP_M if fields["layout"] == "building" else 0.0
    need = max(min_path_length(fields["layout"], radius, fields["corridor_width"], laps) + 0.5, MIN_PATH_M,
               laps * lap)
    n = n_frames
    while True:
        duration = (n - 1) / fields["rate_hz"]
        ramp = min(base["ramp_s"].default, duration / 2.0)
        if fields["speed"] * (duration - ramp) >= need:
            return n
        n = int(math.ceil(n * 1.1)) + 1


def describe(cfg: SynthConfig) -> dict:
    """The drawn values of a randomized config, rounded, for logs and reports."""
    keys = ["layout", "seed", "n_frames", "rate_hz", "speed", "texture", "corridor_width", "cam_height",
            "pitch_deg", "roll_deg", "weave_components", "door_proud_m", "poster_proud_m", "box_density",
            "branch_angle_deg", "depth_incidence", "edge_dropout", "dropout_rate", "image_noise",
            "vignetting", "light_gain", "exposure_ms", "readout_ms", "color_delay_ms", "auto_exposure",
            "flying_pixels"]
    if cfg.speed_dips:  # only when drawn: the logs rendered before keep their names
        keys.append("speed_dips")
    out = {}
    for k in keys:
        v = getattr(cfg, k)
        if isinstance(v, float):
            v = round(v, 4)
        elif isinstance(v, tuple):
            v = [[round(a, 4) for a in w] for w in v]
        out[k] = v
    return out
