"""Speed plumbing: BLAS thread limit, prefetch CPU accounting, CPU figures in the report,
and ``planar-vo bench run`` on a short log."""
import argparse
import threading
import time

import numpy as np
import pytest

from threadpoolctl import threadpool_info

from planar_vo import pipeline
from planar_vo.core.errors import PartialResult
from planar_vo.prefetch import Prefetcher, ProcessPrefetcher, process_prefetch_available

needs_fork = pytest.mark.skipif(not process_prefetch_available(), reason="the process reader needs fork (Linux)")


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_run_limits_blas_threads_and_restores(monkeypatch):
    """``run`` gives every BLAS one thread while it runs (threadpoolctl) and restores the counts,
    also after an exception."""
    import cv2  # noqa: F401 - its OpenBLAS too

    before = _blas_threads()
    if not before:
        pytest.skip("no BLAS found by threadpoolctl in this process")
    seen = []

    def fake_run(*args, **kwargs):
        seen.append(_blas_threads())
        a = np.arange(12.0).reshape(3, 4)
        np.testing.assert_allclose(a @ a.T, np.einsum("ij,kj->ik", a, a))
        raise KeyError("x")

    monkeypatch.setattr(pipeline, "_run", fake_run)
    with pytest.raises(KeyError):
        pipeline.run("log", "out")
    assert seen == [[1] * len(before)]
    assert _blas_threads() == before


def _burn(seconds):
    t0 = time.thread_time()
    x = 0
    while time.thread_time() - t0 < seconds:
        x += 1
    return x


def test_prefetcher_counts_producer_cpu_not_waiting():
    def source():
        for i in range(3):
            _burn(0.02)       # CPU work, counted
            time.sleep(0.05)  # waiting (I/O), not counted as CPU
            yield i

    with Prefetcher(source(), depth=1) as p:
        assert list(p) == [0, 1, 2]
    assert 0.05 <= p.busy_cpu_s < 0.12
    assert p.busy_s >= p.busy_cpu_s + 0.14


def test_prefetcher_reraises_and_stops_early():
    def source():
        yield 1
        raise ValueError("bad frame")

    with Prefetcher(source()) as p:
        with pytest.raises(ValueError, match="bad frame"):
            list(p)

    stop = threading.Event()

    def endless():
        i = 0
        while not stop.is_set():
            i += 1
            yield i

    with Prefetcher(endless(), depth=2) as p:
        assert next(iter(p)) == 1
    assert not p._thread.is_alive()  # closed by the context manager
    stop.set()


@needs_fork
def test_process_prefetcher_hands_over_items_in_order_with_their_arrays():
    """Image-sized arrays through the shared slots (more items than slots, so each slot is
    reused), small ones and the rest through the pipe; ``pack`` runs in the child,
    ``unpack`` and the result of ``finish`` reach the parent."""
    def source():
        for i in range(9):
            yield i, np.full((540, 960), i, np.float32), np.arange(i)

    with ProcessPrefetcher(source(), depth=2, slot_bytes=4 << 20, pack=lambda x: (x[0] * 10,) + x[1:],
                           unpack=lambda x: (x[0] + 1,) + x[1:], finish=lambda: {"seen": "all"}) as p:
        got = list(p)
    assert [g[0] for g in got] == [10 * i + 1 for i in range(9)]
    for i, (_, img, small) in enumerate(got):
        assert img.shape == (540, 960) and img.dtype == np.float32 and np.all(img == i)
        np.testing.assert_array_equal(small, np.arange(i))
        img[0, 0] = -1.0  # the parent's own copy: writable, and the slot is not
    assert p.finished == {"seen": "all"}
    assert p.cpu_s > 0 and p.busy_cpu_s > 0


@needs_fork
def test_process_prefetcher_sends_an_item_larger_than_a_slot_whole():
    def source():
        yield np.arange(3 << 18, dtype=np.float64)  # 6 MB
        yield np.arange(4.0)

    with ProcessPrefetcher(source(), slot_bytes=1 << 20) as p:
        big, small = list(p)
    np.testing.assert_array_equal(big, np.arange(3 << 18, dtype=np.float64))
    np.testing.assert_array_equal(small, np.arange(4.0))


