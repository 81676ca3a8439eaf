"""``planar-vo batch``: one Ray task per log, results identical to ``planar-vo run``, resumable.

Ray starts are the slow part (several seconds each), so one Ray head on the loopback
interface serves the whole module; the first batch starts (and stops) its own local Ray
as a user's would.
"""
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from planar_vo.cli import main as cli
from planar_vo.sim.synth import SynthConfig, write_synth_log
from planar_vo.io.trajectory import read_tum_trajectory

DATA = Path(__file__).resolve().parents[1] / "data"
GOOD = ("a_shift", "b_shift", "corridor", "fr1_xyz")
RAY = Path(sys.executable).with_name("ray")
PLANAR_VO = Path(sys.executable).with_name("planar-vo")


def _synth(path: Path, seed: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cfg = SynthConfig(layout="straight", seed=seed, n_frames=18, speed=1.0, texture="medium").at_resolution(480, 270)
    write_synth_log(cfg, path, progress=False)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """``(root, logs folder, {name: log})``: three small synthetic MCAP logs (two sharing a
    name), a TUM folder, a corrupt MCAP; and ``root/ref/<name>`` run by ``planar-vo run``."""
    root = tmp_path_factory.mktemp("fleet")
    logs = root / "logs"
    paths = {"a_shift": logs / "a" / "shift.mcap", "b_shift": logs / "b" / "shift.mcap",
             "corridor": logs / "corridor.mcap", "fr1_xyz": logs / "tum" / "fr1_xyz"}
    for seed, name in enumerate(GOOD[:3], start=1):
        _synth(paths[name], seed)
    shutil.copytree(DATA / "tum_fr1_xyz_head10", paths["fr1_xyz"])
    (logs / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    for name in GOOD:
        assert cli(["run", str(paths[name]), "--out", str(root / "ref" / name), "--quiet"]) == 0
    return root, logs, paths


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_head():
    """A Ray head on 127.0.0.1 (2 CPUs, no dashboard) for the module; its address. Stopped by
    terminating the ``ray start --block`` process, which stops what it started."""
    port = _free_port()
    # token authentication with a token of this module's own, for the head and every driver
    auth = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(16)}
    saved = {k: os.environ.get(k) for k in auth}
    os.environ.update(auth)
    env = dict(os.environ, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0")
    proc = subprocess.Popen([str(RAY), "start", "--head", "--block", "--node-ip-address=127.0.0.1", f"--port={port}",
                             "--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    ready = threading.Event()
    output: list[str] = []

    def watch():
        for line in proc.stdout:
            output.append(line)
            if "Ray runtime started" in line:
                ready.set()
    threading.Thread(target=watch, daemon=True).start()
    try:
        assert ready.wait(120), "ray start did not come up:\n" + "".join(output[-20:])
        yield f"127.0.0.1:{port}"
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # our own session: only what this fixture started
            proc.wait(10)
        for k, v in saved.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)


def _same_trajectory(a: Path, b: Path) -> None:
    ta, tb = read_tum_trajectory(a), read_tum_trajectory(b)
    assert len(ta) == len(tb) > 0
    assert np.max(np.abs(ta.stamps - tb.stamps)) <= 1e-9
    assert np.max(np.abs(ta.poses - tb.poses)) <= 1e-9


def _assert_like_run(res: Path, ref: Path) -> None:
    for name in GOOD:
        for traj in ("raw.tum", "smoothed.tum"):
            _same_trajectory(res / name / traj, ref / name / traj)


def _summary(res: Path) -> dict:
    doc = json.loads((res / "summary.json").read_text())
    return doc | {"by_name": {r["name"]: r for r in doc["logs"]}}


def _processes_mentioning(text: str) -> list[int]:
    pids = []
    for p in Path("/proc").iterdir():
        try:
            if p.name.isdigit() and text.encode() in (p / "cmdline").read_bytes():
                pids.append(int(p.name))
        except OSError:
            continue
    return pids


def test_batch_local_like_run_then_skips_then_reruns_on_new_config(fleet, ray_head, tmp_path, capsys):
    root, logs, paths = fleet
    res = tmp_path / "res"
    proc = subprocess.run([str(PLANAR_VO), "batch", str(logs), "--out", str(res),
                           "--gt-from-logs", "--quiet"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 5, proc.stderr  # one log failed
    assert sorted(p.name for p in res.iterdir() if p.is_dir()) == sorted(GOOD + ("broken",))
    _assert_like_run(res, root / "ref")
    s = _summary(res)
    assert s["totals"]["ray"]["mode"] == "local" and s["totals"]["skipped"] == 0
    assert _processes_mentioning(s["totals"]["ray"]["session_dir"]) == []  # the command stopped its Ray
    broken = s["by_name"]["broken"]
    assert broken["status"] == "failed" and "broken.mcap" in broken["reason"] and "MCAP" in broken["reason"]
    assert "broken" in proc.stderr and broken["reason"] in proc.stderr
    from planar_vo.evaluation import evaluate_run, ground_truth_for_log
    for name in GOOD:
        row = s["by_name"][name]
        assert row["status"] in ("ok", "not_estimated") and row["frames"] == len(read_tum_trajectory(
            root / "ref" / name / "raw.tum"))
        ev = evaluate_run(root / "ref" / name, ground_truth_for_log(paths[name])[0])
        assert row["smoothed_ate_rmse_m"] == pytest.approx(ev["smoothed"]["ate_rmse_m"], abs=1e-12)
        assert row["raw_endpoint_drift_pct"] == pytest.approx(ev["raw"]["endpoint_drift_pct"], abs=1e-12)
    assert s["by_name"]["corridor"]["steps_dpp"] + s["by_name"]["corridor"]["steps_2pt"] > 0
    md = (res / "summary.md").read_text()
    assert all(f"]({name}/trajectory.png)" in md for name in GOOD)

    # the same batch again: the four finished logs are skipped (untouched), the corrupt one retried
    stamp = {n: (res / n / "raw.tum").stat().st_mtime_ns for n in GOOD}
    t0 = time.perf_counter()
    assert cli(["batch", str(logs), "--out", str(res), "--gt-from-logs", "--address", ray_head, "--quiet"]) == 5
    wall = time.perf_counter() - t0
    s = _summary(res)
    assert [n for n in GOOD if s["by_name"][n]["skipped"]] == list(GOOD)
    assert {n: (res / n / "raw.tum").stat().st_mtime_ns for n in GOOD} == stamp
    assert s["by_name"]["broken"]["status"] == "failed" and not s["by_name"]["broken"]["skipped"]
    assert wall - s["totals"]["ray"]["start_s"] < 8.0, (wall, s["totals"]["ray"])

    # another configuration re-runs every log; Ctrl-C after the first one, then a re-run continues
    cfg = tmp_path / "stride2.yaml"
    cfg.write_text("input:\n  stride: 2\n")
    args = ["batch", str(logs), "--out", str(res), "--config", str(cfg), "--address", ray_head, "--workers", "1", "--quiet"]
    proc = subprocess.Popen([str(PLANAR_VO), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    first = _wait_for_new_key(res, stamp, proc)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 3, err
    assert "interrupted" in err and _summary(res)["totals"]["interrupted"] is True
    capsys.readouterr()
    assert cli(args) == 5
    s = _summary(res)
    assert [n for n in GOOD if s["by_name"][n]["skipped"]] == [first]
    for name in GOOD:
        n_frames = len(read_tum_trajectory(root / "ref" / name / "raw.tum"))
        assert s["by_name"][name]["frames"] == (n_frames + 1) // 2
        assert "stride: 2" in (res / name / "config.yaml").read_text()


def _default_sigint() -> None:
    """In the child before exec: Ctrl-C's default action. A suite started in the background
    by a shell without job control (``bash -c 'pytest &'``) runs with SIGINT ignored, the
    child inherits that and Python then never raises KeyboardInterrupt: the batch ran to its
    end and this test failed twice so."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for_new_key(res: Path, old_stamps: dict, proc, timeout_s: float = 300) -> str:
    """Name of the first log re-run under the new configuration (its raw.tum rewritten and
    its batch.json written), waiting for it while ``proc`` runs."""
    t_end = time.time() + timeout_s
    while time.time() < t_end:
        assert proc.poll() is None, proc.communicate()
        for name, ns in old_stamps.items():
            raw, saved = res / name / "raw.tum", res / name / "batch.json"
            if raw.exists() and raw.stat().st_mtime_ns != ns and saved.exists():
                return name
        time.sleep(0.1)
    raise AssertionError("no log finished under the new configuration")


def test_batch_on_a_ray_cluster_by_address(fleet, ray_head, tmp_path):
    root, logs, paths = fleet
    res = tmp_path / "res"
    assert cli(["batch", *(str(paths[n]) for n in GOOD), "--out", str(res), "--address", ray_head, "--quiet"]) == 0
    _assert_like_run(res, root / "ref")
    s = _summary(res)
    assert s["totals"]["ray"]["mode"] == "cluster" and s["totals"]["by_status"] == {"ok": 4}
    assert s["totals"]["frames_run"] == sum(len(read_tum_trajectory(root / "ref" / n / "raw.tum")) for n in GOOD)


def test_batch_without_ray_says_how_to_install(fleet, monkeypatch, tmp_path, capsys):
    _, logs, _ = fleet
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    assert cli(["batch", str(logs), "--out", str(tmp_path / "res")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'planar-vo[fleet]'" in err[0]


def test_find_logs_names_and_content_hash(tmp_path):
    from planar_vo.fleet.logs import content_hash, find_logs, result_names

    for rel in ("r1/day.mcap", "r2/day.mcap", "x/r1/day.mcap", "run.mcap", ".hidden/h.mcap", "out/r/poses.mcap"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(rel.encode())
    tum = tmp_path / "tum_a"
    (tum / "rgb").mkdir(parents=True)
    (tum / "rgb.txt").write_text("# rgb\n")
    (tum / "inside.mcap").write_bytes(b"not a separate log")
    logs = find_logs([tmp_path, tmp_path / "run.mcap"], exclude=tmp_path / "out")
    rel = [p.relative_to(tmp_path.resolve()).as_posix() for p in logs]
    assert rel == ["r1/day.mcap", "r2/day.mcap", "run.mcap", "tum_a", "x/r1/day.mcap"]
    names = result_names(logs)
    assert [names[p] for p in logs[1:4]] == ["r2_day", "run", "tum_a"]
    assert names[logs[0]].startswith("r1_day-") and names[logs[4]].startswith("r1_day-")
    assert len(set(names.values())) == len(logs)
    # the content decides, not the name: a renamed copy hashes the same, one changed byte does not
    run = logs[2]
    h = content_hash(run)
    shutil.copy(run, tmp_path / "renamed.mcap")
    assert content_hash(tmp_path / "renamed.mcap") == h
    (tmp_path / "renamed.mcap").write_bytes(b"run.mcaP")
    assert content_hash(tmp_path / "renamed.mcap") != h
    (tmp_path / "run.gt.tum").write_text("0 0 0 0 0 0 0 1\n")  # ground truth beside it is read too
    assert content_hash(run) != h
    h_tum = content_hash(tum)
    (tum / "rgb" / "1.png").write_bytes(b"x")
    assert content_hash(tum) != h_tum


def test_a_worker_killed_mid_log_fails_that_log_only(fleet, ray_head, tmp_path):
    """A log whose worker process dies (as under the kernel's OOM killer) is recorded with the
    reason and the next log still runs; the worker is one the module's Ray head started."""
    root, logs, paths = fleet
    res = tmp_path / "res"
    killed: list[int] = []

    def kill_first_task():
        t_end = time.time() + 300
        while not killed and time.time() < t_end:
            for pid in _processes_mentioning("ray::run_log"):
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.02)
    killer = threading.Thread(target=kill_first_task, daemon=True)
    killer.start()
    code = cli(["batch", str(paths["a_shift"]), str(paths["corridor"]), "--out", str(res), "--address", ray_head,
                "--workers", "1", "--quiet"])
    killer.join(1)
    assert killed and code == 5
    s = _summary(res)
    assert s["by_name"]["shift"]["status"] == "failed"  # alone, a/shift.mcap keeps its own name
    assert "worker process died" in s["by_name"]["shift"]["reason"]
    assert s["by_name"]["corridor"]["status"] in ("ok", "not_estimated")
    for traj in ("raw.tum", "smoothed.tum"):
        _same_trajectory(res / "corridor" / traj, root / "ref" / "corridor" / traj)
