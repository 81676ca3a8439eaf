"""One setting, one place: every field of the configuration dataclasses is read by the code.

A field that nothing reads is a setting that does nothing; the test walks the dataclasses
of the run, front-end and back-end configuration and looks for an attribute access
``.name`` in the product's modules (the configuration modules themselves excluded: their
own validation does not count as a use).
"""
import dataclasses
import re
from pathlib import Path

import pytest

from planar_vo import config as run_config
from planar_vo.backend import config as backend_config
from planar_vo.frontend import config as frontend_config

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("planar_vo", "frontend", "backend", "io")
WORKSHOP = ("sim", "bench")


def _product_source() -> str:
    files = [p for d in PRODUCT for p in (ROOT / d).rglob("*.py")
             if p.name != "config.py" and not set(p.relative_to(ROOT).parts) & set(WORKSHOP)]
    return "\n".join(p.read_text() for p in files)


def _fields():
    for module in (run_config, frontend_config, backend_config):
        for cls in vars(module).values():
            if dataclasses.is_dataclass(cls) and cls.__module__ == module.__name__:
                for f in dataclasses.fields(cls):
                    yield f"{cls.__name__}.{f.name}", f.name


FIELDS = sorted(_fields())


def test_the_walk_finds_every_section():
    sections = {name.split(".")[0] for name, _ in FIELDS}
    assert {"RunConfig", "InputConfig", "OutputConfig", "FrontendConfig", "LevellingConfig", "PlaneConfig",
            "ManhattanConfig", "FeatureConfig", "OdometryConfig", "BackendConfig"} <= sections
    assert len(FIELDS) > 100


@pytest.mark.parametrize("qualified, name", FIELDS)
def test_field_is_read(qualified, name):
    assert re.search(rf"\.{name}\b", _product_source()), f"{qualified} is read nowhere: remove it or use it"


def test_no_duplicate_leaf_settings():
    """The same setting must not be settable in two sections (the mount, the depth range)."""
    seen = {}
    for qualified, name in FIELDS:
        if name in ("pitch_deg", "roll_deg", "height_m", "min_depth", "max_depth"):
            seen.setdefault(name, []).append(qualified)
    assert all(len(v) == 1 for v in seen.values()), seen
