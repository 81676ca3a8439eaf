"""Back-end: GTSAM planar pose graph with SE(2) step factors and Manhattan-frame rotation
factors, solved in batch (Levenberg-Marquardt) or incrementally (iSAM2). Pure: no file I/O.

``backend/`` (installed as ``planar_vo.backend``; imports ``planar_vo.core`` and itself only):
``config.py`` settings; ``factors.py`` noise models and factors; ``association.py`` Manhattan
frame association; ``graph.py`` ``PlanarPoseGraph`` / ``IncrementalPlanarPoseGraph``. Its
test inputs are simulated in ``planar_vo.sim.simulate`` (workshop).

Public names are imported lazily so that importing the package does not load gtsam.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "BackendConfig": "planar_vo.backend.config",
    "PlanarPoseGraph": "planar_vo.backend.graph",
    "IncrementalPlanarPoseGraph": "planar_vo.backend.graph",
    "ManhattanAssociator": "planar_vo.backend.association",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'planar_vo.backend' has no attribute {name!r}")
