"""`planar-vo run` / `evaluate` end to end on small synthetic logs, including bad input mid-run."""
import json

import numpy as np
import pytest

from planar_vo.cli import main
from planar_vo.evaluation import evaluate_run
from planar_vo.io.trajectory import read_poses_mcap, read_tum_trajectory


@pytest.fixture(scope="module")
def batch_run(lturn_log, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "batch"
    code = main(["run", str(lturn_log), "--out", str(out), "--quiet"])
    return code, out


def test_run_writes_every_output(batch_run, lturn_log):
    code, out = batch_run
    assert code == 0
    for name in ("raw.tum", "smoothed.tum", "poses.mcap", "report.json", "config.yaml", "trajectory.png"):
        assert (out / name).stat().st_size > 0, name
    raw, smooth = read_tum_trajectory(out / "raw.tum"), read_tum_trajectory(out / "smoothed.tum")
    gt = read_tum_trajectory(lturn_log.with_suffix(".gt.tum"))
    assert len(raw) == len(smooth) == 100
    np.testing.assert_allclose(raw.stamps, gt.stamps, atol=1e-6)  # colour stamps
    back = read_poses_mcap(out / "poses.mcap")
    assert set(back) >= {"raw", "smoothed"}
    np.testing.assert_allclose(back["smoothed"].poses, smooth.poses, atol=1e-6)
    r = json.loads((out / "report.json").read_text())
    f = r["frames"]
    assert f["with_pose"] == 100 and f["failed"] == 0
    assert f["estimated_dpp"] + f["estimated_2pt"] + f["bridged"] == 99
    assert f["estimated_dpp"] > 50  # corridor walls are in view most of the time
    assert r["planarity"]["verdict"] == "planar"
    assert r["fps"] > 0 and r["timings_ms_per_frame"]["frontend"] > 0
    # the mount comes from /tf_static
    assert r["mount"]["pitch_deg"] == pytest.approx(10.0, abs=1e-6)


def test_run_is_accurate_on_lturn(batch_run):
    _, out = batch_run
    ev = evaluate_run(out)
    assert ev["raw"]["matched"] == 100
    assert ev["raw"]["endpoint_drift_pct"] < 2.0
    assert ev["smoothed"]["endpoint_drift_pct"] < 1.0
    assert abs(ev["smoothed"]["final_yaw_error_deg"]) < 1.0
    assert ev["smoothed"]["ate_rmse_m"] < 0.05


def test_the_odometry_sees_the_run_s_first_ten_frames_ahead(lturn_log, tmp_path, monkeypatch):
    """The plane detector learns the sensor's range before frame 0's walls
    (PlanarOdometry.look_ahead): it is shown the run's own first ten frames, with the
    run's start and stride, before the first is processed."""
    from planar_vo.frontend.odometry import PlanarOdometry

    seen, processed = [], []
    look_ahead, process = PlanarOdometry.look_ahead, PlanarOdometry.process
    monkeypatch.setattr(PlanarOdometry, "look_ahead",
                        lambda self, frames: look_ahead(self, [seen.append((f.index, len(processed))) or f
                                                               for f in frames]))
    monkeypatch.setattr(PlanarOdometry, "process",
                        lambda self, frame: processed.append(frame.index) or process(self, frame))
    code = main(["run", str(lturn_log), "--out", str(tmp_path / "run"), "--quiet", "--no-plot",
                 "--start", "5", "--stride", "2", "--stop", "60"])
    assert code == 0
    assert [i for i, _ in seen] == list(range(5, 25, 2)) and all(n == 0 for _, n in seen)
    assert processed[:10] == list(range(5, 25, 2))


def test_evaluate_command(batch_run, lturn_log, capsys):
    _, out = batch_run
    assert main(["evaluate", str(out), "--gt", str(lturn_log.with_suffix(".gt.tum"))]) == 0
    text = capsys.readouterr().out
    assert "end-point drift [% of path]" in text and "smoothed" in text
    data = json.loads((out / "evaluation.json").read_text())
    assert data["smoothed"]["matched"] == 100


def test_online_agrees_with_batch(batch_run, lturn_log, tmp_path):
    _, out = batch_run
    assert main(["run", str(lturn_log), "--out", str(tmp_path), "--quiet", "--online", "--no-plot"]) == 0
    a = read_tum_trajectory(out / "smoothed.tum").positions
    b = read_tum_trajectory(tmp_path / "smoothed.tum").positions
    assert np.abs(a - b).max() < 0.01
    assert not (tmp_path / "trajectory.png").exists()


def test_interrupt_keeps_results(lturn_log, tmp_path, monkeypatch, capsys):
    from planar_vo.frontend import odometry

    real = odometry.PlanarOdometry.process
    calls = {"n": 0}

    def process(self, frame):
        calls["n"] += 1
        if calls["n"] == 21:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(odometry.PlanarOdometry, "process", process)
    code = main(["run", str(lturn_log), "--out", str(tmp_path), "--quiet", "--no-plot"])
    assert code == 3
    assert len(read_tum_trajectory(tmp_path / "smoothed.tum")) == 20
    r = json.loads((tmp_path / "report.json").read_text())
    assert r["partial"] and "interrupted" in r["stop_reason"]
    assert "partial run" in capsys.readouterr().out


@pytest.mark.parametrize("fraction,frames", [(0.6, (30, 100)), (0.1, (2, 10))])
def test_truncated_log_keeps_results(lturn_log, tmp_path, capsys, fraction, frames):
    """Cut anywhere, the frames before the cut are kept: also within the first ten, which
    the odometry is shown ahead (``_shown_ahead``)."""
    data = lturn_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    code = main(["run", str(cut), "--out", str(tmp_path / "run"), "--quiet", "--no-plot"])
    assert code == 3
    n = len(read_tum_trajectory(tmp_path / "run" / "smoothed.tum"))
    assert frames[0] <= n < frames[1]
    r = json.loads((tmp_path / "run" / "report.json").read_text())
    assert r["partial"] and "byte" in r["stop_reason"]


def test_corrupt_frame_is_skipped_counted_and_named(lturn_log, tmp_path, mcap_rewriter):
    bad = tmp_path / "bad.mcap"
    # colour message 30 cut in half: its CDR no longer decodes
    mcap_rewriter(lturn_log, bad, lambda topic, k, data: data[: len(data) // 2]
                  if "image_color" in topic and k == 30 else data)
    code = main(["run", str(bad), "--out", str(tmp_path / "run"), "--quiet", "--no-plot", "--stop", "60"])
    assert code == 0
    r = json.loads((tmp_path / "run" / "report.json").read_text())
    assert r["frames"]["failed"] == 1 and len(r["frames"]["failed_frames"]) == 1
    assert r["frames"]["with_pose"] == 59
    assert len(read_tum_trajectory(tmp_path / "run" / "smoothed.tum")) == 59


@pytest.mark.parametrize("reader", ["process", "thread"])
def test_a_run_stopped_early_still_counts_the_frames_it_skipped(lturn_log, tmp_path, mcap_rewriter,
                                                                monkeypatch, reader):
    """Interrupted after a corrupt frame: the report still names it and counts the pairs
    read, whichever reader read them (the process hands its counts over with each frame)."""
    from planar_vo.frontend import odometry

    bad = tmp_path / "bad.mcap"
    mcap_rewriter(lturn_log, bad, lambda topic, k, data: data[: len(data) // 2]
                  if "image_color" in topic and k == 30 else data)
    real = odometry.PlanarOdometry.process

    def process(self, frame):
        if frame.index == 45:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(odometry.PlanarOdometry, "process", process)
    cfg = tmp_path / "reader.yaml"
    cfg.write_text(f"input:\n  reader: {reader}\n")
    code = main(["run", str(bad), "--out", str(tmp_path / "run"), "--quiet", "--no-plot", "--config", str(cfg)])
    assert code == 3
    r = json.loads((tmp_path / "run" / "report.json").read_text())
    assert r["partial"] and r["frames"]["with_pose"] == 44
    assert r["frames"]["failed"] == 1 and r["frames"]["paired"] >= 45


@pytest.mark.parametrize("argv, needle", [
    (["run", "/nonexistent/x.mcap", "--out", "OUT"], "x.mcap"),
    (["run", "LOG", "--out", "OUT", "--fx", "500"], "fx, fy, cx, cy"),
    (["run", "LOG", "--out", "OUT", "--pitch-deg", "10"], "pitch_deg and roll_deg"),
    (["evaluate", "/nonexistent/dir"], "not a run folder"),
])
def test_bad_arguments_are_one_line(argv, needle, lturn_log, tmp_path, capsys):
    argv = [str(lturn_log) if a == "LOG" else str(tmp_path / "o") if a == "OUT" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and "Traceback" not in err[0]


def test_real_tum_sample_runs_and_is_reported_not_planar(tmp_path, capsys):
    """The handheld TUM sample: converted to MCAP, run without a crash, motion flagged as not planar.

    Its measured tilt change is checked against the ground truth (expressed in the first camera frame).
    """
    from pathlib import Path

    from planar_vo.io.trajectory import associate_stamps

    sample = Path(__file__).resolve().parents[1] / "data" / "tum_fr1_xyz_head10"
    log = tmp_path / "tum.mcap"
    assert main(["convert", str(sample), str(log)]) == 0
    assert main(["run", str(log), "--out", str(tmp_path / "run"), "--quiet", "--no-plot"]) == 0
    assert "NOT planar" in capsys.readouterr().out
    r = json.loads((tmp_path / "run" / "report.json").read_text())
    pl = r["planarity"]
    assert pl["verdict"] == "not_planar" and pl["motion"]["gravity"] == "assumed"
    gt = read_tum_trajectory(sample / "groundtruth.txt")
    est = read_tum_trajectory(tmp_path / "run" / "raw.tum")
    _, ib = associate_stamps(est.stamps, gt.stamps, 0.02)
    R0 = gt.poses[ib[0]][:3, :3]
    tilt = np.degrees(np.arccos(np.clip([(R0.T @ T[:3, 1])[1] for T in gt.poses[ib]], -1, 1)))
    true_range = np.percentile(tilt, 95) - np.percentile(tilt, 5)
    assert true_range > 3.0  # the sample really tilts by more than the planar tolerance
    assert pl["motion"]["tilt_range_deg"] == pytest.approx(true_range, abs=1.0)


def test_demo_runs_the_whole_job(lturn_log, tmp_path, capsys):
    """`planar-vo demo` on a given log (the shipped recipe is rendered in CI's demo run)."""
    out = tmp_path / "demo"
    assert main(["demo", "--log", str(lturn_log), "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "end-point drift [% of path]" in text and "trajectory.png" in text
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["smoothed"]["endpoint_drift_pct"] < 1.0
    assert (out / "trajectory.png").stat().st_size > 0


def test_demo_recipe_is_a_valid_synth_config():
    import yaml

    from importlib import resources

    from planar_vo.commands.demo import RECIPE_NAME
    from planar_vo.configtools import from_dict
    from planar_vo.sim.synth import SynthConfig

    text = resources.files("planar_vo.data").joinpath(RECIPE_NAME).read_text()  # as installed
    cfg = from_dict(SynthConfig, yaml.safe_load(text))
    assert cfg.layout == "lturn" and cfg.n_frames == 300 and cfg.seed == 2024


def test_intrinsics_flags_override_the_log(lturn_log, tmp_path):
    """--fx/--fy/--cx/--cy reach the front-end: the true values reproduce the log's own run."""
    from planar_vo.sim.synth import SynthConfig

    c = SynthConfig()
    assert main(["run", str(lturn_log), "--out", str(tmp_path / "a"), "--quiet", "--no-plot", "--stop", "20",
                 "--fx", str(c.fx), "--fy", str(c.fy), "--cx", str(c.cx), "--cy", str(c.cy)]) == 0
    assert main(["run", str(lturn_log), "--out", str(tmp_path / "b"), "--quiet", "--no-plot", "--stop", "20"]) == 0
    a = read_tum_trajectory(tmp_path / "a" / "smoothed.tum").poses
    b = read_tum_trajectory(tmp_path / "b" / "smoothed.tum").poses
    np.testing.assert_allclose(a, b, atol=1e-12)
    assert main(["run", str(lturn_log), "--out", str(tmp_path / "c"), "--quiet", "--no-plot", "--stop", "20",
                 "--fx", "400", "--fy", "400", "--cx", str(c.cx), "--cy", str(c.cy)]) == 0
    wrong = read_tum_trajectory(tmp_path / "c" / "smoothed.tum").poses
    assert np.abs(wrong[:, :3, 3] - b[:, :3, 3]).max() > 1e-3  # a wrong focal length changes the result


def test_the_plot_process_draws_what_the_run_would_draw(batch_run, lturn_log, tmp_path, monkeypatch):
    """trajectory.png comes from a forked process that imported matplotlib during the run
    (planar_vo.plotting.PlotProcess, its CPU in report.json); drawn in the run's own process
    instead (no fork), the file is the same, byte for byte."""
    from planar_vo import pipeline

    _, out = batch_run
    r = json.loads((out / "report.json").read_text())
    assert r["cpu_ms_per_frame"]["plot_process"] > 0
    monkeypatch.setattr(pipeline, "process_prefetch_available", lambda: False)
    assert main(["run", str(lturn_log), "--out", str(tmp_path), "--quiet"]) == 0
    assert "plot_process" not in json.loads((tmp_path / "report.json").read_text())["cpu_ms_per_frame"]
    assert (tmp_path / "trajectory.png").read_bytes() == (out / "trajectory.png").read_bytes()


def test_a_plot_the_process_cannot_draw_is_said_so(tmp_path):
    """PlotProcess.wait is False when the child could not write the file (the run then
    draws it itself and sees the error); a process given nothing to draw just ends."""
    from planar_vo.core.types import Trajectory
    from planar_vo.plotting import PlotProcess

    traj = Trajectory(np.arange(3.0), np.tile(np.eye(4), (3, 1, 1)))
    bad = PlotProcess()
    bad.submit(tmp_path / "no such folder" / "trajectory.png", {"raw": traj})
    assert bad.wait() is False
    good = PlotProcess()
    good.submit(tmp_path / "trajectory.png", {"raw": traj})
    assert good.wait() is True and good.cpu_s > 0
    assert (tmp_path / "trajectory.png").stat().st_size > 0
    idle = PlotProcess()
    idle.close()
    assert not idle._proc.is_alive()
