"""Conversions between project records and ROS 2 / Foxglove messages.

Builders return what the MCAP writers serialise: plain dicts for ROS 2 (CDR via
mcap_ros2) and protobuf objects for Foxglove. Parsers accept a decoded message of
either profile (told apart by the schema name) and return neutral records, so the
reader has one code path for both.

Timestamps: ``stamp`` floats are seconds, split into ``(sec, nanosec)`` with the fraction
rounded to the nanosecond. Epoch stamps (~1.7e9 s, float spacing ~2e-7 s) therefore come
back bit-exactly; small stamps (e.g. 1000.0333333333333) come back to within 0.5 ns.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.geometry import matrix_from_pose7, pose7_from_matrix
from planar_vo.io.codecs import EncodedImage
from planar_vo.core.types import CameraIntrinsics

# Schema names, normalised by :func:`schema_kind`.
IMAGE, COMPRESSED, CAMERA_INFO, TRANSFORMS, POSE, POSES, ODOMETRY = (
    "image", "compressed", "camera_info", "transforms", "pose", "poses", "odometry")

_KINDS = {
    "sensor_msgs/Image": IMAGE, "foxglove.RawImage": IMAGE,
    "sensor_msgs/CompressedImage": COMPRESSED, "foxglove.CompressedImage": COMPRESSED,
    "sensor_msgs/CameraInfo": CAMERA_INFO, "foxglove.CameraCalibration": CAMERA_INFO,
    "tf2_msgs/TFMessage": TRANSFORMS, "foxglove.FrameTransforms": TRANSFORMS,
    "foxglove.FrameTransform": TRANSFORMS,
    "geometry_msgs/PoseStamped": POSE, "foxglove.PoseInFrame": POSE,
    "foxglove.PosesInFrame": POSES,
    "nav_msgs/Odometry": ODOMETRY,
}


def schema_kind(schema_name: str) -> str | None:
    """Role of a schema (``IMAGE``, ``COMPRESSED``, ...) or None if not one we read."""
    return _KINDS.get(schema_name.replace("/msg/", "/"))


# --------------------------------------------------------------------------- time

def stamp_to_sec_nsec(stamp: float) -> tuple[int, int]:
    """Float seconds -> ``(sec, nanosec)``, rounding the fraction to the nanosecond."""
    sec = math.floor(stamp)
    nsec = round((stamp - sec) * 1e9)
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return int(sec), int(nsec)


def stamp_to_ns(stamp: float) -> int:
    sec, nsec = stamp_to_sec_nsec(stamp)
    return sec * 1_000_000_000 + nsec


def sec_nsec_to_stamp(sec: int, nsec: int) -> float:
    return sec + nsec * 1e-9


# ------------------------------------------------------------------------ builders

def ros2_header(stamp: float, frame_id: str) -> dict:
    sec, nsec = stamp_to_sec_nsec(stamp)
    return {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": frame_id}


def _fox_time(msg_timestamp, stamp: float) -> None:
    sec, nsec = stamp_to_sec_nsec(stamp)
    msg_timestamp.seconds, msg_timestamp.nanos = sec, nsec


def ros2_image(stamp: float, frame_id: str, height: int, width: int, enc: EncodedImage) -> dict:
    if enc.raw:
        return {"header": ros2_header(stamp, frame_id), "height": height, "width": width,
                "encoding": enc.encoding, "is_bigendian": 0, "step": enc.step, "data": enc.data}
    return {"header": ros2_header(stamp, frame_id), "format": enc.format, "data": enc.data}


def foxglove_image(stamp: float, frame_id: str, height: int, width: int, enc: EncodedImage):
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    if enc.raw:
        msg = RawImage(frame_id=frame_id, width=width, height=height, encoding=enc.encoding,
                       step=enc.step, data=enc.data)
    else:
        msg = CompressedImage(frame_id=frame_id, format=enc.format, data=enc.data)
    _fox_time(msg.timestamp, stamp)
    return msg


def _kp(intr: CameraIntrinsics) -> tuple[list[float], list[float]]:
    K = [intr.fx, 0.0, intr.cx, 0.0, intr.fy, intr.cy, 0.0, 0.0, 1.0]
    P = [intr.fx, 0.0, intr.cx, 0.0, 0.0, intr.fy, intr.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return K, P


_IDENTITY9 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


def ros2_camera_info(stamp: float, frame_id: str, intr: CameraIntrinsics) -> dict:
    K, P = _kp(intr)
    return {"header": ros2_header(stamp, frame_id), "height": intr.height, "width": intr.width,
            "distortion_model": "plumb_bob", "d": [float(x) for x in intr.distortion],
            "k": K, "r": _IDENTITY9, "p": P, "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def foxglove_camera_calibration(stamp: float, frame_id: str, intr: CameraIntrinsics):
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    K, P = _kp(intr)
    msg = CameraCalibration(frame_id=frame_id, width=intr.width, height=intr.height,
                            distortion_model="plumb_bob", D=[float(x) for x in intr.distortion],
                            K=K, R=_IDENTITY9, P=P)
    _fox_time(msg.timestamp, stamp)
    return msg


def xyz_quat(T: np.ndarray) -> tuple[dict, dict]:
    """ROS 2 ``(position, orientation)`` dicts of the pose ``T`` (4, 4)."""
    p = pose7_from_matrix(T)
    return ({"x": p[0], "y": p[1], "z": p[2]}, {"x": p[3], "y": p[4], "z": p[5], "w": p[6]})


def ros2_tf_message(transforms) -> dict:
    """``transforms``: iterable of ``(stamp, parent, child, T_parent_child (4, 4))``."""
    out = []
    for stamp, parent, child, T in transforms:
        t, q = xyz_quat(T)
        out.append({"header": ros2_header(stamp, parent), "child_frame_id": child,
                    "transform": {"translation": t, "rotation": q}})
    return {"transforms": out}


def foxglove_frame_transforms(transforms):
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
    msg = FrameTransforms()
    for stamp, parent, child, T in transforms:
        ft = msg.transforms.add(parent_frame_id=parent, child_frame_id=child)
        _fox_time(ft.timestamp, stamp)
        t, q = xyz_quat(T)
        ft.translation.x, ft.translation.y, ft.translation.z = t["x"], t["y"], t["z"]
        ft.rotation.x, ft.rotation.y, ft.rotation.z, ft.rotation.w = q["x"], q["y"], q["z"], q["w"]
    return msg


def ros2_pose_stamped(stamp: float, frame_id: str, T: np.ndarray) -> dict:
    t, q = xyz_quat(T)
    return {"header": ros2_header(stamp, frame_id), "pose": {"position": t, "orientation": q}}


_ZERO36 = [0.0] * 36


def ros2_path(stamp: float, frame_id: str, poses: np.ndarray) -> dict:
    """nav_msgs/Path of ``poses`` (N, 4, 4), every pose stamped ``stamp``."""
    return {"header": ros2_header(stamp, frame_id),
            "poses": [ros2_pose_stamped(stamp, frame_id, T) for T in poses]}


def ros2_odometry(stamp: float, frame_id: str, child_frame_id: str, T: np.ndarray,
                  twist=(0.0, 0.0, 0.0), pose_var=None) -> dict:
    """nav_msgs/Odometry: pose ``T`` (4, 4) of ``child_frame_id`` in ``frame_id``; ``twist``
    ``(vx, vy, omega)`` in the child frame; ``pose_var`` the x, y, yaw variances (diagonal;
    z, roll and pitch then 1e6, not measured by a planar base), or None: covariances zero (unknown)."""
    t, q = xyz_quat(T)
    pc = list(_ZERO36)
    if pose_var is not None:
        pc[0], pc[7], pc[35] = (float(v) for v in pose_var)
        pc[14] = pc[21] = pc[28] = 1e6
    tw = {"linear": {"x": float(twist[0]), "y": float(twist[1]), "z": 0.0},
          "angular": {"x": 0.0, "y": 0.0, "z": float(twist[2])}}
    return {"header": ros2_header(stamp, frame_id), "child_frame_id": child_frame_id,
            "pose": {"pose": {"position": t, "orientation": q}, "covariance": pc},
            "twist": {"twist": tw, "covariance": list(_ZERO36)}}


def _fill_pose(pose, T: np.ndarray) -> None:
    p = pose7_from_matrix(T)
    pose.position.x, pose.position.y, pose.position.z = p[0], p[1], p[2]
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = p[3:7]


def foxglove_pose_in_frame(stamp: float, frame_id: str, T: np.ndarray):
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    msg = PoseInFrame(frame_id=frame_id)
    _fox_time(msg.timestamp, stamp)
    _fill_pose(msg.pose, T)
    return msg


def foxglove_poses_in_frame(stamp: float, frame_id: str, poses: np.ndarray):
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
    msg = PosesInFrame(frame_id=frame_id)
    _fox_time(msg.timestamp, stamp)
    for T in poses:
        _fill_pose(msg.poses.add(), T)
    return msg


def ros2_marker_lines(stamp: float, frame_id: str, segments: np.ndarray, ns: str) -> dict:
    """visualization_msgs/MarkerArray with one LINE_LIST marker: ``segments`` (M, 2, 3)
    endpoints in ``frame_id`` (RViz and Foxglove draw it; an empty list deletes nothing)."""
    points = [{"x": float(p[0]), "y": float(p[1]), "z": float(p[2])} for p in np.asarray(segments).reshape(-1, 3)]
    marker = {"header": ros2_header(stamp, frame_id), "ns": ns, "id": 0, "type": 5, "action": 0,  # LINE_LIST, ADD
              "pose": {"orientation": {"w": 1.0}}, "scale": {"x": 0.03},
              "color": {"r": 1.0, "g": 0.2, "b": 0.6, "a": 1.0}, "points": points}
    return {"markers": [marker]}


def foxglove_scene_lines(stamp: float, frame_id: str, segments: np.ndarray, ns: str):
    """foxglove.SceneUpdate with one entity ``ns`` holding a LINE_LIST of ``segments`` (M, 2, 3)."""
    from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    msg = SceneUpdate()
    entity = msg.entities.add(frame_id=frame_id, id=ns)
    _fox_time(entity.timestamp, stamp)
    line = entity.lines.add(type=LinePrimitive.LINE_LIST, thickness=3.0, scale_invariant=True)
    line.pose.orientation.w = 1.0
    line.color.r, line.color.g, line.color.b, line.color.a = 1.0, 0.2, 0.6, 1.0
    for p in np.asarray(segments).reshape(-1, 3):
        q = line.points.add()
        q.x, q.y, q.z = (float(v) for v in p)
    return msg


# ------------------------------------------------------------------------- parsers

@dataclass
class ImageMessage:
    """A decoded image message of either profile, payload still encoded."""

    stamp: float
    frame_id: str
    raw: bool
    data: bytes
    width: int = 0
    height: int = 0
    encoding: str = ""
    step: int = 0
    is_bigendian: bool = False
    format: str = ""

    @property
    def encoding_name(self) -> str:
        return self.encoding if self.raw else self.format


def _stamp_of(msg) -> float:
    """Header stamp of a ROS 2 message or timestamp of a Foxglove one, in seconds."""
    header = getattr(msg, "header", None)
    if header is not None:
        return sec_nsec_to_stamp(header.stamp.sec, header.stamp.nanosec)
    return sec_nsec_to_stamp(msg.timestamp.seconds, msg.timestamp.nanos)


def _frame_of(msg) -> str:
    header = getattr(msg, "header", None)
    return header.frame_id if header is not None else msg.frame_id


def parse_image(kind: str, msg) -> ImageMessage:
    stamp, frame = _stamp_of(msg), _frame_of(msg)
    # bytes from mcap's decoders, a uint8 array from rosbags'
    data = bytes(msg.data) if not isinstance(msg.data, bytes) else msg.data
    if kind == IMAGE:
        return ImageMessage(stamp, frame, True, data, int(msg.width), int(msg.height),
                            msg.encoding, int(msg.step), bool(getattr(msg, "is_bigendian", 0)))
    return ImageMessage(stamp, frame, False, data, format=msg.format)


def _either(msg, name: str):
    """Field ``name`` in ROS 2 spelling, else ROS 1 / Foxglove upper case (lists or arrays)."""
    value = getattr(msg, name, None)
    if value is None or len(value) == 0:
        value = getattr(msg, name.upper(), None)
    return value if value is not None else []


def parse_camera_info(msg, rectified: bool) -> CameraIntrinsics | None:
    """Intrinsics from a CameraInfo / CameraCalibration, or None if it holds no calibration.

    For rectified images (``rectified``) the projection matrix P applies and distortion
    is zero, as in ROS; otherwise K and D.
    """
    K, P, D = (list(_either(msg, name)) for name in ("k", "p", "d"))
    D = tuple(float(x) for x in D)
    w, h = int(msg.width), int(msg.height)
    if rectified and len(P) == 12 and P[0] > 0 and P[5] > 0:
        return CameraIntrinsics(w, h, float(P[0]), float(P[5]), float(P[2]), float(P[6]))
    if len(K) == 9 and K[0] > 0 and K[4] > 0:
        return CameraIntrinsics(w, h, float(K[0]), float(K[4]), float(K[2]), float(K[5]),
                                D if D else (0.0,) * 5)
    return None


def _matrix(t, q) -> np.ndarray:
    return matrix_from_pose7([t.x, t.y, t.z, q.x, q.y, q.z, q.w])


def parse_transforms(msg) -> list[tuple[float, str, str, np.ndarray]]:
    """TFMessage / FrameTransforms / FrameTransform -> ``[(stamp, parent, child, T)]``."""
    items = msg.transforms if hasattr(msg, "transforms") else [msg]
    out = []
    for tr in items:
        if hasattr(tr, "header"):  # geometry_msgs/TransformStamped
            out.append((_stamp_of(tr), tr.header.frame_id, tr.child_frame_id,
                        _matrix(tr.transform.translation, tr.transform.rotation)))
        else:
            out.append((_stamp_of(tr), tr.parent_frame_id, tr.child_frame_id,
                        _matrix(tr.translation, tr.rotation)))
    return out


def parse_pose(msg) -> tuple[float, str, np.ndarray]:
    """PoseStamped / PoseInFrame -> ``(stamp, frame_id, T (4, 4))``."""
    return _stamp_of(msg), _frame_of(msg), _matrix(msg.pose.position, msg.pose.orientation)


def parse_odometry(msg) -> tuple[float, str, str, np.ndarray]:
    """nav_msgs/Odometry -> ``(stamp, frame_id, child_frame_id, T (4, 4))`` (covariances ignored)."""
    p = msg.pose.pose
    return _stamp_of(msg), _frame_of(msg), msg.child_frame_id, _matrix(p.position, p.orientation)

