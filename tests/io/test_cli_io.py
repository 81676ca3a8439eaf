"""`planar-vo info` / `convert` on good and bad input: exit codes and one-line messages."""
from pathlib import Path

import numpy as np

from planar_vo.io import RGBDLogWriter, messages as m
from planar_vo.io.codecs import encode_color, encode_depth

from iohelpers import INTR, make_frames, write_ros2

SAMPLE = Path(__file__).resolve().parents[2] / "data" / "tum_fr1_xyz_head10"


def one_line_error(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in lines[0], (n, lines[0])


def plain_log(path, frames, depth_fn=None, info=True):
    msgs = [] if not info else [("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                                 m.ros2_camera_info(frames[0].stamp, "cam", INTR), frames[0].stamp)]
    for f in frames:
        d = depth_fn(f.depth) if depth_fn else f.depth
        msgs.append(("/cam/color", "sensor_msgs/msg/Image",
                     m.ros2_image(f.stamp, "cam", 48, 64, encode_color(f.color, "bgr8")), f.stamp))
        msgs.append(("/cam/depth", "sensor_msgs/msg/Image",
                     m.ros2_image(f.stamp, "cam", 48, 64, encode_depth(d, "32FC1")), f.stamp))
    write_ros2(path, msgs)
    return path


def test_info_on_tum_sample(run_cli):
    code, out, err = run_cli("info", SAMPLE)
    assert code == 0 and err == ""
    assert "9 paired (1 colour and 2 depth unpaired, 0 corrupt)" in out
    assert "fx 517.300 fy 516.500 cx 318.600 cy 255.300" in out and "70 poses" in out


def test_info_flags_override_intrinsics(tmp_path, run_cli):
    path = plain_log(tmp_path / "a.mcap", make_frames(3, seed=30), info=False)
    code, out, err = run_cli("info", path, "--fx", 60, "--fy", 61, "--cx", 32, "--cy", 24)
    assert code == 0 and "fx 60.000 fy 61.000 cx 32.000 cy 24.000 (64x48)" in out and "[given]" in out
    code, _, err = run_cli("info", path, "--fx", 60)
    assert code == 2
    one_line_error(err, "give all four of --fx/--fy/--cx/--cy", "--fy, --cx, --cy")


def test_not_mcap(tmp_path, run_cli):
    bad = tmp_path / "notes.mcap"
    bad.write_text("just text")
    code, _, err = run_cli("info", bad)
    assert code == 2
    one_line_error(err, "notes.mcap", "not an MCAP file")


def test_truncated(tmp_path, run_cli):
    path = tmp_path / "log.mcap"
    with RGBDLogWriter(path, INTR, color_encoding="bgr8", depth_encoding="16UC1",
                       chunk_compression="none", chunk_size=8 * 1024) as w:
        for f in make_frames(20, seed=31):
            w.write(f)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:-40000])
    code, out, err = run_cli("info", cut)
    assert code == 3  # PartialResult: what was readable is described
    assert "truncated:" in out
    one_line_error(err, "cut short", "at byte", "last readable message at")


def test_no_colour_topic(tmp_path, run_cli):
    frames = make_frames(2, seed=32)
    write_ros2(tmp_path / "d.mcap", [("/cam/depth", "sensor_msgs/msg/Image",
                                       m.ros2_image(f.stamp, "cam", 48, 64, encode_depth(f.depth, "16UC1")), f.stamp)
                                      for f in frames])
    code, _, err = run_cli("info", tmp_path / "d.mcap")
    assert code == 2
    one_line_error(err, "no colour image topic", "--color-topic")


def test_unsupported_encoding(tmp_path, run_cli):
    f = make_frames(1, seed=33)[0]
    msg = m.ros2_image(f.stamp, "cam", 48, 64, encode_color(f.color, "bgr8"))
    msg["encoding"] = "bayer_rggb8"
    write_ros2(tmp_path / "b.mcap", [
        ("/cam/color", "sensor_msgs/msg/Image", msg, f.stamp),
        ("/cam/depth", "sensor_msgs/msg/Image", m.ros2_image(f.stamp, "cam", 48, 64, encode_depth(f.depth, "16UC1")),
         f.stamp)])
    code, _, err = run_cli("info", tmp_path / "b.mcap", "--fx", 1, "--fy", 1, "--cx", 1, "--cy", 1)
    assert code == 2
    one_line_error(err, "bayer_rggb8", "not supported")


def test_sizes_differ(tmp_path, run_cli):
    f = make_frames(1, seed=34)[0]
    g = make_frames(1, seed=34, w=32, h=24)[0]
    write_ros2(tmp_path / "s.mcap", [
        ("/cam/camera_info", "sensor_msgs/msg/CameraInfo", m.ros2_camera_info(f.stamp, "cam", INTR), f.stamp),
        ("/cam/color", "sensor_msgs/msg/Image", m.ros2_image(f.stamp, "cam", 48, 64, encode_color(f.color, "bgr8")), f.stamp),
        ("/cam/depth", "sensor_msgs/msg/Image", m.ros2_image(f.stamp, "cam", 24, 32, encode_depth(g.depth, "16UC1")), f.stamp)])
    code, _, err = run_cli("convert", tmp_path / "s.mcap", tmp_path / "out.mcap")
    assert code == 2
    one_line_error(err, "colour is 64x48 but depth is 32x24")
    assert not (tmp_path / "out.mcap").exists()


def test_no_intrinsics(tmp_path, run_cli):
    path = plain_log(tmp_path / "a.mcap", make_frames(2, seed=35), info=False)
    code, out, err = run_cli("info", path)
    assert code == 2
    one_line_error(err, "no camera calibration", "--fx/--fy/--cx/--cy")


def test_tum_folder_missing_files(tmp_path, run_cli):
    (tmp_path / "rgbd_dataset_freiburg1_x").mkdir()
    (tmp_path / "rgbd_dataset_freiburg1_x" / "depth.txt").write_text("# nothing\n")
    code, _, err = run_cli("info", tmp_path / "rgbd_dataset_freiburg1_x")
    assert code == 2
    one_line_error(err, "rgb.txt is missing")


def test_nan_depth_ok_but_all_invalid_flagged(tmp_path, run_cli):
    frames = make_frames(3, seed=36)

    def some_nan(d):
        d = d.copy()
        d[:5] = np.nan
        return d
    code, out, err = run_cli("info", plain_log(tmp_path / "n.mcap", frames, some_nan))
    assert code == 0 and err == ""
    code, out, err = run_cli("info", plain_log(tmp_path / "z.mcap", frames, lambda d: np.full_like(d, np.nan)))
    assert code == 2 and "depth valid:  0.0 %" in out
    one_line_error(err, "/cam/depth", "invalid (0, NaN or inf) in all 3 sampled frames")


def test_convert_refuses_to_overwrite(tmp_path, run_cli):
    out = tmp_path / "o.mcap"
    out.write_bytes(b"keep")
    code, _, err = run_cli("convert", SAMPLE, out)
    assert code == 2 and out.read_bytes() == b"keep"
    one_line_error(err, "exists", "--overwrite")
