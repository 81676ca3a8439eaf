"""Front-end: levelling, inverse-depth plane histograms, Manhattan frames, features,
the paper's planar solvers and frame-to-frame odometry. Pure: arrays in, results out.

``frontend/`` (installed as ``planar_vo.frontend``; imports ``planar_vo.core`` and itself
only, never ``io``): ``config.py`` settings; ``levelling.py`` mount pitch/roll/height;
``planes.py`` inverse-depth histogram planes; ``manhattan.py`` local Manhattan frames;
``features.py`` KLT/ORB tracking; ``solvers.py`` minimal solvers; ``estimators.py`` robust
estimators (PoseLib-shaped 2-point RANSAC, direction-plus-point); ``planarity.py`` 6-DoF
check; ``odometry.py`` ``PlanarOdometry``, one :class:`~planar_vo.core.steps.FrameResult` per frame;
``places.py`` loop-closure keyframes, place recognition and verification.

Public names are imported lazily so that light users (types only) stay light.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "estimate_planar_motion_2pt": "planar_vo.frontend.estimators",
    "estimate_planar_motion_dpp": "planar_vo.frontend.estimators",
    "PlanarOdometry": "planar_vo.frontend.odometry",
    "FrontendConfig": "planar_vo.frontend.config",
    "ManhattanObservation": "planar_vo.core.steps",
    "Step": "planar_vo.core.steps",
    "FrameResult": "planar_vo.core.steps",
    "PlaceConfig": "planar_vo.frontend.config",
    "Keyframe": "planar_vo.frontend.places",
    "make_keyframe": "planar_vo.frontend.places",
    "PlaceIndex": "planar_vo.frontend.places",
    "ClosureCheck": "planar_vo.frontend.places",
    "verify_closure": "planar_vo.frontend.places",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'planar_vo.frontend' has no attribute {name!r}")
