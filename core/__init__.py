"""The shared base every layer imports: types, geometry, errors. Imports nothing above it.

``core/`` (installed as ``planar_vo.core``):

* ``types.py``    sensor data and results: ``CameraIntrinsics``, ``Mount``, ``RGBDFrame``, ``Trajectory``;
* ``steps.py``    what the front-end hands to the back-end: ``FrameResult``, ``Step``,
  ``ManhattanObservation``, ``FrameDiagnostics``, the step statuses;
* ``geometry.py`` frames and signs (camera optical, base_link, odom), rotations, SE(2);
* ``errors.py``   the error types the CLI turns into one line and an exit code.
"""
