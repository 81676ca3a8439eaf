"""RGBDLogWriter -> open_log round trips for every encoding and both profiles."""
import os

import numpy as np
import pytest

from planar_vo.core.geometry import matrix_from_pose7, mount_rotation
from planar_vo.io import Mount, RGBDLogWriter, open_log
from planar_vo.io.codecs import depth_to_mm
from planar_vo.core.types import CameraIntrinsics

from iohelpers import INTR, make_frames

FRAMES = make_frames(6, seed=3)
T_BASE_CAM = np.eye(4)
T_BASE_CAM[:3, :3] = mount_rotation(np.radians(12.0), np.radians(-2.0), np.radians(3.0))
T_BASE_CAM[:3, 3] = [0.21, -0.03, 0.55]


def gt_pose(i):
    return matrix_from_pose7([0.1 * i, 0.02 * i, 1.0, 0.0, 0.0, np.sin(0.05 * i), np.cos(0.05 * i)])


def write_log(path, profile, color_encoding, depth_encoding, frames=FRAMES, **kw):
    with RGBDLogWriter(path, INTR, profile=profile, mount=Mount(T_BASE_CAM),
                       color_encoding=color_encoding, depth_encoding=depth_encoding, **kw) as w:
        for i, f in enumerate(frames):
            w.write(f)
            w.write_ground_truth(f.stamp, gt_pose(i))
    return path


CASES = [(p, c, d) for p in ("ros2", "foxglove")
         for c, d in (("png", "png"), ("bgr8", "16UC1"), ("rgb8", "32FC1"), ("jpeg", "compressedDepth"),
                      ("mono8", "png"))]


@pytest.mark.parametrize("color_enc", ["png", "jpeg", "rgb8", "mono8"])
def test_gray_color_mode_gives_the_intensity(tmp_path, color_enc):
    """What the pipeline reads (``set_color_mode("gray")``): (H, W) uint8 frames, the
    intensity of the colour frames, the same depth and count."""
    import cv2

    path = write_log(tmp_path / "log.mcap", "ros2", color_enc, "png")
    with open_log(path) as log:
        colour = list(log.frames())
    with open_log(path) as log:
        log.set_color_mode("gray")
        grey = list(log.frames())
        with pytest.raises(ValueError, match="color mode"):
            log.set_color_mode("rgb")
    assert len(grey) == len(colour) == len(FRAMES)
    for g, f in zip(grey, colour):
        assert g.color.shape == f.color.shape[:2] and g.color.dtype == np.uint8
        diff = np.abs(g.color.astype(int) - cv2.cvtColor(f.color, cv2.COLOR_BGR2GRAY))
        assert diff.mean() < 0.5 if color_enc == "jpeg" else diff.max() <= 1
        np.testing.assert_array_equal(g.depth, f.depth)


@pytest.mark.parametrize("profile,color_enc,depth_enc", CASES)
def test_roundtrip(tmp_path, profile, color_enc, depth_enc):
    path = write_log(tmp_path / "log.mcap", profile, color_enc, depth_enc)
    with open_log(path) as log:
        frames = list(log.frames())
        assert log.intrinsics == INTR
        np.testing.assert_allclose(log.mount.T_base_cam, T_BASE_CAM, atol=1e-12)
        gt = log.ground_truth
    assert [f.index for f in frames] == list(range(len(FRAMES)))
    for got, want in zip(frames, FRAMES):
        assert got.stamp == want.stamp  # bit-exact through (sec, nanosec) for epoch stamps
        assert got.color.shape == want.color.shape and got.color.dtype == np.uint8
        if color_enc in ("png", "bgr8", "rgb8"):
            np.testing.assert_array_equal(got.color, want.color)
        elif color_enc == "jpeg":
            assert np.abs(got.color.astype(int) - want.color).mean() < 4.0
        else:
            assert (got.color[..., 0] == got.color[..., 2]).all()
        want_depth = want.depth if depth_enc == "32FC1" else depth_to_mm(want.depth) / np.float32(1000)
        np.testing.assert_array_equal(got.depth, want_depth)
        assert got.depth.dtype == np.float32
    assert gt is not None and len(gt) == len(FRAMES)
    np.testing.assert_array_equal(gt.stamps, [f.stamp for f in FRAMES])
    np.testing.assert_allclose(gt.poses, [gt_pose(i) for i in range(len(FRAMES))], atol=1e-12)


