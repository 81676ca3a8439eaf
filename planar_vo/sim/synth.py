"""Synthetic RGB-D corridor logs with exact ground truth.

Scenes (:mod:`planar_vo.sim.synth_scene`) are triangle meshes of floor, walls, ceiling,
doors, posters, boxes and pillars, ray cast on the CPU with open3d's
``RaycastingScene``; colour comes from procedural textures
(:mod:`planar_vo.sim.synth_texture`) sampled at the hit point's surface coordinates, so it
is fixed to the world and trackable. The camera is a Kinect v2 at qhd on a robot driving
a smooth planar path; frames follow :mod:`planar_vo.core.geometry` (optical ``cam``, REP 103
``base`` on the floor, world z up).

Sensor model (Kinect v2-like; all switchable in :class:`SynthConfig`):

* depth is the optical-axis ``z`` of the hit, with Gaussian noise of standard deviation
  ``sigma(z) = depth_sigma0 + depth_sigma2 * z**2`` (default 1.5 mm + 1.5 mm * z^2, i.e.
  3 mm at 1 m, 15 mm at 3 m), rounded to whole millimetres, kept only inside
  ``[depth_min, depth_max]`` (0.5 - 4.5 m, else 0);
* holes at depth discontinuities (the far-side pixel, and with probability 1/2 the next
  one too), at grazing incidence (``|cos| < depth_min_cos``), random single-pixel dropouts
  (``dropout_rate``) and a few small dropout blobs;
* colour: texture x world-fixed shading (ambient + a fixed sky light + ceiling lamp
  pools, Lambertian, so brightness is constant across views), mild vignetting, Gaussian
  image noise of ``image_noise`` grey levels;
* optional camera effects, off by default (:func:`with_sensor` ``"kinect2"`` turns them
  on): motion blur, rolling shutter and a colour-to-depth time offset synthesised from
  each pixel's image motion, auto-exposure, flicker, and flying pixels at depth edges.

Everything is deterministic for ``seed``: the scene and textures come from it, and each
frame's noise from ``(seed, frame index)``, so any subset of frames renders identically.
"""
from __future__ import annotations

import math
import os
import re
import sys
import time
from dataclasses import dataclass, field, replace
from typing import Iterable, Iterator

import numpy as np

from planar_vo.core.errors import ConfigError, InputError
from planar_vo.core.geometry import mount_rotation, se2_to_matrix, wrap_angle, wrap_quarter
from planar_vo.sim.synth_scene import (BUILDING_LAP_M, CLOSED_LAYOUTS, LABEL_FLOOR, LABEL_WALL, LAYOUTS, MAT_BOX, MAT_CEILING, MAT_CONCRETE,
                                      MAT_DOOR, MAT_FLOOR, MAT_POSTER, MAT_WALL, Scene, build_scene,
                                      min_path_length)
from planar_vo.sim.synth_texture import (FLAT_COLORS, TEX_ATLAS, TEX_CEILING, TEX_CONCRETE, TEX_FLOOR, TEX_WALL,
                                        TEXEL, TEXTURE_LEVELS, N_BOXES, N_DOORS, N_POSTERS, TextureSet,
                                        build_textures)
from planar_vo.core.types import CameraIntrinsics, Mount, RGBDFrame

#: How to get the renderer's one extra dependency.
INSTALL_SIM = "pip install 'planar-vo[sim]' (setup.sh installs it)"


def open3d():
    """The open3d module (ray casting), or one clear error saying how to install it: it is the
    workshop's extra (``planar-vo[sim]``), not a dependency of the product."""
    try:
        import open3d as o3d
    except ImportError:
        raise InputError(f"the synthetic log renderer needs open3d, which is not installed: {INSTALL_SIM}") from None
    return o3d

__all__ = ["SynthConfig", "SynthFrame", "SynthRenderer", "render_sequence", "synth_trajectory", "with_sensor",
           "SENSOR_PRESETS",
           "synth_intrinsics", "synth_mount", "write_synth_log", "frames_for_laps", "LAYOUTS", "TEXTURE_LEVELS"]

_MAT_TEX = {MAT_FLOOR: TEX_FLOOR, MAT_WALL: TEX_WALL, MAT_CEILING: TEX_CEILING, MAT_CONCRETE: TEX_CONCRETE,
            MAT_POSTER: TEX_ATLAS, MAT_DOOR: TEX_ATLAS, MAT_BOX: TEX_ATLAS}
_MAT_FLAT = {MAT_FLOOR: "floor", MAT_WALL: "wall", MAT_CEILING: "ceiling", MAT_CONCRETE: "concrete",
             MAT_POSTER: "wall", MAT_DOOR: "wall", MAT_BOX: "box"}