@needs_fork
def test_process_prefetcher_reraises_where_the_stream_stopped_and_stops_early():
    """The items before the error arrive first, then the error with its own type (the
    pipeline tells a log cut short, PartialResult, from other failures); ``finish`` still
    reports what the source did. An early exit kills the child."""
    def source():
        yield 1
        yield 2
        raise PartialResult("log.mcap: log is cut short")

    got = []
    with ProcessPrefetcher(source(), finish=lambda: "finished") as p:
        with pytest.raises(PartialResult, match="cut short"):
            for x in p:
                got.append(x)
    assert got == [1, 2] and p.finished == "finished"

    def endless():
        i = 0
        while True:
            i += 1
            yield np.zeros(1 << 18)

    with ProcessPrefetcher(endless(), depth=2) as p:
        next(iter(p))
    assert not p._proc.is_alive()


@needs_fork
def test_a_reader_process_that_dies_ends_the_stream_as_a_partial_result():
    """Killed (out of memory, say) after two items: the parent gets those two, then a
    PartialResult that says so (the pipeline writes what it computed), not a hang."""
    import os

    def source():
        yield 1
        yield 2
        os._exit(9)

    got = []
    with ProcessPrefetcher(source()) as p:
        with pytest.raises(PartialResult, match="exit code 9"):
            for x in p:
                got.append(x)
    assert got == [1, 2]


@needs_fork
def test_process_reader_gives_the_thread_readers_results(lturn_log, tmp_path):
    """``input.reader: process`` decodes and tracks in a forked child: the same steps and
    trajectories as the thread, the same log summary in the report (the counts the pass
    recorded come back from the child), and the child's CPU in the run's total."""
    import json

    from planar_vo.config import load_config
    from planar_vo.pipeline import run

    reports = {}
    for reader in ("thread", "process"):
        cfg = load_config(None, {"output": {"plot": False, "poses_mcap": False},
                                 "input": {"stop": 40, "reader": reader}})
        reports[reader] = run(lturn_log, tmp_path / reader, cfg, progress=False).report
    for name in ("raw.tum", "smoothed.tum", "steps.csv"):
        assert (tmp_path / "thread" / name).read_text() == (tmp_path / "process" / name).read_text(), name
    t, p = reports["thread"], reports["process"]
    assert json.dumps(t["input"], sort_keys=True) == json.dumps(p["input"], sort_keys=True)
    assert t["frames"] == p["frames"] and p["frames"]["with_pose"] == 40
    cpu = p["cpu_ms_per_frame"]
    assert cpu["reader_process"] >= 0.9 * (cpu["read_decode_background"] + cpu["track_background"])
    assert cpu["track_background"] > 0.3 and "reader_process" not in t["cpu_ms_per_frame"]
    assert cpu["process"] >= cpu["reader_process"] + cpu["frontend"]


def test_a_pass_state_carries_the_ground_truth_read_in_the_reader(lturn_log):
    """The reader process reads the ground truth when its pass is done; the main process
    takes it over and does not read the log for it again."""
    from planar_vo.io.opener import open_log

    with open_log(lturn_log) as a, open_log(lturn_log) as b:
        for _ in a.frames(stop=3):
            pass
        gt = a.ground_truth
        assert gt is not None and len(gt.stamps) > 10
        b.restore_pass_state(a.pass_state())

        def no_reading():
            raise AssertionError("the ground truth was read again")

        b._read_ground_truth = no_reading
        np.testing.assert_array_equal(b.ground_truth.poses, gt.poses)
        assert b.stats == a.stats


def test_without_shared_memory_the_reader_is_a_thread(lturn_log, tmp_path, monkeypatch):
    """Where the process reader cannot be set up (no /dev/shm for its semaphore, say), the
    run reads in a thread instead, with the same results."""
    from planar_vo.config import load_config
    from planar_vo.pipeline import run

    def no_shm(*args, **kwargs):
        raise OSError(38, "Function not implemented")

    monkeypatch.setattr(ProcessPrefetcher, "__init__", no_shm)
    cfg = load_config(None, {"output": {"plot": False, "poses_mcap": False}, "input": {"stop": 12}})
    rep = run(lturn_log, tmp_path / "run", cfg, progress=False).report
    assert rep["frames"]["with_pose"] == 12 and "reader_process" not in rep["cpu_ms_per_frame"]
    assert rep["cpu_ms_per_frame"]["track_background"] > 0.3


def _available_in_worker(_):
    return process_prefetch_available()