def test_default_topics_are_iai_kinect2(tmp_path):
    path = write_log(tmp_path / "log.mcap", "ros2", "jpeg", "png")
    with open_log(path) as log:
        assert (log.color_topic, log.depth_topic, log.info_topic) == (
            "/kinect2/qhd/image_color_rect/compressed", "/kinect2/qhd/image_depth_rect/compressed",
            "/kinect2/qhd/camera_info")
        assert log.camera_frame == "kinect2_rgb_optical_frame"
        s = log.summary()
    assert s.frames == 6 and s.color_messages == 6 and s.unpaired_color == 0
    assert abs(s.rate_hz - 30.0) < 1e-3  # epoch stamps are spaced 2.4e-7 s apart
    text = str(s)
    assert "pitch 12.00 roll -2.00 yaw 3.00 deg" in text
    assert "6 poses" in text and "fx 50.000 fy 51.000" in text


def test_frame_selection(tmp_path):
    path = write_log(tmp_path / "log.mcap", "ros2", "bgr8", "16UC1")
    with open_log(path) as log:
        assert [f.index for f in log.frames(1, 6, 2)] == [1, 3, 5]
        assert [f.index for f in log.frames(4)] == [4, 5]
        assert [f.index for f in log.frames(stop=2)] == [0, 1]
        with pytest.raises(ValueError, match="stride"):
            list(log.frames(stride=0))


def test_writer_is_atomic(tmp_path):
    path = tmp_path / "log.mcap"
    with pytest.raises(RuntimeError):
        with RGBDLogWriter(path, INTR) as w:
            w.write(FRAMES[0])
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []
    path.write_bytes(b"old")
    with pytest.raises(ValueError, match=r"\(48, 64, 3\)"):
        with RGBDLogWriter(path, INTR) as w:
            w.write(make_frames(1, seed=0, w=32, h=24)[0])  # wrong size
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["log.mcap"]


def test_writer_validates_arguments(tmp_path):
    with pytest.raises(ValueError, match="color_encoding"):
        RGBDLogWriter(tmp_path / "a.mcap", INTR, color_encoding="webp")
    with pytest.raises(ValueError, match="unknown topic keys"):
        RGBDLogWriter(tmp_path / "a.mcap", INTR, topics={"colour": "/x"})
    assert os.listdir(tmp_path) == []


def test_distorted_intrinsics_and_custom_topics(tmp_path):
    k = CameraIntrinsics(64, 48, 50.0, 51.0, 31.5, 23.5, (0.1, -0.2, 0.001, 0.002, 0.05))
    path = tmp_path / "log.mcap"
    with RGBDLogWriter(path, k, topics={"color": "/cam/color/image_raw", "depth": "/cam/depth/image_raw",
                                        "info": "/cam/color/camera_info"},
                       color_encoding="bgr8", depth_encoding="16UC1") as w:
        for f in FRAMES[:2]:
            w.write(f)
    with open_log(path) as log:
        assert log.intrinsics == k
        assert log.mount is None and log.ground_truth is None
        assert len(list(log.frames())) == 2


def test_depth_stream_offset_pairs_within_tolerance(tmp_path):
    """Depth stamped 7 ms after colour: paired at 20 ms tolerance, not at 5 ms."""
    from iohelpers import write_ros2
    from planar_vo.io import messages as m
    from planar_vo.io.codecs import encode_color, encode_depth
    msgs = [("/cam/info", "sensor_msgs/msg/CameraInfo", m.ros2_camera_info(0.5, "cam", INTR), 0.5)]
    for f in FRAMES:
        msgs.append(("/cam/color", "sensor_msgs/msg/Image",
                     m.ros2_image(f.stamp, "cam", 48, 64, encode_color(f.color, "bgr8")), f.stamp))
        msgs.append(("/cam/depth", "sensor_msgs/msg/Image",
                     m.ros2_image(f.stamp + 0.007, "cam", 48, 64, encode_depth(f.depth, "16UC1")), f.stamp + 0.007))
    write_ros2(tmp_path / "log.mcap", msgs)
    with open_log(tmp_path / "log.mcap") as log:
        frames = list(log.frames())
        assert len(frames) == 6 and frames[0].depth_stamp == pytest.approx(FRAMES[0].stamp + 0.007)
    with open_log(tmp_path / "log.mcap", sync_tolerance=0.005) as log:
        assert list(log.frames()) == []
        assert log.stats["unpaired_color"] == 6 and log.stats["unpaired_depth"] == 6