@dataclass
class SynthConfig:
    """Everything that defines a synthetic sequence (defaults: Kinect v2 qhd on a small robot).

    Trajectory: ``n_frames`` at ``rate_hz``, cruising at ``speed`` m/s after a
    ``ramp_s`` second start (and before a same-length stop), on the layout's centre line
    with corners rounded to ``max(turn_radius, speed / max_yaw_rate)`` and a smooth
    sideways weave of amplitude ``weave`` metres. Mount: base_link on the floor, the
    optical centre ``cam_x`` forward and ``cam_height`` up, tilted by ``pitch_deg``
    (down) and ``roll_deg`` (REP 103, :func:`planar_vo.core.geometry.mount_rotation`).
    Closed layouts (``loop``, ``building``) are sized so that the path drives ``laps`` laps
    (None: 1 for ``loop``, 1.5 for ``building``); :func:`frames_for_laps` gives the frames of
    a lap length.
    """

    layout: str = "lturn"
    seed: int = 0
    n_frames: int = 300
    rate_hz: float = 10.0
    speed: float = 0.4
    width: int = 960
    height: int = 540
    fx: float = 540.7
    fy: float = 540.7
    cx: float = 479.5
    cy: float = 269.5
    cam_height: float = 0.8
    pitch_deg: float = 10.0
    roll_deg: float = 2.0
    cam_x: float = 0.1
    texture: str = "medium"
    depth_noise: bool = True
    # trajectory
    ramp_s: float = 1.0
    turn_radius: float = 0.9
    max_yaw_rate: float = 0.6
    weave: float = 0.12
    weave_wavelength: float = 5.0
    #: further sideways weaves ``(amplitude m, wavelength m)`` superposed on the first, each
    #: with a seeded phase: short wavelengths turn the heading fast (a real robot's wobble)
    weave_components: tuple = ()
    #: slow-downs within the cruise ``((centre, width_s, depth), ...)``: around ``centre`` (a
    #: fraction of the run's duration) the speed dips by ``depth`` (a fraction of the cruise
    #: speed; 1: the base stops for an instant) over ``width_s`` seconds, a raised cosine, as a
    #: robot slows for a door or a person. The time lost is made up by cruising a little
    #: faster elsewhere (:func:`_time_warp`), so the path, its length and the frames stay the
    #: same. Empty: the trapezoidal profile alone.
    speed_dips: tuple = ()
    start_stamp: float = 1_700_000_000.0
    #: laps of a closed layout (loop, building) the path drives; None: the layout's default
    laps: float | None = None
    # scene
    corridor_width: float = 2.0
    ceiling_height: float = 2.6
    door_proud_m: float = 0.012      # doors stand this far out of their wall
    poster_proud_m: float = 0.004
    box_density: float = 0.2         # boxes per metre of corridor wall
    branch_angle_deg: float = 60.0   # two_frames: angle between the two corridors
    # depth sensor
    depth_min: float = 0.5
    depth_max: float = 4.5
    depth_sigma0: float = 0.0015
    depth_sigma2: float = 0.0015
    depth_edge_holes: bool = True
    depth_min_cos: float = 0.1
    #: depth sigma grows at oblique incidence: times ``1 + depth_incidence * (1 / cos - 1)``
    depth_incidence: float = 0.0
    #: at a depth edge the far-side pixel is lost, and the next one out with this probability
    edge_dropout: float = 0.5
    dropout_rate: float = 0.001
    dropout_blobs: float = 1.0
    # colour
    image_noise: float = 2.0
    vignetting: float = 0.15
    light_gain: float = 1.0          # scene brightness before exposure (1 = as designed)
    # sensor effects beyond the ideal camera (all off by default; ``sensor="kinect2"`` in
    # :func:`with_sensor` turns on the set the benchmarks call "Kinect v2 effects")
    exposure_ms: float = 0.0
    readout_ms: float = 0.0
    color_delay_ms: float = 0.0
    auto_exposure: bool = False
    ae_target: float = 115.0
    flicker: float = 0.0
    flying_pixels: float = 0.0
    # ground truth: a Manhattan frame counts as visible from this image fraction of in-range wall
    min_wall_fraction: float = 0.002

    def __post_init__(self) -> None:
        def bad(name: str, why: str):
            raise ConfigError(f"SynthConfig.{name}: {why}, got {getattr(self, name)!r}")
        if self.layout not in LAYOUTS:
            bad("layout", f"must be one of {', '.join(LAYOUTS)}")
        if self.texture not in TEXTURE_LEVELS:
            bad("texture", f"must be one of {', '.join(TEXTURE_LEVELS)}")
        if self.n_frames < 2:
            bad("n_frames", "must be at least 2")
        for name in ("rate_hz", "speed", "fx", "fy", "turn_radius", "max_yaw_rate", "corridor_width"):
            if not getattr(self, name) > 0:
                bad(name, "must be positive")
        if self.width < 8 or self.height < 8:
            bad("width" if self.width < 8 else "height", "image must be at least 8 x 8 pixels")
        if not 0.1 <= self.cam_height <= self.ceiling_height - 0.2:
            bad("cam_height", f"must be between 0.1 m and the ceiling minus 0.2 m ({self.ceiling_height - 0.2:.2f})")
        if not -45.0 <= self.pitch_deg <= 60.0:
            bad("pitch_deg", "must be within [-45, 60] degrees")
        if not -30.0 <= self.roll_deg <= 30.0:
            bad("roll_deg", "must be within [-30, 30] degrees")
        if not 0.0 < self.depth_min < self.depth_max:
            bad("depth_max", "need 0 < depth_min < depth_max")
        if self.weave < 0 or self.weave > 0.25 * self.corridor_width:
            bad("weave", "must be within [0, corridor_width / 4]")
        if self.ramp_s < 0:
            bad("ramp_s", "must be >= 0")
        if any(len(d) != 3 or not (0.0 < d[0] < 1.0 and d[1] > 0.0 and 0.0 <= d[2] <= 1.0) for d in self.speed_dips):
            bad("speed_dips", "must be (centre, width_s, depth) triples with 0 < centre < 1, width_s > 0, "
                "0 <= depth <= 1")
        elif self.speed_dips and (_time_warp(self, np.array([self.duration]))[1] <= 0.0
                                  or _dip_depth(self, np.linspace(0.0, self.duration, 4001)).max() > 1.0):
            bad("speed_dips", "overlapping dips slow the base below a stop, or leave no time to drive the path; "
                "make them shallower or narrower")
        if any(len(w) != 2 or not (0 <= w[0] <= 0.25 * self.corridor_width and w[1] > 0)
               for w in self.weave_components):
            bad("weave_components", "must be (amplitude, wavelength) pairs with 0 <= amplitude <= "
                "corridor_width / 4 and wavelength > 0")
        if not 10.0 <= self.branch_angle_deg <= 80.0:
            bad("branch_angle_deg", "must be within [10, 80] degrees")
        if not (0.0 <= self.edge_dropout <= 1.0 and self.depth_incidence >= 0 and self.light_gain > 0
                and self.box_density >= 0 and self.door_proud_m >= 0 and self.poster_proud_m >= 0):
            bad("edge_dropout", "edge_dropout in [0, 1]; depth_incidence, box_density and the proud offsets "
                ">= 0; light_gain > 0")
        for name in ("exposure_ms", "readout_ms", "color_delay_ms", "flicker"):
            if not (getattr(self, name) >= 0 and math.isfinite(getattr(self, name))):
                bad(name, "must be a finite number >= 0")
        # 1e-9 ms of slack: a draw that fills the period exactly (synth_random) must not fail on rounding
        if self.exposure_ms + self.readout_ms + 2 * self.color_delay_ms > 1000.0 / self.rate_hz + 1e-9:
            bad("exposure_ms", "exposure + readout + 2 x colour delay must fit in one frame period "
                f"({1000.0 / self.rate_hz:.0f} ms)")
        if not 0.0 <= self.flying_pixels <= 1.0:
            bad("flying_pixels", "must be a fraction in [0, 1]")
        if not 1.0 <= self.ae_target <= 254.0:
            bad("ae_target", "must be a grey level in [1, 254]")
        if self.laps is not None and (self.layout not in CLOSED_LAYOUTS or not 0.1 <= self.laps <= 100.0):
            bad("laps", f"applies to the closed layouts {', '.join(CLOSED_LAYOUTS)} only, within [0.1, 100]")
        need = min_path_length(self.layout, self.turn_radius_used, self.corridor_width, self.laps_used)
        if self.path_length < need:
            frames = int(math.ceil((need / self.speed + self.ramp_s) * self.rate_hz)) + 2
            raise ConfigError(f"SynthConfig.n_frames: layout {self.layout!r} needs at least {need:.1f} m of path "
                              f"but {self.n_frames} frames at {self.speed} m/s drive {self.path_length:.1f} m; "
                              f"use at least {frames} frames")

    @property
    def turn_radius_used(self) -> float:
        """Corner radius of the path: ``turn_radius``, widened so ``speed / radius <= max_yaw_rate``."""
        return max(self.turn_radius, self.speed / self.max_yaw_rate)

    @property
    def laps_used(self) -> float:
        """Laps the path drives round a closed layout (1 for the open layouts: one pass)."""
        if self.laps is not None:
            return float(self.laps)
        return 1.5 if self.layout == "building" else 1.0

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.n_frames - 1) / self.rate_hz

    @property
    def path_length(self) -> float:
        """Metres driven (trapezoidal speed profile)."""
        return self.speed * (self.duration - self._ramp)

    @property
    def _ramp(self) -> float:
        return min(self.ramp_s, self.duration / 2.0)

    def at_resolution(self, width: int, height: int) -> "SynthConfig":
        """The same sequence seen by the same camera resampled to ``width`` x ``height``."""
        k = synth_intrinsics(self).scaled(width, height)
        return replace(self, width=width, height=height, fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)


@dataclass
class SynthFrame:
    """One rendered frame with its ground truth.

    ``rgbd``: colour (H, W, 3) uint8 BGR, depth (H, W) float32 metres (0 invalid).
    ``T_world_cam``: (4, 4) float64 pose of the optical frame in the world (z up).
    ``pose_world_base``: (3,) float64 SE(2) ``(x, y, theta)`` of base_link.
    ``truth``: ``wall_fraction`` / ``floor_fraction`` (image fractions of in-range wall /
    floor pixels), ``floor_normal_cam`` (3,) (up), ``manhattan_yaws_base`` (list, dominant
    first, wrapped to [-pi/4, pi/4)), ``manhattan_scores`` (their wall fractions),
    ``manhattan_ids`` (layout frame ids), ``labels`` (H, W) uint8 (0 none or out of depth
    range, 1 floor, 2 wall incl. doors/posters, 3 ceiling, 4 box/pillar), ``depth_true``
    (H, W) float32 noise-free z of every hit (0 where the ray hits nothing).
    """

    rgbd: RGBDFrame
    T_world_cam: np.ndarray
    pose_world_base: np.ndarray
    truth: dict = field(default_factory=dict)


