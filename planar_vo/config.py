"""The run configuration: typed, defaults in code, unknown keys rejected.

A YAML file (``--config``) may set any subset of these keys; command-line flags
override the file; the resolved result is written to ``config.yaml`` in every run folder.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

import yaml

from planar_vo.backend.config import BackendConfig
from planar_vo.configtools import from_dict, merge, to_dict
from planar_vo.errors import ConfigError
from planar_vo.frontend.config import FrontendConfig


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

    def __post_init__(self) -> None:
        given = [v is not None for v in (self.fx, self.fy, self.cx, self.cy)]
        if any(given) and not all(given):
            raise ValueError("intrinsics need all of fx, fy, cx, cy (--fx --fy --cx --cy)")
        if self.stride < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride}")
        if self.start < 0 or (self.stop is not None and self.stop <= self.start):
            raise ValueError(f"bad frame range start={self.start} stop={self.stop}")


@dataclass
class MountConfig:
    """Camera mount override (REP 103 angles). Empty: use /tf_static, else estimate from the floor."""

    pitch_deg: Optional[float] = None
    roll_deg: Optional[float] = None
    height_m: Optional[float] = None

    def __post_init__(self) -> None:
        if (self.pitch_deg is None) != (self.roll_deg is None):
            raise ValueError("mount tilt needs both pitch_deg and roll_deg (--pitch-deg --roll-deg)")


@dataclass
class OutputConfig:
    plot: bool = True
    poses_mcap: bool = True


@dataclass
class RunConfig:
    input: InputConfig = field(default_factory=InputConfig)
    mount: MountConfig = field(default_factory=MountConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    #: ``batch``: Levenberg-Marquardt over the whole run; ``online``: iSAM2 per frame.
    solver: Literal["batch", "online"] = "batch"
    output: OutputConfig = field(default_factory=OutputConfig)


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
