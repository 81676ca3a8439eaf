"""planar-vo: planar visual odometry for indoor robots with an RGB-D camera.

One import package over several folders (setup.py): ``planar_vo.core`` (core/: types,
geometry, errors), ``planar_vo.io`` (io/), ``planar_vo.frontend`` (frontend/),
``planar_vo.backend`` (backend/), and this folder: the pipeline (``pipeline.py``), its
configuration, evaluation (evo) and the CLI (``cli.py``, ``commands/``), with the workshop
apart in ``sim/`` and ``bench/``. This module imports nothing, so importing any layer stays light.
"""
__version__ = "0.1.0"
