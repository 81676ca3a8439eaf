"""One synthetic log in every container: ROS 2 MCAP, Foxglove MCAP, ROS 1 bag, rosbag2 sqlite3
and mcap folders, ROS 1-profile MCAP. Frames, calibration, mount, ground truth and the run's
raw.tum must not depend on the container; damaged or incomplete containers give one line."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planar_vo.config import load_config
from planar_vo.io import open_log
from planar_vo.sim.synth import SynthConfig, write_synth_log
from planar_vo.io.trajectory import read_poses_mcap, read_tum_trajectory, write_poses_mcap
from planar_vo.core.types import Trajectory

from test_cli_io import one_line_error

#: name -> (container, profile, output name)
CONTAINERS = {
    "ros2_mcap": ("mcap", "ros2", "log.mcap"),
    "foxglove_mcap": ("mcap", "foxglove", "log.mcap"),
    "bag": ("bag", "ros2", "log.bag"),
    "rosbag2_sqlite3": ("rosbag2-sqlite3", "ros2", "log"),
    "rosbag2_mcap": ("rosbag2-mcap", "ros2", "log"),
    "ros1_mcap": ("mcap-ros1", "ros2", "log.mcap"),
}
FORMATS = {"ros2_mcap": "MCAP (ROS 2, cdr)", "foxglove_mcap": "MCAP (Foxglove, protobuf)",
           "bag": "ROS 1 bag (ros1)", "rosbag2_sqlite3": "rosbag2 (sqlite3, cdr)",
           "rosbag2_mcap": "rosbag2 (mcap, cdr)", "ros1_mcap": "MCAP (ROS 1, ros1)"}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    """The same 10-frame straight corridor (320x180, seed 4) written in every container."""
    cfg = SynthConfig(layout="straight", seed=4, n_frames=10, speed=2.0).at_resolution(320, 180)
    out = {}
    for name, (container, profile, fname) in CONTAINERS.items():
        path = tmp_path_factory.mktemp(name) / fname
        write_synth_log(cfg, path, profile=profile, container=container, progress=False)
        out[name] = path
    return out


def _read(path):
    with open_log(path) as log:
        frames = [(f.stamp, f.color, f.depth) for f in log.frames()]
        return frames, log.intrinsics, log.mount, log.ground_truth, log.summary()


def test_every_container_gives_the_same_frames(logs):
    ref_frames, ref_k, ref_mount, ref_gt, _ = _read(logs["ros2_mcap"])
    assert len(ref_frames) == 10
    for name, path in logs.items():
        frames, k, mount, gt, summary = _read(path)
        assert summary.format == FORMATS[name]
        assert summary.frames == 10 and summary.corrupt == 0
        assert len(frames) == len(ref_frames), name
        for (s, c, d), (rs, rc, rd) in zip(frames, ref_frames):
            assert s == rs
            np.testing.assert_array_equal(c, rc, err_msg=name)
            np.testing.assert_array_equal(d, rd, err_msg=name)
        assert k == ref_k, name
        np.testing.assert_array_equal(mount.T_base_cam, ref_mount.T_base_cam, err_msg=name)
        assert (mount.parent_frame, mount.child_frame) == (ref_mount.parent_frame, ref_mount.child_frame)
        np.testing.assert_array_equal(gt.stamps, ref_gt.stamps, err_msg=name)
        np.testing.assert_allclose(gt.poses, ref_gt.poses, atol=1e-12, err_msg=name)


def test_metadata_yaml_names_the_folder(logs):
    frames, *_ = _read(logs["rosbag2_sqlite3"] / "metadata.yaml")
    assert len(frames) == 10


@pytest.fixture(scope="module")
def runs(logs, tmp_path_factory) -> dict[str, Path]:
    from planar_vo.pipeline import run
    config = load_config(None, {"output": {"plot": False}})
    out = {}
    for name, path in logs.items():
        out[name] = tmp_path_factory.mktemp(f"run_{name}")
        run(path, out[name], config, progress=False)
    return out


def test_run_gives_identical_raw_tum_in_every_container(runs):
    ref = (runs["ros2_mcap"] / "raw.tum").read_bytes()
    assert len(read_tum_trajectory(runs["ros2_mcap"] / "raw.tum")) == 10
    for name, out in runs.items():
        assert (out / "raw.tum").read_bytes() == ref, name
        assert (out / "smoothed.tum").read_bytes() == (runs["ros2_mcap"] / "smoothed.tum").read_bytes(), name


def test_poses_mcap_follows_the_log_family(runs):
    from mcap.reader import make_reader
    for name, out in runs.items():
        with open(out / "poses.mcap", "rb") as f:
            summary = make_reader(f).get_summary()
        schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        if name == "foxglove_mcap":
            assert schemas["/planar_vo/smoothed/pose"] == "foxglove.PoseInFrame"
        else:
            assert schemas == {"/planar_vo/raw/odom": "nav_msgs/msg/Odometry",
                               "/planar_vo/smoothed/odom": "nav_msgs/msg/Odometry",
                               "/planar_vo/raw/path": "nav_msgs/msg/Path",
                               "/planar_vo/smoothed/path": "nav_msgs/msg/Path",
                               "/tf": "tf2_msgs/msg/TFMessage"}, name
        smoothed = read_tum_trajectory(out / "smoothed.tum")
        back = read_poses_mcap(out / "poses.mcap")["smoothed"]
        np.testing.assert_allclose(back.poses, smoothed.poses, atol=1e-9)
        np.testing.assert_allclose(back.stamps, smoothed.stamps, atol=1e-9)


def test_evo_reads_poses_mcap_of_a_ros_log(runs, tmp_path):
    """What `evo_traj bag2 poses.mcap /planar_vo/smoothed/odom` reads equals smoothed.tum."""
    from evo.tools import file_interface
    from rosbags.rosbag2 import Reader

    out = runs["bag"]
    smoothed = read_tum_trajectory(out / "smoothed.tum")
    reader = Reader(out / "poses.mcap")
    reader.open()
    try:
        traj = file_interface.read_bag_trajectory(reader, "/planar_vo/smoothed/odom")
    finally:
        reader.close()
    np.testing.assert_allclose(traj.timestamps, smoothed.stamps, atol=1e-6)
    np.testing.assert_allclose(traj.poses_se3, smoothed.poses, atol=1e-6)
    # the command itself, as a user types it
    evo_traj = Path(sys.executable).parent / "evo_traj"
    subprocess.run([str(evo_traj), "bag2", str(out / "poses.mcap"), "/planar_vo/smoothed/odom", "--save_as_tum"],
                   cwd=tmp_path, check=True, capture_output=True, env={**os.environ, "MPLBACKEND": "Agg"})
    saved = read_tum_trajectory(tmp_path / "planar_vo_smoothed_odom.tum")
    np.testing.assert_allclose(saved.stamps, smoothed.stamps, atol=1e-6)
    np.testing.assert_allclose(saved.poses, smoothed.poses, atol=1e-6)


@pytest.mark.parametrize("fmt", ["ros2", "foxglove"])
def test_poses_mcap_roundtrip_in_both_formats(tmp_path, fmt):
    rng = np.random.default_rng(7)
    n = 40
    stamps = 1.7e9 + np.arange(n) / 10
    yaw = np.cumsum(rng.normal(0, 0.05, n))
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    poses[:, :3, 3] = np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0)
    trajs = {"raw": Trajectory(stamps, poses, frame_id="odom", child_frame_id="camera_optical_frame")}
    write_poses_mcap(tmp_path / "poses.mcap", trajs, transforms=[(stamps[0], "odom", "base_link", poses[0])],
                     format=fmt)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["poses.mcap"]
    back = read_poses_mcap(tmp_path / "poses.mcap")["raw"]
    np.testing.assert_array_equal(back.stamps, stamps)
    np.testing.assert_allclose(back.poses, poses, atol=1e-12)
    assert (back.frame_id, back.child_frame_id) == ("odom", "camera_optical_frame")


# ----------------------------------------------------------------------------- bad input

def _cut_copy(src: Path, dst_dir: Path, keep: float = 0.6) -> Path:
    """A copy of a log (file or folder) whose data file is cut to ``keep`` of its length."""
    dst = dst_dir / src.name
    if src.is_dir():
        shutil.copytree(src, dst)
        data = next(p for p in dst.iterdir() if p.name != "metadata.yaml")
    else:
        shutil.copy(src, dst)
        data = dst
    raw = data.read_bytes()
    data.write_bytes(raw[:int(len(raw) * keep)])
    return dst


@pytest.mark.parametrize("name, code, needles", [
    ("bag", 2, ("cannot open the ROS 1 bag", "no index")),
    ("rosbag2_sqlite3", 2, ("cannot open the rosbag2 folder", "malformed")),
])
def test_truncated_container(logs, tmp_path, run_cli, name, code, needles):
    cut = _cut_copy(logs[name], tmp_path)
    got, out, err = run_cli("info", cut)
    assert got == code, err
    one_line_error(err, *needles)
    if code == 3:
        assert "truncated:" in out


@pytest.mark.parametrize("container, name", [("rosbag2-mcap", "bag"), ("mcap-ros1", "bag.mcap")])
def test_truncated_mcap_keeps_its_readable_chunks(tmp_path, run_cli, container, name):
    """A cut MCAP (a rosbag2 folder's or a ROS 1-profile one) yields the chunks before the cut
    (rosbags needs the MCAP summary; the MCAP reader reads what it can), then exit 3."""
    from iohelpers import INTR, make_frames
    from planar_vo.io.rosbags_writer import open_log_writer
    frames = make_frames(100, seed=40)  # raw 64x48: 1.5 MB, two of rosbags' 1 MiB chunks
    with open_log_writer(tmp_path / name, INTR, container=container, color_encoding="bgr8",
                         depth_encoding="16UC1", chunk_size=64 * 1024, chunk_compression="none") as w:
        for f in frames:
            w.write(f)
    (tmp_path / "cut").mkdir()
    cut = _cut_copy(tmp_path / name, tmp_path / "cut", keep=0.8)
    code, out, err = run_cli("info", cut)
    assert code == 3, err
    one_line_error(err, "cut short", "last readable message at")
    n = int(out.split("frames:")[1].split()[0])
    assert 0 < n < 100
    with open_log(cut) as log:
        got = []
        with pytest.raises(Exception, match="cut short"):
            for f in log.frames():
                got.append(f)
    assert len(got) == n
    for f, ref in zip(got, frames):
        np.testing.assert_array_equal(f.color, ref.color)


@pytest.mark.parametrize("name", list(CONTAINERS))
def test_missing_topic(logs, run_cli, name):
    code, _, err = run_cli("info", logs[name], "--color-topic", "/camera/nope")
    assert code == 2
    one_line_error(err, "--color-topic /camera/nope is not in the log", "/kinect2/qhd/image_color_rect/compressed")


@pytest.mark.parametrize("name", ["rosbag2_sqlite3", "rosbag2_mcap"])
def test_rosbag2_folder_without_metadata(logs, tmp_path, run_cli, name):
    folder = tmp_path / "bag"
    shutil.copytree(logs[name], folder)
    (folder / "metadata.yaml").unlink()
    code, _, err = run_cli("info", folder)
    assert code == 2
    one_line_error(err, "rosbag2 folder", "no metadata.yaml")


def test_convert_a_bag_to_mcap(logs, tmp_path, run_cli):
    code, out, err = run_cli("convert", logs["bag"], tmp_path / "out.mcap")
    assert code == 0, err
    ref, *_ = _read(logs["bag"])
    back, *_ = _read(tmp_path / "out.mcap")
    assert len(back) == len(ref) == 10
    for (s, c, d), (rs, rc, rd) in zip(back, ref):
        assert s == rs
        np.testing.assert_array_equal(c, rc)
        np.testing.assert_array_equal(d, rd)


def test_synth_container_names_checked(tmp_path, capsys):
    from planar_vo import cli
    for argv, needle in ((["synth", str(tmp_path / "a.mcap"), "--container", "bag"], "must end in .bag"),
                         (["synth", str(tmp_path / "a.bag"), "--container", "rosbag2-mcap"], "writes a folder"),
                         (["synth", str(tmp_path / "a"), "--container", "zip"], "--container 'zip'"),
                         (["synth", str(tmp_path / "a.bag"), "--container", "bag", "--profile", "foxglove"],
                          "--container mcap only")):
        assert cli.main(argv) == 2
        one_line_error(capsys.readouterr().err, needle)
    assert list(tmp_path.iterdir()) == []


def test_ros2_dicts_serialise_as_ros1_and_back():
    """A ROS 2-style dict becomes a ROS 1 message (K from k, seq zero) and parses back the same."""
    from iohelpers import INTR
    from planar_vo.io import messages as m, rosmsg
    d = m.ros2_camera_info(1_700_000_000.25, "cam", INTR)
    raw = rosmsg.serialize(rosmsg.ROS1, "sensor_msgs/msg/CameraInfo", d)
    msg = rosmsg.typestore(rosmsg.ROS1).deserialize_ros1(raw, "sensor_msgs/msg/CameraInfo")
    assert msg.header.seq == 0 and msg.header.frame_id == "cam"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    np.testing.assert_array_equal(msg.K, [50.0, 0, 31.5, 0, 51.0, 23.5, 0, 0, 1])
    assert m.parse_camera_info(msg, rectified=False) == INTR
    with pytest.raises(ValueError, match="fixed array of 9 float64 got 4"):
        rosmsg.serialize(rosmsg.ROS1, "sensor_msgs/msg/CameraInfo", {**d, "k": [1.0, 2.0, 3.0, 4.0]})


def test_run_flag_chooses_the_poses_format(logs, tmp_path):
    from mcap.reader import make_reader

    from planar_vo import cli
    for fmt, schema in (("foxglove", "foxglove.PoseInFrame"), ("ros2", "nav_msgs/msg/Odometry")):
        out = tmp_path / fmt
        src = logs["bag"] if fmt == "foxglove" else logs["foxglove_mcap"]  # against the log's family
        assert cli.main(["run", str(src), "--out", str(out), "--poses-format", fmt, "--no-plot", "--quiet"]) in (0, 4)
        with open(out / "poses.mcap", "rb") as f:
            summary = make_reader(f).get_summary()
        assert schema in {s.name for s in summary.schemas.values()}
        back = read_poses_mcap(out / "poses.mcap")["raw"]
        np.testing.assert_allclose(back.poses, read_tum_trajectory(out / "raw.tum").poses, atol=1e-9)


# ---------------------------------------------------------------- wheel odometry
#: name -> (container, profile, output name, where the odometry goes)
ODOM_LOGS = {**{name: (*spec, "odom") for name, spec in CONTAINERS.items()},
             "bag_tf": ("bag", "ros2", "log.bag", "tf"),
             "rosbag2_sqlite3_tf": ("rosbag2-sqlite3", "ros2", "log", "tf"),
             "ros1_mcap_tf": ("mcap-ros1", "ros2", "log.mcap", "tf")}


@pytest.fixture(scope="module")
def odom_logs(tmp_path_factory) -> dict[str, Path]:
    """The 10-frame corridor of ``logs`` with wheel odometry (+2 % scale, seeded noise) in
    every container, on /odom and, for the ROS 1 and rosbag2 containers, on /tf."""
    from planar_vo.io.wheel_odom import WheelOdomModel
    cfg = SynthConfig(layout="straight", seed=4, n_frames=10, speed=2.0).at_resolution(320, 180)
    out = {}
    for name, (container, profile, fname, on) in ODOM_LOGS.items():
        path = tmp_path_factory.mktemp(f"odom_{name}") / fname
        write_synth_log(cfg, path, profile=profile, container=container, progress=False,
                        wheel_odom=WheelOdomModel(seed=4), wheel_odom_on=on)
        out[name] = path
    return out


def test_every_container_gives_the_same_wheel_odometry(odom_logs):
    with open_log(odom_logs["ros2_mcap"]) as log:
        ref, gt = log.wheel_odometry(), log.ground_truth
    assert len(ref.stamps) == 46 and ref.stamps[-1] - ref.stamps[0] == pytest.approx(0.9)  # 50 Hz
    # the base's path (1.06 m) is close to the camera's (1.08 m; the camera swings with the weave)
    odo_len = np.linalg.norm(np.diff(ref.poses[:, :2], axis=0), axis=1).sum()
    cam_len = np.linalg.norm(np.diff(gt.poses[:, :3, 3], axis=0), axis=1).sum()
    assert odo_len == pytest.approx(cam_len, rel=0.03)
    for name, path in odom_logs.items():
        with open_log(path) as log:
            odo = log.wheel_odometry()
            described = log.summary().wheel_odometry
        assert odo is not None, name
        assert odo.topic == ("/tf" if name.endswith("_tf") else "/odom"), name
        np.testing.assert_allclose(odo.stamps, ref.stamps, rtol=0, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(odo.poses, ref.poses, rtol=0, atol=1e-9, err_msg=name)
        assert "46 samples" in described, name


def test_synth_keeps_the_odometry_parameters_in_rosbag2_metadata(odom_logs):
    import json

    import yaml
    meta = yaml.safe_load((odom_logs["rosbag2_mcap"] / "metadata.yaml").read_text())
    custom = meta["rosbag2_bagfile_information"]["custom_data"]
    assert json.loads(custom["planar_vo.wheel_odometry"])["scale"] == "0.02"


@pytest.fixture(scope="module")
def odom_runs(odom_logs, tmp_path_factory) -> dict[str, Path]:
    from planar_vo.pipeline import run
    config = load_config(None, {"output": {"plot": False}})
    outs = {}
    for name in ("ros2_mcap", "foxglove_mcap", "bag", "rosbag2_sqlite3", "rosbag2_mcap", "ros1_mcap", "bag_tf"):
        outs[name] = tmp_path_factory.mktemp(f"odom_run_{name}")
        run(odom_logs[name], outs[name], config, progress=False)
    return outs


def test_run_gives_identical_wheel_odom_tum_in_every_container(odom_runs):
    ref = odom_runs["ros2_mcap"]
    assert len(read_tum_trajectory(ref / "wheel_odom.tum")) == 10
    for name, out in odom_runs.items():
        for tum in ("wheel_odom.tum", "smoothed.tum"):
            assert (out / tum).read_bytes() == (ref / tum).read_bytes(), (name, tum)


def test_poses_mcap_carries_the_wheel_odometry(odom_runs):
    """Its own topics in both formats, read back equal to wheel_odom.tum."""
    from mcap.reader import make_reader
    for name in ("ros2_mcap", "foxglove_mcap", "bag"):
        out = odom_runs[name]
        with open(out / "poses.mcap", "rb") as f:
            topics = {ch.topic for ch in make_reader(f).get_summary().channels.values()}
        kind = "pose" if name == "foxglove_mcap" else "odom"
        assert {f"/planar_vo/wheel_odom/{kind}", "/planar_vo/wheel_odom/path"} <= topics, name
        wheel = read_tum_trajectory(out / "wheel_odom.tum")
        back = read_poses_mcap(out / "poses.mcap")
        assert set(back) == {"raw", "smoothed", "wheel_odom"}, name
        np.testing.assert_allclose(back["wheel_odom"].stamps, wheel.stamps, rtol=0, atol=1e-6)
        np.testing.assert_allclose(back["wheel_odom"].poses, wheel.poses, rtol=0, atol=1e-6)
        # not the smoothed path: the odometry's +2 % scale shows over the ~1 m
        assert np.abs(back["wheel_odom"].poses[-1, :3, 3] - back["smoothed"].poses[-1, :3, 3]).max() > 5e-3
    # and evo reads it as it reads the smoothed path (`evo_traj bag2 poses.mcap /planar_vo/wheel_odom/odom`)
    from evo.tools import file_interface
    from rosbags.rosbag2 import Reader
    reader = Reader(odom_runs["bag"] / "poses.mcap")
    reader.open()
    try:
        traj = file_interface.read_bag_trajectory(reader, "/planar_vo/wheel_odom/odom")
    finally:
        reader.close()
    wheel = read_tum_trajectory(odom_runs["bag"] / "wheel_odom.tum")
    np.testing.assert_allclose(traj.timestamps, wheel.stamps, rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.poses_se3, wheel.poses, rtol=0, atol=1e-6)


def test_trajectory_png_draws_the_wheel_odometry(odom_logs, tmp_path, monkeypatch):
    """The plot's legend: ground truth, raw, smoothed, wheel odometry (captured at savefig)."""
    import matplotlib.figure

    from planar_vo import pipeline
    from planar_vo.pipeline import run
    labels = []
    real_savefig = matplotlib.figure.Figure.savefig

    def savefig(fig, *args, **kwargs):
        labels.extend(fig.axes[0].get_legend_handles_labels()[1])
        return real_savefig(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    # drawn in this process (not a forked PlotProcess), so the patched savefig sees it
    monkeypatch.setattr(pipeline, "process_prefetch_available", lambda: False)
    run(odom_logs["ros2_mcap"], tmp_path, load_config(None, {}), progress=False)
    assert (tmp_path / "trajectory.png").stat().st_size > 0
    assert labels == ["ground truth", "raw", "smoothed", "wheel odometry", "start"]
