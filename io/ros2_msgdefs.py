"""ROS 2 message definitions (the ``ros2msg`` schema text MCAP stores with each channel).

Each constant is the type's own ``.msg`` text followed by every nested type, separated
the way ``ros2 bag`` writes them (a line of ``=`` and ``MSG: pkg/Type``).
"""
from __future__ import annotations

_SEP = "=" * 80 + "\n"

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
_POINT = "float64 x\nfloat64 y\nfloat64 z\n"
_QUATERNION = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
_TRANSFORM = "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
_TRANSFORM_STAMPED = ("std_msgs/Header header\nstring child_frame_id\n"
                      "geometry_msgs/Transform transform\n")
_POSE = "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n"
_ROI = ("uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n")


def _join(main: str, *deps: tuple[str, str]) -> str:
    return main + "".join(f"{_SEP}MSG: {name}\n{text}" for name, text in deps)


_HEADER_DEPS = (("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME))

IMAGE = _join(
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
    "uint8 is_bigendian\nuint32 step\nuint8[] data\n", *_HEADER_DEPS)

COMPRESSED_IMAGE = _join("std_msgs/Header header\nstring format\nuint8[] data\n", *_HEADER_DEPS)

CAMERA_INFO = _join(
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
    "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
    "uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
    *_HEADER_DEPS, ("sensor_msgs/RegionOfInterest", _ROI))

TF_MESSAGE = _join(
    "geometry_msgs/TransformStamped[] transforms\n",
    ("geometry_msgs/TransformStamped", _TRANSFORM_STAMPED), *_HEADER_DEPS,
    ("geometry_msgs/Transform", _TRANSFORM), ("geometry_msgs/Vector3", _VECTOR3),
    ("geometry_msgs/Quaternion", _QUATERNION))

POSE_STAMPED = _join(
    "std_msgs/Header header\ngeometry_msgs/Pose pose\n", *_HEADER_DEPS,
    ("geometry_msgs/Pose", _POSE), ("geometry_msgs/Point", _POINT),
    ("geometry_msgs/Quaternion", _QUATERNION))

_VECTOR3_DEP = ("geometry_msgs/Vector3", _VECTOR3)

ODOMETRY = _join(
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist\n", *_HEADER_DEPS,
    ("geometry_msgs/PoseWithCovariance", "geometry_msgs/Pose pose\nfloat64[36] covariance\n"),
    ("geometry_msgs/Pose", _POSE), ("geometry_msgs/Point", _POINT),
    ("geometry_msgs/Quaternion", _QUATERNION),
    ("geometry_msgs/TwistWithCovariance", "geometry_msgs/Twist twist\nfloat64[36] covariance\n"),
    ("geometry_msgs/Twist", "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n"),
    _VECTOR3_DEP)

#: datatype name -> definition text
DEFINITIONS = {
    "sensor_msgs/msg/Image": IMAGE,
    "sensor_msgs/msg/CompressedImage": COMPRESSED_IMAGE,
    "sensor_msgs/msg/CameraInfo": CAMERA_INFO,
    "tf2_msgs/msg/TFMessage": TF_MESSAGE,
    "geometry_msgs/msg/PoseStamped": POSE_STAMPED,
    "nav_msgs/msg/Odometry": ODOMETRY,
}