#: Named sensor models for :func:`with_sensor`. ``ideal``: the defaults (a global-shutter
#: colour camera synchronised with the depth camera, fixed exposure). ``kinect2``: the
#: Kinect v2's free-running colour camera as logged by iai_kinect2: auto-exposure, a
#: 20 ms exposure (dim indoor light; at most 33 ms keeps 30 Hz), a rolling-shutter
#: readout, colour and depth streams that are not synchronised (a constant offset of up
#: to half a 30 Hz period), mains flicker, and flying pixels at depth edges. The values
#: are plausible choices, not a calibration of one device.
SENSOR_PRESETS: dict[str, dict] = {
    "ideal": {},
    "kinect2": {"exposure_ms": 20.0, "readout_ms": 15.0, "color_delay_ms": 16.0, "auto_exposure": True,
                "flicker": 0.02, "flying_pixels": 0.5},
}


def with_sensor(cfg: SynthConfig, sensor: str) -> SynthConfig:
    """``cfg`` with the sensor-effect fields set to the preset ``sensor`` (see ``SENSOR_PRESETS``)."""
    if sensor not in SENSOR_PRESETS:
        raise ConfigError(f"sensor {sensor!r}: must be one of {', '.join(SENSOR_PRESETS)}")
    base = SynthConfig.__dataclass_fields__
    fields = ("exposure_ms", "readout_ms", "color_delay_ms", "auto_exposure", "ae_target", "flicker", "flying_pixels")
    values = {f: base[f].default for f in fields}
    values.update(SENSOR_PRESETS[sensor])
    return replace(cfg, **values)


def synth_intrinsics(cfg: SynthConfig) -> CameraIntrinsics:
    """Pinhole intrinsics of the synthetic camera (no distortion)."""
    return CameraIntrinsics(cfg.width, cfg.height, cfg.fx, cfg.fy, cfg.cx, cfg.cy)


def synth_mount(cfg: SynthConfig) -> Mount:
    """``T_base_cam``: optical frame at ``(cam_x, 0, cam_height)`` in base_link, REP 103 tilt."""
    T = np.eye(4)
    T[:3, :3] = mount_rotation(math.radians(cfg.pitch_deg), math.radians(cfg.roll_deg))
    T[:3, 3] = (cfg.cam_x, 0.0, cfg.cam_height)
    return Mount(T, parent_frame="base_link", child_frame="kinect2_rgb_optical_frame")


def frames_for_laps(laps: float = 1.5, lap_m: float = BUILDING_LAP_M, speed: float = 0.4, rate_hz: float = 10.0,
                    ramp_s: float = 1.0) -> int:
    """Fewest frames whose path (SynthConfig's trapezoidal speed profile) is ``laps * lap_m`` metres
    or more, so that a closed layout's lap comes out at least ``lap_m`` long."""
    length = laps * lap_m
    n = max(2, int(math.ceil((length / speed + ramp_s) * rate_hz)) - 1)
    while speed * ((n - 1) / rate_hz - min(ramp_s, (n - 1) / rate_hz / 2.0)) < length:
        n += 1
    return n


def _scene_for(cfg: SynthConfig) -> Scene:
    # a closed layout is built for one lap; the path drives laps_used of them
    return build_scene(cfg.layout, cfg.path_length / cfg.laps_used, cfg.seed, corridor_width=cfg.corridor_width,
                       ceiling_height=cfg.ceiling_height, turn_radius=cfg.turn_radius_used,
                       n_posters=N_POSTERS, n_doors=N_DOORS, n_box_designs=N_BOXES,
                       door_proud=cfg.door_proud_m, poster_proud=cfg.poster_proud_m,
                       box_density=cfg.box_density, branch_angle_deg=cfg.branch_angle_deg)


def _dip_depth(cfg: SynthConfig, t: np.ndarray) -> np.ndarray:
    """(M,) the fraction of the cruise speed ``cfg.speed_dips`` take away at times ``t`` (M,) s."""
    out = np.zeros_like(np.asarray(t, dtype=np.float64))
    for centre, width, depth in cfg.speed_dips:
        y = np.clip(t - centre * cfg.duration, -0.5 * width, 0.5 * width)
        out += depth * 0.5 * (1.0 + np.cos(2.0 * math.pi * y / width))
    return out


def _time_warp(cfg: SynthConfig, t: np.ndarray) -> tuple[np.ndarray, float]:
    """``(u (M,), k)``: the trapezoidal profile's time ``u`` at which the base, slowed by
    ``cfg.speed_dips``, is where it is at time ``t`` (M,) s, and ``k``, the share of the
    duration left to drive in. The speed is the profile's times ``(1 - sum_i d_i b_i(t)) / k``,
    ``b_i`` the raised cosine of dip ``i`` (1 at its centre, 0 beyond half its width), so
    ``u(0) = 0`` and ``u(T) = T``: the same path in the same time."""
    T = cfg.duration

    def lost(x: np.ndarray) -> np.ndarray:  # integral over [0, x] of sum_i d_i b_i
        out = np.zeros_like(x)
        for centre, width, depth in cfg.speed_dips:
            h = 0.5 * width
            for sign, z in ((1.0, x), (-1.0, np.zeros_like(x))):  # a dip may begin before t = 0
                y = np.clip(z - centre * T, -h, h)
                out += sign * depth * (0.5 * (y + h) + width / (4.0 * math.pi) * np.sin(2.0 * math.pi * y / width))
        return out

    k = 1.0 - float(lost(np.array([T]))[0]) / T if T > 0 else 1.0
    return (t - lost(t)) / k if k > 0 else t, k