@needs_fork
def test_a_pool_worker_reads_in_a_thread():
    """A daemonic process (a multiprocessing.Pool worker running planar-vo's pipeline) may
    not start children: the process reader is not offered there."""
    import multiprocessing

    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.map(_available_in_worker, [0]) == [False]


def test_report_has_cpu_per_stage(lturn_log, tmp_path):
    from planar_vo.config import load_config
    from planar_vo.pipeline import run

    cfg = load_config(None, {"output": {"plot": False}, "input": {"stop": 12}})
    res = run(lturn_log, tmp_path / "run", cfg, progress=False)
    assert res.report["frames"]["with_pose"] == 12
    cpu = res.report["cpu_ms_per_frame"]
    for k in ("summary", "outputs_import_background", "read_decode_background", "track_background",
              "frontend", "backend", "optimize", "write", "process"):
        assert cpu[k] >= 0.0, k
    assert cpu["frontend"] > 0.5 and cpu["read_decode_background"] > 0.5  # 960x540 frames take ms
    assert cpu["track_background"] > 0.3
    # The process total covers the stages of every thread.
    parts = sum(cpu[k] for k in ("summary", "outputs_import_background", "read_decode_background",
                                 "track_background", "frontend", "backend", "optimize", "write"))
    assert cpu["process"] >= 0.9 * parts


def test_bench_run_prints_figures_and_checks_results(lturn_log, tmp_path, capsys):
    import json

    from planar_vo.bench import run as bench

    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    keep = tmp_path / "keep"
    args = p.parse_args([str(lturn_log), "--frames", "12", "--repeat", "1", "--json", str(tmp_path / "b.json"),
                         "--keep", str(keep)])
    assert bench.main(args) == 0
    out = capsys.readouterr().out
    assert "frames/s median" in out and "peak RSS" in out and "front-end (main thread)" in out
    data = json.loads((tmp_path / "b.json").read_text())
    (log,) = data["logs"]
    assert log["frames"] == 12 and len(log["runs"]) == 1
    run0 = log["runs"][0]
    assert run0["fps"] > 0 and 50 < run0["peak_rss_mb"] < 4000
    if process_prefetch_available():  # the reader process's own peak, printed beside the main one
        assert 20 < run0["reader_peak_rss_mb"] < 4000 and "(reader process" in out
    assert run0["cpu_ms_per_frame"]["frontend.planes"] > 0
    kept = keep / lturn_log.stem / "run0"
    assert (kept / "raw.tum").is_file() and (kept / "smoothed.tum").is_file()

    # Against itself: the same; against a doctored copy: reported, exit code 1.
    assert bench.trajectory_difference(kept, kept) == 0.0
    doctored = tmp_path / "doctored" / lturn_log.stem / "run0"
    doctored.mkdir(parents=True)
    for name in ("raw.tum", "smoothed.tum"):
        lines = (kept / name).read_text().splitlines()
        if name == "smoothed.tum":
            v = lines[-1].split()
            v[1] = repr(float(v[1]) + 1e-6)
            lines[-1] = " ".join(v)
        (doctored / name).write_text("\n".join(lines) + "\n")
    assert bench.trajectory_difference(kept, doctored) == pytest.approx(1e-6, rel=1e-3)
    args = p.parse_args([str(lturn_log), "--frames", "12", "--repeat", "1", "--reference", str(tmp_path / "doctored")])
    assert bench.main(args) == 1
    assert "DIFFERENT" in capsys.readouterr().out


def test_bench_run_rejects_a_missing_log(tmp_path):
    from planar_vo.bench import run as bench
    from planar_vo.core.errors import InputError

    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    with pytest.raises(InputError, match="no such log"):
        bench.main(p.parse_args([str(tmp_path / "nope.mcap")]))
    # a log the run itself refuses (a folder without rgb.txt): the child's one-line reason,
    # as bad input, not an internal error
    with pytest.raises(InputError, match="rgb.txt is missing"):
        bench.main(p.parse_args([str(tmp_path), "--repeat", "1"]))


@pytest.fixture(scope="module")
def first_frames(lturn_log):
    from planar_vo.io import open_log

    with open_log(lturn_log) as log:
        return log.intrinsics, log.mount, list(log.frames(stop=8))


