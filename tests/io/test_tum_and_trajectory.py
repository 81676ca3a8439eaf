"""TUM folders (the real sample), conversion to MCAP, and trajectory files."""
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from planar_vo.core.errors import InputError
from planar_vo.core.geometry import matrix_from_pose7
from planar_vo.io import Trajectory, open_log
from planar_vo.io.trajectory import read_poses_mcap, read_tum_trajectory, write_poses_mcap, write_tum_trajectory
from planar_vo.io.tum import TUM_INTRINSICS

SAMPLE = Path(__file__).resolve().parents[2] / "data" / "tum_fr1_xyz_head10"


@pytest.fixture(scope="module")
def sample_frames():
    with open_log(SAMPLE) as log:
        return list(log.frames()), log.intrinsics, log.ground_truth, dict(log.stats)


def test_tum_sample_reads_like_the_benchmark(sample_frames):
    frames, k, gt, stats = sample_frames
    assert k == TUM_INTRINSICS["freiburg1"]
    # associate.py's rule at 20 ms: colour .243211 loses both neighbours to closer pairs.
    assert len(frames) == 9 and (stats["unpaired_color"], stats["unpaired_depth"]) == (1, 2)
    assert not stats["corrupt"]
    assert [f.meta["color_file"] for f in frames[1:3]] == ["rgb/1305031102.211214.png", "rgb/1305031102.275326.png"]
    assert frames[1].depth_stamp == 1305031102.226738
    f0 = frames[0]
    assert f0.stamp == 1305031102.175304 and f0.depth_stamp == 1305031102.160407
    raw = cv2.imread(str(SAMPLE / "depth/1305031102.160407.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(f0.depth, raw.astype(np.float32) / np.float32(5000))
    assert 0.5 < np.median(f0.depth[f0.depth > 0]) < 2.0  # a desk scene about a metre away
    assert len(gt) == 70 and gt.stamps[0] == 1305031101.9758  # first line of groundtruth.txt
    np.testing.assert_allclose(gt.poses[0], matrix_from_pose7([1.3877, 0.6338, 1.7091, 0.6648, 0.5995, -0.2818, -0.3454]),
                               atol=1e-12)


def test_tum_gray_color_mode(sample_frames):
    """The pipeline reads TUM colour PNGs as intensity: libpng's conversion, within 1 level."""
    with open_log(SAMPLE) as log:
        log.set_color_mode("gray")
        grey = list(log.frames())
    frames = sample_frames[0]
    assert len(grey) == len(frames)
    for g, f in zip(grey, frames):
        assert g.color.shape == f.color.shape[:2]
        assert np.abs(g.color.astype(int) - cv2.cvtColor(f.color, cv2.COLOR_BGR2GRAY)).max() <= 1


@pytest.mark.parametrize("profile", ["ros2", "foxglove"])
def test_convert_roundtrip_is_bit_exact(sample_frames, tmp_path, run_cli, profile):
    frames, k, gt, _ = sample_frames
    out = tmp_path / "tum.mcap"
    code, stdout, err = run_cli("convert", SAMPLE, out, "--profile", profile)
    assert code == 0, err
    assert "9 frames, 70 ground-truth poses" in stdout
    with open_log(out) as log:
        back = list(log.frames())
        assert log.intrinsics == k
        np.testing.assert_array_equal(log.ground_truth.stamps, gt.stamps)
        np.testing.assert_allclose(log.ground_truth.poses, gt.poses, atol=1e-12)
    assert len(back) == len(frames)
    for a, b in zip(back, frames):
        assert a.stamp == b.stamp
        np.testing.assert_array_equal(a.color, b.color)
        np.testing.assert_array_equal(a.depth, b.depth)


def test_tum_missing_files(tmp_path):
    folder = tmp_path / "rgbd_dataset_freiburg1_cut"
    shutil.copytree(SAMPLE, folder)
    (folder / "rgb" / "1305031102.311267.png").unlink()  # colour of frame 3 lost
    with open_log(folder) as log:
        got = [f.index for f in log.frames()]
        assert got == [0, 1, 2, 4, 5, 6, 7, 8] and "1305031102.311267" in log.stats["corrupt"][0][1]
    (folder / "depth.txt").unlink()
    with pytest.raises(InputError, match="depth.txt is missing"):
        open_log(folder)


def test_tum_unknown_sensor_needs_intrinsics(tmp_path):
    folder = tmp_path / "my_recording"
    shutil.copytree(SAMPLE, folder)
    with open_log(folder) as log, pytest.raises(InputError, match="--fx/--fy/--cx/--cy"):
        log.intrinsics


def test_tum_trajectory_roundtrip_and_errors(tmp_path):
    rng = np.random.default_rng(21)
    q = rng.normal(size=(5, 4))
    poses = np.array([matrix_from_pose7(np.r_[rng.normal(size=3), qi]) for qi in q])
    traj = Trajectory(1305031102.175304 + np.arange(5) * 0.033, poses)
    path = tmp_path / "t.txt"
    write_tum_trajectory(path, traj, header="estimated by a test")
    back = read_tum_trajectory(path)
    np.testing.assert_array_equal(back.stamps, traj.stamps)
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-14)
    assert path.read_text().startswith("# estimated by a test\n# timestamp tx ty tz qx qy qz qw\n")
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"bad.txt:3: expected 8 finite numbers"):
        read_tum_trajectory(bad)
    bad.write_text("1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"bad.txt:1: zero quaternion"):
        read_tum_trajectory(bad)
    bad.write_text("1.0 0 0 nan 0 0 0 1\n")
    with pytest.raises(InputError, match=r"bad.txt:1"):
        read_tum_trajectory(bad)
    with pytest.raises(InputError, match="not found"):
        read_tum_trajectory(tmp_path / "none.txt")


def test_poses_mcap_roundtrip(tmp_path):
    n = 200
    t = 1.7e9 + np.arange(n) / 30
    yaw = np.linspace(0, 1, n)
    poses = np.array([matrix_from_pose7([np.cos(a), np.sin(a), 0, 0, 0, np.sin(a / 2), np.cos(a / 2)]) for a in yaw])
    trajs = {"raw": Trajectory(t, poses, frame_id="odom", child_frame_id="base_link"),
             "smoothed": Trajectory(t[::2], poses[::2], frame_id="odom", child_frame_id="base_link")}
    tf = [(t[0], "world", "odom", np.eye(4)), (t[0], "odom", "base_link", poses[0])]
    path = tmp_path / "poses.mcap"
    write_poses_mcap(path, trajs, transforms=tf, path_period=1.0, path_max_poses=50)
    back = read_poses_mcap(path)
    assert set(back) == {"raw", "smoothed"}
    for name, tr in trajs.items():
        np.testing.assert_array_equal(back[name].stamps, tr.stamps)
        np.testing.assert_allclose(back[name].poses, tr.poses, atol=1e-12)
        assert (back[name].frame_id, back[name].child_frame_id) == ("odom", "base_link")
    # Any MCAP reader sees the Foxglove schemas, the growing paths and the transforms.
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        paths = [msg for _, ch, _, msg in reader.iter_decoded_messages(topics=["/planar_vo/raw/path"])]
    assert schemas == {"/planar_vo/raw/pose": "foxglove.PoseInFrame", "/planar_vo/raw/path": "foxglove.PosesInFrame",
                       "/planar_vo/smoothed/pose": "foxglove.PoseInFrame",
                       "/planar_vo/smoothed/path": "foxglove.PosesInFrame", "/tf": "foxglove.FrameTransforms"}
    assert len(paths) == 7 and len(paths[-1].poses) == n  # one per second of 6.6 s, the last complete
    assert all(len(p.poses) <= 50 for p in paths[:-1])


def test_ros2_paths_built_once_per_pose_serialise_as_the_dicts_do():
    """poses.mcap's ROS 2 paths share each pose's message between the path messages that hold
    it (_Ros2Paths): the bytes are those of the dict that messages.ros2_path describes, for
    thinned paths, two frames and the poses a growing path repeats."""
    from planar_vo.io import messages, rosmsg
    from planar_vo.io.trajectory import _Ros2Paths, _thin
    rng = np.random.default_rng(5)
    poses = np.array([matrix_from_pose7(np.r_[rng.normal(size=3), q / np.linalg.norm(q)])
                      for q in rng.normal(size=(40, 4))])
    for frame in ("odom", "map"):
        paths = _Ros2Paths(poses, frame)
        for stamp, idx in ((1.7e9 + 0.25, np.arange(10)), (1.7e9 + 1.5, _thin(np.arange(40), 16)),
                           (1.7e9 + 2.0, np.arange(40))):
            fast = rosmsg.serialize(rosmsg.CDR, "nav_msgs/msg/Path", paths(stamp, idx))
            slow = rosmsg.serialize(rosmsg.CDR, "nav_msgs/msg/Path", messages.ros2_path(stamp, frame, poses[idx]))
            assert fast == slow


@pytest.mark.parametrize("fmt", ["ros2", "foxglove"])
def test_poses_mcap_keeps_each_trajectory_s_frame(tmp_path, fmt):
    """Each trajectory's messages carry its own frame: the builders once looked the frame
    up after the loop over the trajectories, so all took the last one's."""
    t = 1.7e9 + np.arange(40) / 10
    poses = np.array([matrix_from_pose7([0.1 * k, 0, 0, 0, 0, 0, 1]) for k in range(40)])
    trajs = {"raw": Trajectory(t, poses, frame_id="odom", child_frame_id="base_link"),
             "global": Trajectory(t, poses, frame_id="map", child_frame_id="base_link")}
    write_poses_mcap(tmp_path / "p.mcap", trajs, format=fmt)
    back = read_poses_mcap(tmp_path / "p.mcap")
    assert {name: tr.frame_id for name, tr in back.items()} == {"raw": "odom", "global": "map"}


def test_poses_mcap_rejects_bad_names_and_files(tmp_path):
    with pytest.raises(ValueError, match="trajectory name"):
        write_poses_mcap(tmp_path / "p.mcap", {"bad name": Trajectory(np.zeros(1), np.eye(4)[None])})
    assert list(tmp_path.iterdir()) == []
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"junk")
    with pytest.raises(InputError, match="not a readable poses MCAP"):
        read_poses_mcap(junk)
