"""Loop closure end to end (`planar-vo run`): a corridor ring driven past its start closes
the loop with closures that match the ground truth, and two corridors that look the same
produce no accepted closure. Small renders (480x270, 5 Hz) keep this fast; the full-size
figures are ``planar-vo bench loops``."""
import json

import numpy as np
import pytest

from planar_vo.bench.loops import _base_poses, closure_errors
from planar_vo.cli import main
from planar_vo.evaluation import evaluate_run
from planar_vo.io.trajectory import read_lines_mcap, read_tum_trajectory
from planar_vo.sim.revisits import revisit_pairs
from planar_vo.sim.synth import SynthConfig, frames_for_laps, synth_mount, write_synth_log


def _log(tmp_path_factory, name: str, **kw):
    cfg = SynthConfig(speed=0.8, rate_hz=5.0, seed=11, texture="rich", **kw).at_resolution(480, 270)
    out = tmp_path_factory.mktemp("logs") / f"{name}.mcap"
    write_synth_log(cfg, out, progress=False)
    return out, cfg


def _run(log, out, *extra):
    assert main(["run", str(log), "--out", str(out), "--quiet", *extra]) == 0
    return json.loads((out / "report.json").read_text())


def _gt_base(log, out, cfg):
    gt = read_tum_trajectory(str(log)[:-5] + ".gt.tum")
    stamps = read_tum_trajectory(out / "smoothed.tum").stamps
    return _base_poses(gt, stamps, np.asarray(synth_mount(cfg).T_base_cam))


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    """A 12 m corridor ring driven 1.25 laps: the first 3 m are seen again."""
    log, cfg = _log(tmp_path_factory, "ring", layout="loop", laps=1.25,
                    n_frames=frames_for_laps(1.25, 12.0, 0.8, 5.0))
    out = tmp_path_factory.mktemp("run")
    return log, cfg, out, _run(log, out / "batch"), _run(log, out / "online", "--online")


def test_closures_match_the_ground_truth(ring):
    log, cfg, out, rep, _ = ring
    lc = rep["loop_closure"]
    kept = [c for c in lc["list"] if c["verdict"] == "accepted"]
    assert len(kept) >= 3
    errors = closure_errors(kept, _gt_base(log, out / "batch", cfg))
    assert max(e["error_m"] for e in errors) <= 0.05
    assert max(e["error_deg"] for e in errors) <= 0.5


def test_revisited_keyframes_are_closed(ring):
    log, cfg, out, rep, _ = ring
    lc = rep["loop_closure"]
    pairs = revisit_pairs(_gt_base(log, out / "batch", cfg), np.asarray(lc["keyframe_frames"]))
    revisiting = {b for _, b in pairs}
    closed = {c["b"] for c in lc["list"] if c["verdict"] == "accepted"}
    assert len(revisiting) >= 3
    assert len(revisiting & closed) >= 0.8 * len(revisiting)


def test_outputs_show_the_closures(ring):
    log, cfg, out, rep, _ = ring
    ev = evaluate_run(out / "batch")
    assert {"raw", "smoothed_no_loops", "smoothed"} <= set(ev)
    kept = [c for c in rep["loop_closure"]["list"] if c["verdict"] == "accepted"]
    segments = read_lines_mcap(out / "batch" / "poses.mcap", "loop_closures")
    smoothed = read_tum_trajectory(out / "batch" / "smoothed.tum").positions
    expect = np.array([[smoothed[c["a"]], smoothed[c["b"]]] for c in kept])
    np.testing.assert_allclose(segments, expect, atol=1e-9)
    assert rep["cpu_ms_per_frame"]["loops"] > 0
    # a keyframe that closed a loop is not kept (memory grows with the area, not the laps)
    lc = rep["loop_closure"]
    assert lc["keyframes_kept"] == lc["keyframes"] - len({c["b"] for c in kept})
    # candidates the prior put out of view are counted as such, not as verified
    unseen = lc["not_accepted_by_reason"].get("out_of_view", 0)
    assert lc["verified"] == lc["candidates"] - unseen
    assert all(c["matches"] == 0 for c in lc["list"] if c["reason"] == "out_of_view")


def test_batch_and_online_agree(ring):
    log, cfg, out, rep, rep_online = ring
    a = read_tum_trajectory(out / "batch" / "smoothed.tum").positions
    b = read_tum_trajectory(out / "online" / "smoothed.tum").positions
    assert rep_online["loop_closure"]["accepted"] >= 3
    assert np.linalg.norm(a - b, axis=1).max() <= 0.01


def test_no_loops_flag(ring, tmp_path):
    log, *_ = ring
    rep = _run(log, tmp_path / "r", "--no-loops")
    assert rep["loop_closure"] == {"enabled": False}
    assert not (tmp_path / "r" / "smoothed_no_loops.tum").exists()


def test_look_alike_corridors_close_nothing(tmp_path_factory):
    """Two corridors with the same doors, posters and spacing at different places: candidates
    are proposed between them (they look alike) but none is accepted."""
    log, cfg = _log(tmp_path_factory, "aliased", layout="aliased", n_frames=frames_for_laps(1.0, 12.5, 0.8, 5.0))
    out = tmp_path_factory.mktemp("run") / "aliased"
    rep = _run(log, out)
    lc = rep["loop_closure"]
    assert lc["candidates"] >= 5
    kept = [c for c in lc["list"] if c["verdict"] == "accepted"]
    errors = closure_errors(kept, _gt_base(log, out, cfg))
    assert all(e["error_m"] <= 0.05 and e["error_deg"] <= 0.5 for e in errors)  # no wrong closure


def test_summary_line_counts_the_pairs_out_of_view_apart(ring, capsys):
    """The run's summary line splits the rejected candidates into those the prior put out
    of view (never matched) and those verification rejected."""
    from types import SimpleNamespace

    from planar_vo.commands.run import print_summary

    log, cfg, out, rep, _ = ring
    print_summary(SimpleNamespace(report=rep, out_dir=out / "batch", files={}, partial=False, stop_reason=None))
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("loop closure:"))
    lc = rep["loop_closure"]
    unseen = lc["not_accepted_by_reason"].get("out_of_view", 0)
    assert f"({unseen} out of view, {lc['rejected'] - unseen} rejected by verification," in line


def test_keyframes_in_the_background_change_nothing(ring, tmp_path, monkeypatch):
    """The run makes and verifies keyframes on a worker thread (LoopCloser(background=True));
    the closures reach the graph a frame later, in the same order: the same closures and
    the same solution as the closer run in line."""
    from planar_vo import loops, pipeline
    log, cfg, out, rep, _ = ring
    made = []

    def in_line(*args, **kwargs):
        closer = loops.LoopCloser(*args, **{**kwargs, "background": False})
        made.append(closer)
        return closer

    def closer(log_, odometry, graph, config):
        return in_line(log_.intrinsics, odometry.mount.T_base_cam, config.loops, config.places, graph,
                       frontend=config.frontend)

    monkeypatch.setattr(pipeline, "_loop_closer", closer)
    rep_in_line = _run(log, tmp_path / "in_line")
    assert made and not made[0]._background

    def verdicts(r):
        return [(c["a"], c["b"], c["verdict"], c["reason"], c["inliers"], c["pose"], c["closure_id"])
                for c in r["loop_closure"]["list"]]

    assert verdicts(rep_in_line) == verdicts(rep)
    assert rep["loop_closure"]["accepted"] >= 3
    a = read_tum_trajectory(out / "batch" / "smoothed.tum").positions
    b = read_tum_trajectory(tmp_path / "in_line" / "smoothed.tum").positions
    np.testing.assert_array_equal(a, b)