def _results(odo, frames, ahead: bool):
    out = []
    for f in frames:
        if ahead:
            odo.track(f)
        r = odo.process(f)
        out.append((None if r.step is None else (r.step.pose.tolist(), r.step.information.tolist(), r.step.status),
                    [(m.yaw, m.sigma, m.track_id) for m in r.manhattan], r.diagnostics.matches))
    return out


def test_tracking_ahead_gives_the_same_steps(first_frames):
    from planar_vo.frontend.odometry import PlanarOdometry

    intr, mount, frames = first_frames
    inline = _results(PlanarOdometry(intr, mount), frames, ahead=False)
    # All frames tracked first (as far ahead as a pipeline could be), then processed.
    odo = PlanarOdometry(intr, mount)
    for f in frames:
        odo.track(f)
    ahead = [_results(odo, [f], ahead=False)[0] for f in frames]
    assert ahead == inline
    assert _results(PlanarOdometry(intr, mount), frames, ahead=True) == inline
    assert inline[-1][2] > 50  # the frames were really tracked


def test_tracking_ahead_out_of_order_is_refused(first_frames):
    from planar_vo.frontend.odometry import PlanarOdometry

    intr, mount, frames = first_frames
    odo = PlanarOdometry(intr, mount)
    odo.track(frames[1])
    with pytest.raises(RuntimeError, match="track"):
        odo.process(frames[0])


def _out_of_plane_reference(P1, P2, seed=0, iterations=64, rel_threshold=0.02, min_inliers=8):
    """The first, einsum-based formulation of planarity.out_of_plane_motion (R, t, inliers)."""
    from planar_vo.frontend.planarity import _kabsch

    rng = np.random.default_rng(seed)
    idx = np.array([rng.choice(len(P1), 3, replace=False) for _ in range(iterations)])
    R, t = _kabsch(P1[idx], P2[idx])
    res = np.linalg.norm(np.einsum("kij,nj->kni", R, P1) + t[:, None, :] - P2[None], axis=2)
    thr = rel_threshold * np.maximum(P2[:, 2], 0.5)
    mask = (res < thr[None])[(res < thr[None]).sum(1).argmax()]
    for _ in range(2):
        Rb, tb = _kabsch(P1[mask], P2[mask])
        mask = np.linalg.norm(P1 @ Rb.T + tb - P2, axis=1) < thr
    return Rb, tb, int(mask.sum())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_planarity_fit_is_bit_identical_to_its_first_formulation(seed):
    from planar_vo.frontend.planarity import out_of_plane_motion

    rng = np.random.default_rng(seed)
    n = 150 + 50 * seed
    P1 = rng.normal(size=(n, 3)) + [0.0, 0.0, 3.0]
    a = 0.05 * (seed + 1)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    P2 = P1 @ R.T + [0.02, 0.0, 0.1] + rng.normal(size=(n, 3)) * 0.005
    P2[:20] += rng.normal(size=(20, 3))  # outliers
    got = out_of_plane_motion(P1, P2, seed=seed)
    Rb, tb, n_in = _out_of_plane_reference(P1, P2, seed=seed)
    assert got.inliers == n_in and n_in >= n - 25
    assert np.array_equal(got.R, Rb) and np.array_equal(got.t, tb)


def test_plane_helpers_match_numpy_bit_for_bit():
    from planar_vo.frontend.planes import _band_medians, _median, _pairs, _percentiles

    rng = np.random.default_rng(7)
    for n in list(range(1, 12)) + [100, 101, 4000, 4001]:
        a = rng.normal(size=n) * 1e-3
        a[::3] = np.round(a[::3], 4)  # ties
        assert _median(a) == np.median(a), n
        assert np.array_equal(_percentiles(a, np.array([0.02, 0.98])), np.percentile(a, [2.0, 98.0])), n
        nb = max(1, n // 60)
        band = rng.integers(0, nb, n)
        count = np.bincount(band, minlength=nb)
        which = count >= 5
        order = np.lexsort((a, band))
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        assert np.array_equal(_band_medians(a, band, count, which), a[order[start[which] + count[which] // 2]])
    for m in (3, 4, 48):
        ia, ib = _pairs(m)
        ra, rb = np.triu_indices(m, 1)
        assert np.array_equal(ia, ra) and np.array_equal(ib, rb) and not ia.flags.writeable
    assert np.isnan(_median(np.array([1.0, np.nan, 2.0])))
