"""The workshop's benchmarks: ``planar-vo bench solvers|frontend|backend|io|peers|run|sweep``.

``planar_vo/bench/`` -- each module is one subcommand (``add_arguments`` / ``main``) that
prints figures; ``peer_methods.py`` wraps other libraries' RGB-D odometry (Open3D, OpenCV)
for ``bench peers`` (Open3D comes with the ``planar-vo[sim]`` extra). Not the product:
nothing in ``core``, ``io``, ``frontend``, ``backend`` or the pipeline imports it.
"""
