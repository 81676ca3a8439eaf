"""summary() right after a complete frames() pass reuses what the pass saw (no second scan)
and describes the log exactly as a scan of its own would, damaged logs included."""
import numpy as np
import pytest

from planar_vo.core.errors import PartialResult
from planar_vo.io import RGBDLogWriter, open_log
from planar_vo.io import messages as m
from planar_vo.io.codecs import encode_color, encode_depth
from planar_vo.io.mcap_reader import McapRGBDLog

from iohelpers import INTR, make_frames, write_ros2

FRAMES = make_frames(40, seed=11)


def _messages(corrupt_color=(), corrupt_depth=(), small_depth=(), bad_cdr=()):
    msgs = [("/cam/camera_info", "sensor_msgs/msg/CameraInfo", m.ros2_camera_info(FRAMES[0].stamp, "cam", INTR),
             FRAMES[0].stamp)]
    for i, f in enumerate(FRAMES):
        ce, de = encode_color(f.color, "jpeg"), encode_depth(f.depth, "png")
        if i in corrupt_color:
            ce = type(ce)(ce.raw, b"\xff\xd8garbage", ce.encoding, ce.step, ce.format)
        if i in corrupt_depth:
            de = type(de)(de.raw, b"\x89PNG\r\n\x1a\ngarbage", de.encoding, de.step, de.format)
        if i in small_depth:
            de = encode_depth(f.depth[::2, ::2], "png")
        msgs.append(("/cam/color", "sensor_msgs/msg/CompressedImage", m.ros2_image(f.stamp, "cam", 48, 64, ce),
                     f.stamp))
        if i in bad_cdr:
            continue  # written separately below, as an undecodable message
        msgs.append(("/cam/depth", "sensor_msgs/msg/CompressedImage", m.ros2_image(f.stamp, "cam", 48, 64, de),
                     f.stamp))
    return msgs


def _described(log) -> tuple:
    s = log.summary()
    d = {k: v for k, v in vars(s).items() if k not in ("mount", "intrinsics")}
    return d, s.intrinsics, log.stats


def _compare(path, expect_partial=False):
    with open_log(path) as fresh:
        want = _described(fresh)
    with open_log(path) as log:
        got_frames = []
        if expect_partial:
            with pytest.raises(PartialResult):
                for f in log.frames():
                    got_frames.append(f.index)
        else:
            got_frames = [f.index for f in log.frames()]
        # No second scan: reading any message now would fail.
        log._pair_events = None
        got = _described(log)
    assert got == want
    return got_frames, want


def test_clean_log(tmp_path):
    path = tmp_path / "clean.mcap"
    write_ros2(path, _messages())
    frames, (s, _, stats) = _compare(path)
    assert frames == list(range(40)) and s["frames"] == 40 and s["depth_frames_sampled"] == 14
    assert s["depth_valid_fraction"] == pytest.approx(0.9, abs=0.03)


def test_corrupt_colour_and_depth_at_sampled_and_other_frames(tmp_path):
    path = tmp_path / "bad.mcap"
    # every = 40 // 12 = 3: frames 0, 3, 6, ... are sampled by summary()
    write_ros2(path, _messages(corrupt_color={3, 4}, corrupt_depth={6, 7}, small_depth={9}))
    frames, (s, _, stats) = _compare(path)
    assert 3 not in frames and 6 not in frames and 9 not in frames
    # summary() sees only the sampled depths: 6 fails; the colour of 3 does not matter to it
    assert s["corrupt"] == 1 and len(stats["corrupt"]) == 1
    assert s["depth_frames_sampled"] == 13


def test_undecodable_messages_mixed_with_bad_frames(tmp_path, mcap_rewriter):
    src, path = tmp_path / "src.mcap", tmp_path / "cdr.mcap"
    write_ros2(src, _messages(corrupt_color={3}, corrupt_depth={11}))
    mcap_rewriter(src, path, lambda topic, k, data: b"\x00\x01"
                  if topic == "/cam/depth" and k in {5, 6, 20} else data)
    frames, (s, _, stats) = _compare(path)
    # 37 pairs (three depth messages undecodable: their colour is unpaired), 2 bad frames
    assert s["frames"] == 37 and len(frames) == 35
    # summary(): the three undecodable messages and the depth of frame 11 (pair 9, sampled)
    assert s["unpaired_color"] == 3 and s["corrupt"] == 4
    assert [("undecodable" in r) for _, r in stats["corrupt"]] == [True, True, False, True]


def test_truncated_log(tmp_path):
    src = tmp_path / "raw.mcap"
    with RGBDLogWriter(src, INTR, color_encoding="bgr8", depth_encoding="16UC1",
                       chunk_compression="none", chunk_size=16 * 1024) as w:
        for f in FRAMES:
            w.write(f)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[: int(src.stat().st_size * 0.6)])
    frames, (s, _, _) = _compare(cut, expect_partial=True)
    assert s["truncated"] and "byte" in s["truncated"] and s["frames"] == len(frames)


def test_partial_passes_do_not_stand_in_for_a_scan(tmp_path):
    path = tmp_path / "clean.mcap"
    write_ros2(path, _messages(corrupt_depth={6}))
    with open_log(path) as fresh:
        want = _described(fresh)
    for kwargs in ({"start": 1}, {"stop": 30}, {"stride": 2}):
        with open_log(path) as log:
            list(log.frames(**kwargs))
            assert log._facts is None
            assert _described(log) == want
    with open_log(path) as log:  # a pass stopped early by its consumer
        it = log.frames()
        next(it)
        it.close()
        assert log._facts is None
        assert _described(log) == want
    assert isinstance(log, McapRGBDLog)


def test_expected_frames_from_the_index(tmp_path):
    path = tmp_path / "clean.mcap"
    write_ros2(path, _messages(bad_cdr={5}))
    with open_log(path) as log:
        assert log.expected_frames() == 39
        assert np.isfinite(log.summary().frames)
