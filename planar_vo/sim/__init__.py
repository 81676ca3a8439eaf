"""The workshop's simulators: synthetic inputs with exact ground truth (not the product).

``planar_vo/sim/`` -- needs the ``planar-vo[sim]`` extra (open3d) for rendering:

* ``synth.py``         renders RGB-D corridor logs (MCAP + TUM ground truth): ``planar-vo synth``, the demo's sample;
* ``synth_scene.py``   corridor, hall, ring, building-floor and aliasing layouts as triangle meshes;
* ``synth_texture.py`` world-fixed procedural textures;
* ``synth_random.py``  randomized scenes for ``planar-vo bench sweep``;
* ``revisits.py``      loop-closure ground truth: which keyframes revisit a place, closure errors;
* ``simulate.py``      pose-graph inputs (steps and Manhattan observations) for back-end tests and benchmarks;
* ``problems.py``      two-view planar-motion problems for the solver tests and benchmarks.

The product (``core``, ``io``, ``frontend``, ``backend``, the pipeline and CLI) never imports
it at module level; ``tests/test_layers.py`` checks.
"""
