"""Damaged and awkward MCAP logs: truncation, corrupt payloads, topic discovery, calibration."""
import numpy as np
import pytest

from planar_vo.core.errors import InputError, PartialResult
from planar_vo.core.geometry import rot_z
from planar_vo.io import RGBDLogWriter, open_log
from planar_vo.io import messages as m
from planar_vo.io.codecs import encode_color, encode_depth

from iohelpers import INTR, make_frames, write_ros2

FRAMES = make_frames(40, seed=5)


@pytest.fixture(scope="module")
def raw_log(tmp_path_factory):
    """40 raw frames in small chunks, so a cut keeps most of them readable."""
    path = tmp_path_factory.mktemp("damage") / "raw.mcap"
    with RGBDLogWriter(path, INTR, color_encoding="bgr8", depth_encoding="16UC1",
                       chunk_compression="none", chunk_size=16 * 1024) as w:
        for f in FRAMES:
            w.write(f)
    return path


def test_truncated_log_yields_what_is_readable_then_partial_result(raw_log, tmp_path):
    data = raw_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    got = []
    with open_log(cut) as log:
        assert not log.indexed
        with pytest.raises(PartialResult, match=r"cut short at byte \d+ of \d+: .*; last readable message at 17\d+\.\d+ s; read \d+ frames"):
            for f in log.frames():
                got.append(f)
    assert 15 <= len(got) < 40
    for g in got:
        np.testing.assert_array_equal(g.color, FRAMES[g.index].color)
    assert [g.index for g in got] == list(range(len(got)))


def test_log_cut_inside_the_header_is_an_input_error(raw_log, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw_log.read_bytes()[:20])
    with pytest.raises(InputError, match="no readable MCAP records|no colour image topic"):
        open_log(cut)


def test_not_mcap(tmp_path):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"hello world, not a log at all")
    with pytest.raises(InputError, match="not an MCAP file"):
        open_log(bad)
    bag = tmp_path / "x.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 64)
    with pytest.raises(InputError, match="ROS 1 bag"):
        open_log(bag)


def _stream(frames, color="bgr8", depth="16UC1", corrupt_at=(), info=True, color_topic="/cam/color",
            depth_topic="/cam/depth", extra=()):
    msgs = list(extra)
    if info:
        msgs.append(("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                     m.ros2_camera_info(frames[0].stamp, "cam", INTR), frames[0].stamp))
    for i, f in enumerate(frames):
        ce, de = encode_color(f.color, color), encode_depth(f.depth, depth)
        if i in corrupt_at:
            ce = type(ce)(ce.raw, b"\xff\xd8garbage", ce.encoding, ce.step, ce.format)
        kind = "sensor_msgs/msg/Image" if ce.raw else "sensor_msgs/msg/CompressedImage"
        msgs.append((color_topic, kind, m.ros2_image(f.stamp, "cam", 48, 64, ce), f.stamp))
        kind = "sensor_msgs/msg/Image" if de.raw else "sensor_msgs/msg/CompressedImage"
        msgs.append((depth_topic, kind, m.ros2_image(f.stamp, "cam", 48, 64, de), f.stamp))
    return msgs


def test_corrupt_frame_is_skipped_and_counted(tmp_path):
    path = tmp_path / "log.mcap"
    write_ros2(path, _stream(FRAMES[:6], color="jpeg", corrupt_at={2, 4}))
    with open_log(path) as log:
        idx = [f.index for f in log.frames()]
        corrupt = log.stats["corrupt"]
    assert idx == [0, 1, 3, 5]
    assert [c[0] for c in corrupt] == [FRAMES[2].stamp, FRAMES[4].stamp]
    assert all("not a decodable JPEG/PNG" in c[1] for c in corrupt)


def test_corrupt_chunk_is_skipped_when_indexed(raw_log, tmp_path):
    data = bytearray(raw_log.read_bytes())
    mid = len(data) // 2
    data[mid: mid + 64] = b"\xAA" * 64  # bit rot in one chunk; CRCs catch it
    bad = tmp_path / "rot.mcap"
    bad.write_bytes(bytes(data))
    with open_log(bad) as log:
        assert log.indexed
        got = [f.index for f in log.frames()]
        corrupt = log.stats["corrupt"]
    assert 30 <= len(got) < 40 and any("unreadable" in c[1] for c in corrupt)


def test_nan_depth_is_invalid_not_an_error(tmp_path):
    f = make_frames(1, seed=6)[0]
    f.depth[:10] = np.nan
    f.depth[10:12] = np.inf
    path = tmp_path / "log.mcap"
    write_ros2(path, _stream([f], depth="32FC1"))
    with open_log(path) as log:
        (got,) = list(log.frames())
    assert np.isfinite(got.depth).all() and (got.depth[:12] == 0).all()
    np.testing.assert_array_equal(got.depth[12:], f.depth[12:])


def test_all_invalid_depth_is_flagged(tmp_path):
    frames = make_frames(3, seed=7)
    for f in frames:
        f.depth[:] = np.nan
    path = tmp_path / "log.mcap"
    write_ros2(path, _stream(frames, depth="32FC1"))
    with open_log(path) as log:
        s = log.summary()
    assert s.depth_all_invalid and s.depth_valid_fraction == 0.0
    assert "invalid" in str(s)


def test_unsupported_encoding(tmp_path):
    frames = make_frames(2, seed=8)
    msgs = _stream(frames)
    msgs = [(t, k, {**msg, "encoding": "yuv422"} if t == "/cam/color" else msg, s) for t, k, msg, s in msgs]
    path = tmp_path / "log.mcap"
    write_ros2(path, msgs)
    with open_log(path) as log, pytest.raises(InputError, match="colour encoding 'yuv422' is not supported"):
        list(log.frames())


def test_colour_and_depth_sizes_differ(tmp_path):
    frames = make_frames(2, seed=9)
    small = make_frames(2, seed=9, w=32, h=24)
    msgs = _stream(frames)
    for i, f in enumerate(small):  # replace depth with half-size images
        msgs = [x for x in msgs if not (x[0] == "/cam/depth" and x[3] == f.stamp)]
        msgs.append(("/cam/depth", "sensor_msgs/msg/Image",
                     m.ros2_image(f.stamp, "cam", 24, 32, encode_depth(f.depth, "16UC1")), f.stamp))
    msgs.sort(key=lambda x: x[3])
    path = tmp_path / "log.mcap"
    write_ros2(path, msgs)
    with open_log(path) as log, pytest.raises(InputError, match="colour is 64x48 but depth is 32x24"):
        list(log.frames())


def test_no_intrinsics_names_the_flags(tmp_path):
    path = tmp_path / "log.mcap"
    write_ros2(path, _stream(make_frames(2, seed=10), info=False))
    with open_log(path) as log:
        with pytest.raises(InputError, match="--fx/--fy/--cx/--cy"):
            log.intrinsics
        log.set_intrinsics(INTR)
        assert log.intrinsics == INTR


def test_calibration_at_another_resolution_is_scaled(tmp_path):
    hd = INTR.scaled(128, 96)
    msgs = _stream(make_frames(2, seed=11), info=False)
    msgs.insert(0, ("/cam/camera_info", "sensor_msgs/msg/CameraInfo", m.ros2_camera_info(0.0, "cam", hd), 1.0))
    path = tmp_path / "log.mcap"
    write_ros2(path, msgs)
    with open_log(path) as log:
        k = log.intrinsics
    assert (k.width, k.height) == (64, 48)
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], [INTR.fx, INTR.fy, INTR.cx, INTR.cy], atol=1e-12)


