"""planar-vo: planar visual odometry for indoor robots with an RGB-D camera."""
__version__ = "0.1.0"