def _trajectory(cfg: SynthConfig, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(cfg.n_frames) / cfg.rate_hz
    return cfg.start_stamp + t, _poses_at(cfg, scene, t)


def _poses_at(cfg: SynthConfig, scene: Scene, t: np.ndarray) -> np.ndarray:
    """Base poses ``(x, y, theta)`` (M, 3) at times ``t`` (M,) seconds after the first frame."""
    t = np.asarray(t, dtype=np.float64)
    T, r, v = cfg.duration, cfg._ramp, cfg.speed
    # trapezoidal speed: accelerate over r seconds, cruise, stop over the last r seconds
    t = np.clip(t, 0.0, T)
    if cfg.speed_dips:
        t = _time_warp(cfg, t)[0]
    if r > 0:
        s = np.where(t < r, 0.5 * v / r * t ** 2,
                     np.where(t <= T - r, 0.5 * v * r + v * (t - r), v * (T - r) - 0.5 * v / r * (T - t) ** 2))
    else:
        s = v * t
    S = cfg.path_length
    total = scene.path.length * cfg.laps_used  # laps of a closed path (evaluate takes s modulo a lap)
    s = s * (total / S)  # exact arc length (closes the loop to rounding)
    c, head, kappa = scene.path.evaluate(s)
    # sideways weave d(s); a whole number of periods over the drive so that a whole number of
    # laps closes, but not per lap when there is more than one: a revisit then passes off the
    # first lap's line (a different lateral offset and heading, as a real robot would)
    rng = np.random.default_rng([int(cfg.seed), 2029])
    n_per = _periods(total / cfg.weave_wavelength, cfg.laps_used)
    k = 2.0 * np.pi * n_per / total
    phase = rng.uniform(0.0, 2.0 * np.pi)
    d = cfg.weave * np.sin(k * s + phase)
    dd = cfg.weave * k * np.cos(k * s + phase)
    for amp, wavelength in cfg.weave_components:
        n_per = _periods(total / wavelength, cfg.laps_used)
        kk = 2.0 * np.pi * n_per / total
        ph = rng.uniform(0.0, 2.0 * np.pi)
        d = d + amp * np.sin(kk * s + ph)
        dd = dd + amp * kk * np.cos(kk * s + ph)
    nrm = np.stack([-np.sin(head), np.cos(head)], -1)
    xy = c + d[:, None] * nrm
    # heading of p(s) = c(s) + d(s) n(s): p' = t (1 - kappa d) + d' n
    theta = wrap_angle(head + np.arctan2(dd, 1.0 - kappa * d))
    return np.column_stack([xy, theta])


def _periods(n: float, laps: float) -> int:
    """Whole weave periods nearest ``n`` over a drive of ``laps`` laps (at least 1), one more if
    beyond one lap they would repeat lap after lap."""
    n_per = max(1, int(round(n)))
    if laps > 1.0 and abs(n_per / laps - round(n_per / laps)) < 1e-9:
        n_per += 1
    return n_per


def _twists_at(cfg: SynthConfig, scene: Scene, t: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Base_link velocities ``(vx, vy, omega)`` (M, 3) at times ``t`` (M,): m/s and rad/s in
    base_link axes (REP 103), by central differences of :func:`_poses_at`."""
    t = np.asarray(t, dtype=np.float64)
    a, b = _poses_at(cfg, scene, t - h), _poses_at(cfg, scene, t + h)
    mid = _poses_at(cfg, scene, t)
    c, s = np.cos(mid[:, 2]), np.sin(mid[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[:, 2] - a[:, 2])]) / (2.0 * h)


def synth_trajectory(cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth without rendering: ``stamps`` (N,) float64 s, ``poses_world_base`` (N, 3)."""
    return _trajectory(cfg, _scene_for(cfg))


# ---------------------------------------------------------------------------- renderer

class SynthRenderer:
    """Ray casts one scene from arbitrary base poses. Build once, call :meth:`render` per frame.

    Pixels are processed grouped by the surface they hit (a radix sort of the surface id
    image), so per-surface parameters are scalars and each material's texture is sampled
    in one call.
    """

    def __init__(self, cfg: SynthConfig, scene: Scene | None = None, textures: TextureSet | None = None):
        o3d = open3d()

        self.cfg = cfg
        self.scene = scene if scene is not None else _scene_for(cfg)
        self.textures = textures if textures is not None else build_textures(cfg.texture, cfg.seed)
        self.mount = synth_mount(cfg)
        self.intrinsics = synth_intrinsics(cfg)
        sc = self.scene
        # surfaces ordered by texture, so each texture's pixels are one contiguous range
        order = sorted(range(len(sc.surfaces)), key=lambda i: (_MAT_TEX[sc.surfaces[i].material], i))
        self.surfaces = [sc.surfaces[i] for i in order]
        S = len(self.surfaces)
        if S >= 32767:
            raise ValueError(f"scene has {S} surfaces; at most 32766 are supported")
        sc_sorted = Scene(sc.layout, self.surfaces, sc.manhattan_headings, sc.path, sc.lamps,
                          sc.ceiling_height, sc.bounds)
        V, F, tri_surface = sc_sorted.mesh()
        self._vertices = V.astype(np.float64)
        self._triangles = o3d.core.Tensor(F)
        # surface id per triangle, last entry for a miss; uint8 keys sort ~3x faster
        self._tri_surface = np.append(tri_surface, S).astype(np.uint8 if S < 255 else np.int16)
        self._n_tri = len(tri_surface)
        self._label = np.array([s.label for s in self.surfaces] + [0], np.uint8)
        self._mframe = np.array([s.mframe for s in self.surfaces] + [-1], np.int32)
        self._tex = np.array([_MAT_TEX[s.material] for s in self.surfaces], np.int32)
        self._prepare_surfaces()
        self._prepare_lightmap()
        H, W = cfg.height, cfg.width
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        self._xn = ((u - cfg.cx) / cfg.fx).astype(np.float32).ravel()
        self._yn = ((v - cfg.cy) / cfg.fy).astype(np.float32).ravel()
        self._inv_norm = (1.0 / np.sqrt(self._xn.astype(np.float64) ** 2 + self._yn ** 2 + 1.0)).astype(np.float32)
        rays = np.zeros((H * W, 6), np.float32)
        rays[:, 3], rays[:, 4], rays[:, 5] = self._xn, self._yn, 1.0
        self._rays = o3d.core.Tensor(rays)
        r2 = (u - cfg.cx) ** 2 + (v - cfg.cy) ** 2
        self._vignette = (1.0 - cfg.vignetting * r2 / r2.max()).astype(np.float32).ravel()
        # standard normals for depth and image noise: each frame reads a window at a
        # random offset (drawing fresh Gaussians would cost ~20 ms a frame)
        noise_rng = np.random.default_rng([int(cfg.seed), 77])
        self._normals = noise_rng.standard_normal(2 * H * W + (1 << 18), dtype=np.float32)
        self._img_noise = noise_rng.standard_normal(4 * H * W + (1 << 18), dtype=np.float32)
        self._img_noise *= np.float32(cfg.image_noise)
        self._img_noise += np.float32(0.5)
        # camera effects: rays in base_link axes (for image motion), the rolling-shutter
        # time of each row, and the sequence's constant colour-to-depth capture offset
        self._effects = cfg.exposure_ms > 0 or cfg.readout_ms > 0 or cfg.color_delay_ms > 0 \
            or cfg.auto_exposure or cfg.flicker > 0
        #: colour exposure centre minus depth (and ground-truth) instant, seconds: constant for
        #: the sequence, uniform in +-color_delay_ms (free-running 30 Hz streams)
        self.color_delay_s = float(np.random.default_rng([int(cfg.seed), 4242]).uniform(-1.0, 1.0)) \
            * cfg.color_delay_ms * 1e-3
        if self._effects:
            self._R_bc = self.mount.T_base_cam[:3, :3]
            self._ray_base = np.column_stack([self._xn, self._yn, np.ones(H * W, np.float32)]) \
                @ self._R_bc.T.astype(np.float32)
            self._row_time = ((v.ravel() / max(H - 1, 1) - 0.5) * cfg.readout_ms * 1e-3).astype(np.float32)
            self._u, self._v = u.astype(np.float32).ravel(), v.astype(np.float32).ravel()
        self.timings: dict[str, float] = {}
        self._clock = time.perf_counter  # stage timer (a benchmark may swap in process_time)

    # -------------------------------------------------------------- per-surface tables
    def _prepare_surfaces(self) -> None:
        """Texture maps ``(tx, ty) = (su * u + ou, sv * v + ov)`` (level-0 texels) and flat colours."""
        ts = self.textures
        S = len(self.surfaces)
        self._su, self._sv = np.zeros(S), np.zeros(S)
        self._ou, self._ov = np.zeros(S), np.zeros(S)
        self._flat = np.zeros((S, 3))
        self._tint = np.ones((S, 3))
        sky = np.array([0.25, 0.35, 0.9])
        sky /= np.linalg.norm(sky)
        self._diffuse = np.zeros(S)
        for i, s in enumerate(self.surfaces):
            n = s.normal
            # world-fixed Lambertian shading: ambient + light from above and one side
            self._diffuse[i] = 0.62 + 0.38 * max(float(n @ sky), 0.0) + 0.08 * float(n[0])
            self._flat[i] = np.array(FLAT_COLORS[_MAT_FLAT[s.material]]) * s.tint
            if s.material in (MAT_FLOOR, MAT_WALL, MAT_CEILING, MAT_CONCRETE):
                self._tint[i] = s.tint
                self._su[i], self._sv[i] = 1.0 / TEXEL, -1.0 / TEXEL
                h = ts.textures[_MAT_TEX[s.material]].shape[0] if ts else 0
                self._ou[i] = s.offset[0] / TEXEL
                self._ov[i] = h - s.offset[1] / TEXEL  # v = 0 (floor level) is the bottom edge
            elif ts is not None:
                cells = {MAT_POSTER: ts.poster_cells, MAT_DOOR: ts.door_cells, MAT_BOX: ts.box_cells}[s.material]
                x0, y0, w, h = cells[s.design % len(cells)]
                self._su[i], self._ou[i] = w / s.size[0], x0
                self._sv[i], self._ov[i] = -h / s.size[1], y0 + h
        # texel coordinates: texel corners at integers, so the cell [x0, x0 + w) is the decal

    def _prepare_lightmap(self) -> None:
        """Ceiling lamp pools: a smooth world-fixed (x, y) light map at 10 cm, in [0, 1]."""
        x0, y0, x1, y1 = self.scene.bounds
        res = 0.1
        gx = np.arange(x0, x1 + res, res)
        gy = np.arange(y0, y1 + res, res)
        X, Y = np.meshgrid(gx, gy)
        L = np.zeros_like(X)
        for lx, ly in self.scene.lamps:
            L += np.exp(-((X - lx) ** 2 + (Y - ly) ** 2) / (2 * 1.1 ** 2))
        self._light = (L / max(L.max(), 1e-9)).astype(np.float32)
        self._light_origin, self._light_res = (x0, y0), res

    # ------------------------------------------------------------------------- render
    def render(self, pose_world_base, index: int = 0, stamp: float = 0.0, twist=None) -> SynthFrame:
        """Render the view from base pose ``(x, y, theta)`` (3,) in the world.

        ``index`` selects the frame's noise (with the seed); ``stamp`` is copied into the
        record. ``twist`` (3,): the base's velocity ``(vx, vy, omega)`` (m/s, rad/s, base_link
        axes), needed only for motion blur, rolling shutter and colour delay (None = still).
        Stage times accumulate in :attr:`timings` (seconds).
        """
        return self._shade(self._cast(pose_world_base), index, stamp, twist)

    def render_stream(self, poses, indices, stamps, twists=None) -> Iterator[SynthFrame]:
        """Render many frames, ray casting frame k + 1 on a worker thread while frame k is shaded.

        open3d releases the GIL while it casts, so on two cores this hides most of the
        ray-casting time. ``poses`` (M, 3), ``indices`` (M,), ``stamps`` (M,), ``twists``
        (M, 3) or None (see :meth:`render`).
        """
        from concurrent.futures import ThreadPoolExecutor

        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if not len(poses):
            return
        with ThreadPoolExecutor(max_workers=1) as pool:
            nxt = pool.submit(self._cast, poses[0])
            for k in range(len(poses)):
                cast = nxt.result()
                if k + 1 < len(poses):
                    nxt = pool.submit(self._cast, poses[k + 1])
                yield self._shade(cast, indices[k], stamps[k], None if twists is None else twists[k])

    def _cast(self, pose_world_base) -> tuple:
        """Ray cast one view: ``(pose, T_world_cam, z (N,) float32, primitive ids (N,) uint32, seconds)``."""
        o3d = open3d()

        t0 = self._clock()
        pose = np.asarray(pose_world_base, dtype=np.float64).reshape(3)
        T_wc = se2_to_matrix(pose) @ self.mount.T_base_cam
        R, c = T_wc[:3, :3], T_wc[:3, 3]
        # Ray cast in the camera frame: the rays (0, (xn, yn, 1)) never change, so t_hit is
        # the optical-axis depth z; moving the few hundred vertices and rebuilding the BVH
        # is cheaper than rotating half a million ray directions.
        V_cam = ((self._vertices - c) @ R).astype(np.float32)
        rc = o3d.t.geometry.RaycastingScene()
        rc.add_triangles(o3d.core.Tensor.from_numpy(V_cam), self._triangles)
        hits = rc.cast_rays(self._rays)
        return pose, T_wc, hits["t_hit"].numpy(), hits["primitive_ids"].numpy(), self._clock() - t0

    def _shade(self, cast: tuple, index: int, stamp: float, twist=None) -> SynthFrame:
        """Colour, depth and ground truth from one :meth:`_cast` result."""
        cfg, tm, f32 = self.cfg, self.timings, np.float32
        H, W = cfg.height, cfg.width
        N = H * W
        pose, T_wc, z, prim, t_cast = cast
        R, c = T_wc[:3, :3], T_wc[:3, 3]
        rng = np.random.default_rng([int(cfg.seed), int(index), 3])
        xn, yn = self._xn, self._yn
        t2 = self._clock()

        S = len(self.surfaces)
        sid = self._tri_surface[np.minimum(prim, self._n_tri)]  # S where the ray missed
        order = np.argsort(sid, kind="stable")  # radix sort: pixels grouped by surface
        counts = np.bincount(sid, minlength=S + 1)
        n_hit = N - int(counts[S])
        idx = order[:n_hit]
        zs, xs, ys = z[idx], xn[idx], yn[idx]
        starts = np.concatenate([[0], np.cumsum(counts[:S])])
        t3 = self._clock()

        cos_s = np.empty(n_hit, f32)
        px, py = np.empty(n_hit, f32), np.empty(n_hit, f32)
        tex = self.textures
        if tex is not None:
            tx, ty, foot = np.empty(n_hit, f32), np.empty(n_hit, f32), np.empty(n_hit, f32)
        Rt = R.T
        visible = np.nonzero(counts[:S])[0]
        inv_norm = self._inv_norm[idx]
        for s in visible:
            a, b = starts[s], starts[s + 1]
            zz, xx, yy = zs[a:b], xs[a:b], ys[a:b]
            surf = self.surfaces[s]
            # |cos| of the incidence angle: n_cam . (xn, yn, 1) / |(xn, yn, 1)|
            n_cam = Rt @ surf.normal
            cs = cos_s[a:b]
            np.multiply(xx, f32(n_cam[0]), out=cs)
            cs += yy * f32(n_cam[1])
            cs += f32(n_cam[2])
            np.abs(cs, out=cs)
            cs *= inv_norm[a:b]
            # any affine function of the hit point is z * (A . (xn, yn, 1)) + B
            todo = [(px, R[0], c[0]), (py, R[1], c[1])]
            if tex is not None:
                for axis, scale, off, out in ((surf.axis_u, self._su[s], self._ou[s], tx),
                                              (surf.axis_v, self._sv[s], self._ov[s], ty)):
                    todo.append((out, scale * (Rt @ axis), scale * float((c - surf.origin) @ axis) + off))
                # pixel footprint in level-0 texels (isotropic compromise for oblique views)
                np.multiply(zz, f32(abs(self._su[s]) / cfg.fx), out=foot[a:b])
                foot[a:b] /= np.sqrt(np.maximum(cs, f32(0.05)))
            for out, A, B in todo:
                o = out[a:b]
                np.multiply(xx, f32(A[0]), out=o)
                o += yy * f32(A[1])
                o += f32(A[2])
                o *= zz
                o += f32(B)
        t4 = self._clock()

        # colour = material colour x per-surface (tint x Lambert term)
        colour = np.empty((n_hit, 3), f32)
        coef = self._tint * self._diffuse[:, None]
        if tex is None:
            for s in visible:
                colour[starts[s]:starts[s + 1]] = self._flat[s] * self._diffuse[s]
        else:
            lod = np.log2(np.maximum(foot, f32(1e-6)))
            tbounds = starts[np.searchsorted(self._tex, np.arange(len(tex.textures) + 1))]
            c8 = np.empty((n_hit, 3), np.uint8)
            for t_id, texture in enumerate(tex.textures):
                a, b = tbounds[t_id], tbounds[t_id + 1]
                if b > a:
                    c8[a:b] = _sample_trilinear(texture, tx[a:b], ty[a:b], lod[a:b])
            for s in visible:
                a, b = starts[s], starts[s + 1]
                np.multiply(c8[a:b], coef[s].astype(f32), out=colour[a:b])
        t5 = self._clock()

        # world-fixed lamp pools x camera vignetting, then sensor noise
        lo, res = self._light_origin, self._light_res
        px -= f32(lo[0])
        px *= f32(1.0 / res)
        py -= f32(lo[1])
        py *= f32(1.0 / res)
        light = _remap_points(self._light, px, py, border=_BORDER_REPLICATE)
        light *= f32(0.35)
        light += f32(0.8)
        light *= self._vignette[idx]
        colour *= light[:, None]
        buf = self._img_noise  # image noise + 0.5 (rounding), read at a random offset
        if self._effects:
            color = self._camera(colour, idx, z, twist, rng, buf)
        else:
            off = int(rng.integers(0, len(buf) - 3 * n_hit))
            colour += buf[off: off + 3 * n_hit].reshape(n_hit, 3)
            np.clip(colour, 0.0, 255.0, out=colour)
            color = np.zeros((H, W, 3), np.uint8)
            color.reshape(-1).view("V3")[idx] = colour.astype(np.uint8).view("V3").ravel()
        t6 = self._clock()

        # ---------------------------------------------------------------------- depth
        z_true = np.where(sid < S, z, f32(0.0))
        cos_full = np.ones(N, f32)
        cos_full[idx] = cos_s
        depth = self._depth(z_true, cos_full, rng)
        t7 = self._clock()

        labels = self._label[sid]
        in_range = (z_true >= f32(cfg.depth_min)) & (z_true <= f32(cfg.depth_max))
        labels = np.where(in_range, labels, np.uint8(0)).reshape(H, W)
        truth = self._truth(labels, sid, pose, T_wc)
        truth["depth_true"] = z_true.reshape(H, W)
        rgbd = RGBDFrame(index=int(index), stamp=float(stamp), color=color, depth=depth,
                         depth_stamp=float(stamp), meta={"source": "synth", "layout": cfg.layout})
        t8 = self._clock()
        for name, dt in (("cast", t_cast), ("sort", t3 - t2), ("surfaces", t4 - t3), ("texture", t5 - t4),
                         ("compose", t6 - t5), ("depth", t7 - t6), ("truth", t8 - t7), ("shade", t8 - t2)):
            tm[name] = tm.get(name, 0.0) + dt
        tm["frames"] = tm.get("frames", 0) + 1
        return SynthFrame(rgbd, T_wc, pose.copy(), truth)

    def _camera(self, colour: np.ndarray, idx: np.ndarray, z: np.ndarray, twist, rng, noise: np.ndarray) -> np.ndarray:
        """The colour camera's view of the scene radiance ``colour`` (n_hit, 3) at pixels ``idx``.

        The radiance image is rendered at the depth (and ground-truth) instant t. Pixel q
        of the colour image integrates it over the shutter interval, which opens at
        ``t + delay + row_time(q) - exposure / 2`` (global colour-to-depth offset, rolling
        shutter), approximated to first order by the image motion ``flow(q)`` (px/s) that
        the base velocity ``twist`` induces: ``I_c(q) = mean_s I_t(q - s * flow(q))``.
        Then auto-exposure scales the frame to a mean grey of ``ae_target`` (the camera
        meters at 30 Hz, so it has settled by the next 10 Hz frame), mains flicker
        multiplies it by ``1 + flicker * N(0, 1)``, and sensor noise is added.
        Returns (H, W, 3) uint8.
        """
        import cv2

        cfg, f32 = self.cfg, np.float32
        H, W = cfg.height, cfg.width
        img = np.zeros((H * W, 3), f32)
        img[idx] = colour
        img = img.reshape(H, W, 3)
        exposure = cfg.exposure_ms * 1e-3
        if twist is not None and (exposure > 0 or cfg.readout_ms > 0 or self.color_delay_s != 0.0):
            vx, vy, om = (float(a) for a in np.asarray(twist, dtype=np.float64).reshape(3))
            zz = np.where(np.isfinite(z) & (z > 0), z, f32(0.0)).astype(f32)  # 0 where the ray missed
            # world-fixed point in the moving base frame: dX/dt = -v - omega z_hat x X
            Xb = self._ray_base * zz[:, None]
            Xb += self.mount.T_base_cam[:3, 3].astype(f32)
            dxb = Xb[:, 1] * f32(om) - f32(vx)
            dyb = Xb[:, 0] * f32(-om) - f32(vy)
            R = self._R_bc  # X_cam = R_bc^T (X_base - t_bc)
            dX = dxb * f32(R[0, 0]) + dyb * f32(R[1, 0])
            dY = dxb * f32(R[0, 1]) + dyb * f32(R[1, 1])
            dZ = dxb * f32(R[0, 2]) + dyb * f32(R[1, 2])
            inv_z = np.divide(f32(1.0), zz, out=np.zeros_like(zz), where=zz > 0)
            du = (dX - self._xn * dZ) * inv_z * f32(cfg.fx)
            dv = (dY - self._yn * dZ) * inv_z * f32(cfg.fy)
            speed = float(np.sqrt(np.max(du * du + dv * dv))) if len(du) else 0.0
            K = int(np.clip(math.ceil(speed * exposure) + 1, 1, 9)) if exposure > 0 else 1
            t0 = self._row_time + f32(self.color_delay_s)
            acc = np.zeros_like(img)
            for s in (np.linspace(-0.5, 0.5, K) * exposure if K > 1 else [0.0]):
                tau = t0 + f32(s)
                mx = (self._u - tau * du).reshape(H, W)
                my = (self._v - tau * dv).reshape(H, W)
                acc += cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            img = acc
            img *= f32(1.0 / K)
        if cfg.light_gain != 1.0:
            img *= f32(cfg.light_gain)
        gain = 1.0
        if cfg.auto_exposure:
            gain = cfg.ae_target / max(float(img.mean()), 1.0)
        if cfg.flicker > 0:
            gain *= max(1.0 + cfg.flicker * float(rng.standard_normal()), 0.05)
        if gain != 1.0:
            img *= f32(gain)
        off = int(rng.integers(0, len(noise) - 3 * H * W))
        img += noise[off: off + 3 * H * W].reshape(H, W, 3)
        np.clip(img, 0.0, 255.0, out=img)
        return img.astype(np.uint8)

    def _depth(self, z_true: np.ndarray, cos_full: np.ndarray, rng) -> np.ndarray:
        """Kinect v2-like measured depth (H, W) float32 from the true z (N,) float32."""
        cfg, f32 = self.cfg, np.float32
        H, W = cfg.height, cfg.width
        N = H * W
        if cfg.depth_noise:
            buf = self._normals
            off = int(rng.integers(0, len(buf) - N))
            d = z_true * z_true
            d *= f32(cfg.depth_sigma2)
            d += f32(cfg.depth_sigma0)
            if cfg.depth_incidence > 0:  # oblique surfaces return fewer, noisier photons
                d *= f32(1.0) + f32(cfg.depth_incidence) * (f32(1.0) / np.maximum(np.abs(cos_full), f32(0.2))
                                                           - f32(1.0))
            d *= buf[off: off + N]
            d += z_true
            d *= f32(1000.0)
            np.rint(d, out=d)
            d /= f32(1000.0)  # whole millimetres, bit-identical to a 16UC1 image read back
        else:
            d = z_true.copy()
        bad = (d < f32(cfg.depth_min)) | (d > f32(cfg.depth_max))
        if cfg.depth_noise:  # no return at grazing incidence
            bad |= cos_full < f32(cfg.depth_min_cos)
        d[bad] = 0.0
        d = d.reshape(H, W)
        if not cfg.depth_noise:
            return d
        if cfg.depth_edge_holes:
            fly: list | None = [] if cfg.flying_pixels > 0 else None
            zt = z_true.reshape(H, W)
            d[_edge_holes(zt, rng, fly, cfg.edge_dropout)] = 0.0
            if fly:
                # flying pixels: the far-side pixel mixes the near and far returns
                rr = np.concatenate([f[0] for f in fly])
                cc = np.concatenate([f[1] for f in fly])
                zn = np.concatenate([f[2] for f in fly])
                pick = rng.random(len(rr)) < cfg.flying_pixels
                rr, cc, zn = rr[pick], cc[pick], zn[pick]
                zf = zt[rr, cc]
                ok = (zf > 0) & (zn < 1e3)
                rr, cc, zn, zf = rr[ok], cc[ok], zn[ok], zf[ok]
                w = rng.random(len(rr)).astype(f32)
                mix = w * zn + (f32(1.0) - w) * zf
                mix += (f32(cfg.depth_sigma0) + f32(cfg.depth_sigma2) * mix * mix) * rng.standard_normal(len(mix)).astype(f32)
                mix = np.rint(mix * f32(1000.0)) / f32(1000.0)
                mix[(mix < f32(cfg.depth_min)) | (mix > f32(cfg.depth_max))] = 0.0
                d[rr, cc] = mix
        if cfg.dropout_rate > 0:
            d.reshape(-1)[rng.integers(0, N, rng.poisson(cfg.dropout_rate * N))] = 0.0
        if cfg.dropout_blobs > 0:
            import cv2
            for _ in range(rng.poisson(cfg.dropout_blobs)):
                cx, cy = int(rng.integers(0, W)), int(rng.integers(0, H))
                ax, ay = int(rng.integers(2, 7)), int(rng.integers(2, 7))
                y0, x0 = max(cy - 7, 0), max(cx - 7, 0)
                sub = d[y0: cy + 8, x0: cx + 8]
                mask = np.zeros(sub.shape, np.uint8)
                cv2.ellipse(mask, (cx - x0, cy - y0), (ax, ay), float(rng.uniform(0, 180)), 0, 360, 1, -1)
                sub[mask.astype(bool)] = 0.0
        return d

    def _truth(self, labels: np.ndarray, sid: np.ndarray, pose: np.ndarray, T_wc: np.ndarray) -> dict:
        N = labels.size
        walls = labels.reshape(-1) == LABEL_WALL
        n_frames = len(self.scene.manhattan_headings)
        per = np.bincount(self._mframe[sid[walls]], minlength=n_frames)[:n_frames] / N
        seen = [k for k in np.argsort(-per, kind="stable") if per[k] >= self.cfg.min_wall_fraction]
        return {
            "wall_fraction": float(walls.mean()),
            "floor_fraction": float((labels == LABEL_FLOOR).mean()),
            "floor_normal_cam": T_wc[:3, :3].T @ np.array([0.0, 0.0, 1.0]),
            "manhattan_yaws_base": [float(wrap_quarter(self.scene.manhattan_headings[k] - pose[2])) for k in seen],
            "manhattan_scores": [float(per[k]) for k in seen],
            "manhattan_ids": [int(k) for k in seen],
            "labels": labels,
        }


def _edge_holes(z: np.ndarray, rng: np.random.Generator, flying: list | None = None,
                extra: float = 0.5) -> np.ndarray:
    """Mask (H, W) of pixels lost at depth discontinuities.

    A jump between neighbours larger than ``0.02 + 0.03 z^2`` m (well above the
    neighbour-to-neighbour change of a slanted floor) removes the far-side pixel, and
    with probability ``extra`` the next one outward as well (one or two pixels, as Kinect v2).
    If ``flying`` is a list, ``(rows, cols, z_near)`` of the far-side pixels next to a
    jump are appended to it (the pixels a time-of-flight camera may return as mixtures).
    """
    f32 = np.float32
    H, W = z.shape
    zz = np.where(z > 0, z, f32(1e3))
    mask = np.zeros(z.shape, bool)
    for axis in (0, 1):
        a, b = (zz[:-1], zz[1:]) if axis == 0 else (zz[:, :-1], zz[:, 1:])
        thr = np.minimum(a, b)
        thr *= thr
        thr *= f32(0.03)
        thr += f32(0.02)
        dz = b - a
        r, c = np.nonzero(np.abs(dz) > thr)
        sgn = np.where(dz[r, c] > 0, 1, -1)  # +1: b is the far side, -1: a is
        far = np.where(sgn > 0, 1, 0)
        if flying is not None:
            rr, cc = (r + far, c) if axis == 0 else (r, c + far)
            flying.append((rr, cc, np.minimum(a[r, c], b[r, c])))
        for k, keep in ((far, None), (far + sgn, rng.random(len(r)) < extra)):  # 1 or 2 pixels
            rr, cc = (r + k, c) if axis == 0 else (r, c + k)
            ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
            if keep is not None:
                ok &= keep
            mask[rr[ok], cc[ok]] = True
    return mask


_BORDER_REPLICATE, _BORDER_WRAP = 1, 3  # cv2.BORDER_REPLICATE, cv2.BORDER_WRAP


def _remap_points(img: np.ndarray, x: np.ndarray, y: np.ndarray, border: int,
                  keep_rows: bool = False) -> np.ndarray:
    """Bilinear samples of ``img`` at float32 points (n,): (n, C) (or (n,) for 2-D images).

    OpenCV limits map sizes to < 32767 per side, so points go in as rows of 1024;
    ``keep_rows`` returns that padded (rows, 1024, C) image instead.
    """
    import cv2
    n = len(x)
    cols = 1024
    rows = -(-n // cols)
    if rows * cols == n:
        mx, my = x.reshape(rows, cols), y.reshape(rows, cols)
    else:
        mx = np.zeros(rows * cols, np.float32)
        my = np.zeros(rows * cols, np.float32)
        mx[:n], my[:n] = x, y
        mx, my = mx.reshape(rows, cols), my.reshape(rows, cols)
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=border)
    if keep_rows:
        return out
    return out.reshape(rows * cols, *img.shape[2:])[:n]


def _sample_trilinear(texture, tx: np.ndarray, ty: np.ndarray, lod: np.ndarray) -> np.ndarray:
    """Trilinear (mip-mapped) samples (n, 3) uint8 of a texture.

    ``tx``, ``ty``: level-0 coordinates with texel *corners* at integers (texel centres
    at +0.5), so level ``l`` coordinates are simply ``tx * 2**-l``. ``lod``: log2 of the
    pixel footprint in level-0 texels. Each pixel is sampled at levels ``floor(lod)``
    and ``floor(lod) + 1`` of the packed pyramid (two remap calls in all) and blended.
    """
    import cv2
    f32 = np.float32
    nlev = len(texture.levels)
    lod = np.clip(lod, 0.0, nlev - 1.001)
    l0 = lod.astype(np.uint8)
    frac = lod - l0
    sc = np.take(texture.scale, l0)
    maps = []
    for t, size, off in ((tx, texture.w[0], texture.ox), (ty, texture.h[0], texture.oy)):
        t = t.copy()
        if texture.periodic:  # wrap at level 0; every level then lies in its own region
            t -= np.floor(t * f32(1.0 / size)) * f32(size)
        t *= sc
        t0 = t + np.take(off - f32(0.5), l0)  # pixel-centre convention of cv2.remap
        t *= f32(0.5)
        t += np.take(np.append(off[1:], off[-1]) - f32(0.5), l0)
        maps.append((t0, t))
    a = _remap_points(texture.packed, maps[0][0], maps[1][0], _BORDER_REPLICATE, keep_rows=True)
    b = _remap_points(texture.packed, maps[0][1], maps[1][1], _BORDER_REPLICATE, keep_rows=True)
    wb = np.zeros(a.shape[:2], f32)
    wb.reshape(-1)[:len(frac)] = frac
    out = cv2.blendLinear(a, b, f32(1.0) - wb, wb)
    return out.reshape(-1, 3)[:len(frac)]


# ------------------------------------------------------------------------------ streams

def render_sequence(cfg: SynthConfig, frames: Iterable[int] | None = None) -> Iterator[SynthFrame]:
    """Render the sequence one frame at a time (all frames, or the given frame indices)."""
    idx = np.arange(cfg.n_frames) if frames is None else np.array([int(i) for i in frames], dtype=np.int64)
    bad = idx[(idx < 0) | (idx >= cfg.n_frames)]
    if len(bad):
        raise IndexError(f"frame {bad[0]} is outside the sequence of {cfg.n_frames} frames")
    renderer = SynthRenderer(cfg)
    stamps, poses = _trajectory(cfg, renderer.scene)
    twists = _twists_at(cfg, renderer.scene, stamps[idx] - cfg.start_stamp)
    yield from renderer.render_stream(poses[idx], idx, stamps[idx], twists)


def _write_tum(path: str, stamps: np.ndarray, poses: np.ndarray, cfg: SynthConfig) -> None:
    from planar_vo.io.trajectory import write_tum_trajectory
    from planar_vo.core.types import Trajectory
    write_tum_trajectory(path, Trajectory(stamps, poses),
                         header=f"planar-vo synth ground truth: camera optical frame in world (z up)\n"
                                f"layout={cfg.layout} seed={cfg.seed} frames={cfg.n_frames} texture={cfg.texture}")


#: MCAP metadata record holding a synthetic log's wheel odometry parameters.
WHEEL_ODOM_METADATA = "planar_vo.wheel_odometry"


def _wheel_odom_samples(cfg: SynthConfig, scene: Scene, model) -> tuple:
    """``(stamps (M,), T_odom_base (M, 3), rate_hz, twists (M, 3))`` of the simulated wheel
    odometry: from the first frame to the last, at ``model.rate_hz`` but never slower than
    the frames, driven by the true base path."""
    from planar_vo.io.wheel_odom import se2_between_many, simulate_wheel_odometry

    rate = max(float(model.rate_hz), cfg.rate_hz)
    t_end = (cfg.n_frames - 1) / cfg.rate_hz
    n = int(math.floor(t_end * rate + 1e-9)) + 1
    t = np.arange(n) / rate
    if t[-1] < t_end - 1e-9:
        t = np.append(t, t_end)
    P = simulate_wheel_odometry(_poses_at(cfg, scene, t), model)
    tw = np.zeros_like(P)
    if len(P) > 1:
        tw[1:] = se2_between_many(P[:-1], P[1:]) / np.diff(t)[:, None]
        tw[0] = tw[1]
    return cfg.start_stamp + t, P, rate, tw


class _OdomStream:
    """Writes a log's simulated wheel odometry in stamp order, interleaved with the frames,
    after its parameters as the metadata record ``WHEEL_ODOM_METADATA``."""

    def __init__(self, cfg: SynthConfig, scene: Scene, model, writer, on: str):
        self.stamps, self.poses, rate, self.twists = _wheel_odom_samples(cfg, scene, model)
        self.writer, self.on, self.next = writer, on, 0
        writer.add_metadata(WHEEL_ODOM_METADATA, {**model.metadata(), "on": on, "rate_hz": repr(rate)})

    def write_until(self, stamp: float) -> None:
        while self.next < len(self.stamps) and self.stamps[self.next] <= stamp:
            i = self.next
            self.writer.write_wheel_odometry(self.stamps[i], se2_to_matrix(self.poses[i]), on=self.on,
                                             twist=self.twists[i])
            self.next += 1


def write_synth_log(cfg: SynthConfig, out_path, *, profile: str = "ros2", color_encoding: str = "jpeg",
                    depth_encoding: str = "png", progress: bool = True, container: str = "mcap",
                    wheel_odom=None, wheel_odom_on: str = "odom") -> dict:
    """Render ``cfg`` into an MCAP log plus ``<out>.gt.tum``; returns ``{'log': ..., 'ground_truth': ...}``.

    The log looks like an iai_kinect2 recording (``/kinect2/qhd/...`` images and
    camera_info, the mount on ``/tf_static``, ground truth on ``/ground_truth``) in the
    ``ros2`` profile, or uses the Foxglove schemas in the ``foxglove`` profile.
    ``container`` (:data:`planar_vo.io.rosbags_writer.CONTAINERS`) writes the same
    messages as a ROS 1 bag, a rosbag2 folder or a ROS 1-profile MCAP instead.
    ``wheel_odom`` (a :class:`~planar_vo.io.wheel_odom.WheelOdomModel`) adds wheel odometry on
    ``/odom`` or (``wheel_odom_on="tf"``) ``/tf``, parameters in the metadata (:class:`_OdomStream`).
    """
    from concurrent.futures import ThreadPoolExecutor

    from planar_vo.io.rosbags_writer import open_log_writer

    out = os.fspath(out_path).rstrip("/") or "/"
    parent = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(parent):
        raise InputError(f"output {out}: directory {parent} does not exist; create it first")
    base = re.sub(r"\.(mcap|bag)$", "", out.rstrip("/"))
    gt_path = base + ".gt.tum"
    renderer = SynthRenderer(cfg)
    stamps, poses = _trajectory(cfg, renderer.scene)
    T_wc = np.empty((cfg.n_frames, 4, 4))
    try:
        writer = open_log_writer(out, renderer.intrinsics, container=container, profile=profile,
                                 mount=renderer.mount, color_encoding=color_encoding,
                                 depth_encoding=depth_encoding)
    except ValueError as exc:
        raise InputError(f"synthetic log {out}: {exc}") from None

    def put(frame: SynthFrame) -> None:
        if odom is not None:
            odom.write_until(frame.rgbd.stamp)
        writer.write(frame.rgbd)
        writer.write_ground_truth(frame.rgbd.stamp, frame.T_world_cam)

    t0 = time.perf_counter()
    # encode and write frame k on a worker thread while frame k + 1 renders (OpenCV's
    # encoders and most numpy work release the GIL)
    with writer, ThreadPoolExecutor(max_workers=1) as pool:
        pending = None
        odom = _OdomStream(cfg, renderer.scene, wheel_odom, writer, wheel_odom_on) if wheel_odom else None
        twists = _twists_at(cfg, renderer.scene, stamps - cfg.start_stamp)
        for i, f in enumerate(renderer.render_stream(poses, np.arange(cfg.n_frames), stamps, twists)):
            T_wc[i] = f.T_world_cam
            if pending is not None:
                pending.result()
            pending = pool.submit(put, f)
            if progress and (i % 10 == 9 or i == cfg.n_frames - 1):
                rate = (i + 1) / max(time.perf_counter() - t0, 1e-9)
                print(f"\rsynth {cfg.layout}: frame {i + 1}/{cfg.n_frames}  {rate:.1f} frames/s",
                      end="", file=sys.stderr, flush=True)
        if pending is not None:
            pending.result()
        if odom is not None:
            odom.write_until(math.inf)
    if progress:
        print(file=sys.stderr)
    _write_tum(gt_path, stamps, T_wc, cfg)
    return {"log": out, "ground_truth": gt_path}
