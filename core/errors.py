"""Error types shared by every layer.

The CLI turns a :class:`PlanarVOError` into one line on stderr and its ``exit_code``;
any message must name the thing that is wrong (file, topic, flag) and the fix.
"""
from __future__ import annotations


class PlanarVOError(Exception):
    """Base class: a problem the user can fix, reported as one line."""

    exit_code = 2


class InputError(PlanarVOError):
    """Bad or unreadable input (file, topic, encoding, calibration, flag)."""

    exit_code = 2


class ConfigError(PlanarVOError):
    """Invalid configuration (unknown key, wrong type, out-of-range value)."""

    exit_code = 2


class PartialResult(PlanarVOError):
    """The run stopped early (interrupt, truncated log); what was computed is on disk."""

    exit_code = 3
