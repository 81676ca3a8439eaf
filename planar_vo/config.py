"""The run configuration: typed, defaults in code, unknown keys rejected.

A YAML file (``--config``) may set any subset of these keys; command-line flags
override the file; the resolved result is written to ``config.yaml`` in every run folder.
Each setting lives in one place: the camera mount in ``frontend.levelling``, the depth
range in ``frontend``; ``tests/test_config_fields.py`` checks that every field is read.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

import yaml

from planar_vo.backend.config import BackendConfig
from planar_vo.configtools import from_dict, merge, to_dict
from planar_vo.core.errors import ConfigError
from planar_vo.frontend.config import FrontendConfig, PlaceConfig


@dataclass
class InputConfig:
    """What to read from the log. Topics are found automatically when left empty."""

    color_topic: Optional[str] = None
    depth_topic: Optional[str] = None
    info_topic: Optional[str] = None
    #: Wheel odometry topic (nav_msgs/Odometry, /tf with odom -> base_link, or a pose topic).
    odom_topic: Optional[str] = None
    sync_tolerance_s: float = 0.02
    #: Intrinsics override (all four or none), pixels.
    fx: Optional[float] = None
    fy: Optional[float] = None
    cx: Optional[float] = None
    cy: Optional[float] = None
    start: int = 0
    stop: Optional[int] = None
    stride: int = 1
    #: Where frames are decoded and their corners tracked while the main thread works on
    #: earlier ones: ``process`` (a forked child process, Linux; elsewhere a thread),
    #: ``thread``. The same results either way; the process does not share the
    #: interpreter lock with the main thread.
    reader: Literal["process", "thread"] = "process"

    def __post_init__(self) -> None:
        given = [v is not None for v in (self.fx, self.fy, self.cx, self.cy)]
        if any(given) and not all(given):
            raise ConfigError("intrinsics need all of fx, fy, cx, cy (--fx --fy --cx --cy)")
        if self.stride < 1:
            raise ConfigError(f"config key 'input.stride' must be >= 1, got {self.stride}")
        if self.start < 0 or (self.stop is not None and self.stop <= self.start):
            raise ConfigError(f"config keys 'input.start'/'input.stop': bad frame range start={self.start} stop={self.stop}")


@dataclass
class OutputConfig:
    plot: bool = True
    poses_mcap: bool = True
    #: poses.mcap schemas: ``auto`` (the log's family: Foxglove for Foxglove MCAP and TUM
    #: folders, ROS 2 messages for ROS logs), ``ros2`` or ``foxglove``.
    poses_format: Literal["auto", "ros2", "foxglove"] = "auto"


@dataclass
class LoopConfig:
    """Keyframes and candidates (verification settings are ``places``)."""

    #: Off: no keyframes, no closures (the run is then frame-to-frame plus Manhattan priors).
    enabled: bool = True
    #: A keyframe every this much travelled path (m) or turned heading (deg), whichever first.
    keyframe_distance_m: float = 0.5
    keyframe_angle_deg: float = 20.0
    #: Keyframes within this much travelled path of the newest are not candidates.
    recent_path_m: float = 4.0
    #: Candidates per keyframe from the place-recognition index.
    appearance_candidates: int = 2
    #: Candidates per keyframe from proximity (the nearest in Mahalanobis distance).
    proximity_candidates: int = 2
    #: Proximity gate: chi-square of the 2-D position, with the places a keyframe sees
    #: (``view_radius_m``) added to the chain's covariance; 13.8 = 99.9 % for 2 dof.
    proximity_chi2: float = 13.8
    view_radius_m: float = 1.0
    #: Views overlap only if the headings differ by less than this (deg), plus 3 sigma.
    view_angle_deg: float = 45.0
    #: A verified closure must agree with the odometry chain's relative pose within
    #: ``places.prior_gate_chi2``, the chain's sigmas scaled by this (stated step sigmas can
    #: be optimistic). Rejects places that look the same elsewhere, which a redescending
    #: graph kernel cannot always tell: the chain gives way (its robust steps) instead.
    odometry_sigma_scale: float = 3.0
    #: The same scale for guessed steps (partial, bridged): their sigmas are bounds already
    #: (the bridge's cap, or an acceleration bound on the constant-velocity guess), not a
    #: fit's statement. On low-texture rings with 40 % partial steps they made the scaled
    #: prior 4.5 m wide at lap scale, where the look-alikes are 5-10 m apart.
    guessed_sigma_scale: float = 1.0
    #: A verified closure must agree (within ``places.prior_gate_chi2``) with the latest
    #: closure accepted within this much path back, chained through the odometry between
    #: the two pairs of keyframes; 0 turns the check off.
    consistency_path_m: float = 3.0
    #: The prior's heading: ``manhattan`` holds each keyframe's heading by the Manhattan
    #: factors the graph linked at the keyframes (a filter over the chain, per earlier
    #: keyframe), so its sigmas stop growing with the heading drift of the path between;
    #: ``chain`` is the odometry chain alone (its translation sigma grows with path x heading
    #: sigma; on the 40 m tuning rings the measured steps' part is 0.2-0.4 m scaled at lap
    #: scale, more on longer loops).
    prior_heading: Literal["manhattan", "chain"] = "manhattan"
    #: A new keyframe that closed a loop is not kept: the older keyframe it matched stands
    #: for the place, so memory grows with the area explored, not with the time spent in
    #: it (a robot going round a floor again and again keeps one lap of keyframes).
    forget_closed: bool = True

    def __post_init__(self) -> None:
        for name in ("keyframe_distance_m", "keyframe_angle_deg", "proximity_chi2", "view_radius_m",
                     "view_angle_deg", "odometry_sigma_scale", "guessed_sigma_scale"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"config key 'loops.{name}' must be > 0, got {getattr(self, name)}")
        if self.prior_heading not in ("manhattan", "chain"):
            raise ConfigError(f"config key 'loops.prior_heading' must be manhattan or chain, got {self.prior_heading!r}")
        for name in ("recent_path_m", "appearance_candidates", "proximity_candidates", "consistency_path_m"):
            if getattr(self, name) < 0:
                raise ConfigError(f"config key 'loops.{name}' must be >= 0, got {getattr(self, name)}")


@dataclass
class RunConfig:
    input: InputConfig = field(default_factory=InputConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    #: ``batch``: Levenberg-Marquardt over the whole run; ``online``: iSAM2 per frame.
    solver: Literal["batch", "online"] = "batch"
    output: OutputConfig = field(default_factory=OutputConfig)
    #: Loop closure: keyframes and candidates (:mod:`planar_vo.loops`) ...
    loops: LoopConfig = field(default_factory=LoopConfig)
    #: ... and place recognition and verification (:mod:`planar_vo.frontend.places`).
    places: PlaceConfig = field(default_factory=PlaceConfig)


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> RunConfig:
    """Defaults <- YAML file <- ``overrides`` (nested dict), validated."""
    data: dict = {}
    if path is not None:
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as exc:
            raise ConfigError(f"{p}: cannot read config file ({exc.strerror}); check the --config path") from None
        try:
            data = yaml.safe_load(text) or {}
        except yaml.YAMLError as exc:
            raise ConfigError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
        if not isinstance(data, dict):
            raise ConfigError(f"{p}: a config file must be a mapping of sections, got {type(data).__name__}")
    if overrides:
        data = merge(data, overrides)
    return from_dict(RunConfig, data)


def dump_config(config: RunConfig) -> str:
    return yaml.safe_dump(to_dict(config), sort_keys=False)