def test_missing_colour_or_depth_topic(tmp_path):
    only_depth = [x for x in _stream(make_frames(2, seed=12)) if x[0] != "/cam/color"]
    write_ros2(tmp_path / "a.mcap", only_depth)
    with pytest.raises(InputError, match="no colour image topic.*--color-topic"):
        open_log(tmp_path / "a.mcap")
    only_color = [x for x in _stream(make_frames(2, seed=12)) if x[0] != "/cam/depth"]
    write_ros2(tmp_path / "b.mcap", only_color)
    with pytest.raises(InputError, match="no depth image topic.*--depth-topic"):
        open_log(tmp_path / "b.mcap")


def test_iai_kinect2_resolutions_and_ambiguity(tmp_path):
    frames = make_frames(2, seed=13)
    msgs = []
    for res in ("hd", "qhd", "sd"):
        msgs += _stream(frames, color_topic=f"/kinect2/{res}/image_color_rect",
                        depth_topic=f"/kinect2/{res}/image_depth_rect", info=False)
        msgs += _stream(frames, color="jpeg", depth="png", info=False,
                        color_topic=f"/kinect2/{res}/image_color_rect/compressed",
                        depth_topic=f"/kinect2/{res}/image_depth_rect/compressed")
    msgs += [(f"/kinect2/{r}/camera_info", "sensor_msgs/msg/CameraInfo",
              m.ros2_camera_info(frames[0].stamp, "cam", INTR), frames[0].stamp) for r in ("hd", "qhd", "sd")]
    msgs.sort(key=lambda x: x[3])
    write_ros2(tmp_path / "k2.mcap", msgs)
    with open_log(tmp_path / "k2.mcap") as log:
        assert (log.color_topic, log.depth_topic, log.info_topic) == (
            "/kinect2/qhd/image_color_rect", "/kinect2/qhd/image_depth_rect", "/kinect2/qhd/camera_info")
    with open_log(tmp_path / "k2.mcap", color_topic="/kinect2/hd/image_color_rect/compressed") as log:
        assert (log.depth_topic, log.info_topic) == ("/kinect2/hd/image_depth_rect", "/kinect2/hd/camera_info")
    two = _stream(frames, color_topic="/left/image", info=False) + \
        _stream(frames, color_topic="/right/image", depth_topic="/cam/depth2", info=False)
    write_ros2(tmp_path / "two.mcap", sorted(two, key=lambda x: x[3]))
    with pytest.raises(InputError, match=r"several colour topics fit \(/left/image, /right/image\).*--color-topic"):
        open_log(tmp_path / "two.mcap")
    with pytest.raises(InputError, match="--color-topic /nope is not in the log"):
        open_log(tmp_path / "two.mcap", color_topic="/nope")


def test_mount_from_a_tf_chain(tmp_path):
    frames = make_frames(2, seed=14)
    T1 = np.eye(4)
    T1[:3, :3], T1[:3, 3] = rot_z(0.3), [0.2, 0.0, 0.4]
    T2 = np.eye(4)
    T2[:3, :3], T2[:3, 3] = rot_z(-0.1) @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]]), [0.0, 0.05, 0.0]
    tf = m.ros2_tf_message([(frames[0].stamp, "base_link", "kinect2_link", T1),
                            (frames[0].stamp, "cam", "kinect2_link", np.linalg.inv(T2))])  # reversed edge
    msgs = [("/tf_static", "tf2_msgs/msg/TFMessage", tf, frames[0].stamp)] + _stream(frames)
    write_ros2(tmp_path / "tf.mcap", msgs)
    with open_log(tmp_path / "tf.mcap") as log:
        mount = log.mount
    assert mount.parent_frame == "base_link" and mount.child_frame == "cam"
    np.testing.assert_allclose(mount.T_base_cam, T1 @ T2, atol=1e-12)
