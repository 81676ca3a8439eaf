"""Data-layer benchmark: decode time per encoding, and flat memory while streaming a >= 1 GB log.

Prints (1) milliseconds per frame to read 960x540 logs through ``open_log().frames()``
for every colour and depth encoding and both profiles, split into the pure pixel
decode and the whole read (chunk I/O, message decoding, pairing, pixel decode);
(2) for a generated raw ``bgr8`` + ``16UC1`` log of at least ``--size-gb`` in each of
``--containers`` (MCAP, ROS 1 bag, rosbag2 sqlite3 and mcap folders; one at a time, each
deleted after its check), its size, frames, frames/s and the peak RSS of a fresh reading
process before and after it streams every frame (target: under 500 MB).
"""
from __future__ import annotations

import argparse

W, H = 960, 540
RSS_TARGET_MB = 500.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--size-gb", type=float, default=1.0, help="size of the streamed log (default 1.0)")
    parser.add_argument("--frames-per-encoding", type=int, default=30,
                        help="frames per decode-timing log (default 30)")
    parser.add_argument("--keep", action="store_true", help="keep the generated files (prints where)")
    parser.add_argument("--skip-memory", action="store_true", help="only the per-encoding timings")
    parser.add_argument("--containers", default="mcap,bag,rosbag2-sqlite3,rosbag2-mcap",
                        help="containers streamed for the memory check, comma-separated, one at a time "
                             "(mcap, bag, rosbag2-sqlite3, rosbag2-mcap, mcap-ros1; default: the first four)")
    parser.add_argument("--skip-timings", action="store_true", help="only the memory check")


def _base_frames(seed: int = 0, n: int = 4):
    """A few textured 960x540 frames with plausible depth (smooth ramps + noise)."""
    import cv2
    import numpy as np
    rng = np.random.default_rng(seed)
    out = []
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    for i in range(n):
        noise = rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8)
        color = cv2.resize(noise, (W, H), interpolation=cv2.INTER_CUBIC)
        color = cv2.addWeighted(color, 0.8, rng.integers(0, 256, (H, W, 3), dtype=np.uint8), 0.2, 0)
        depth = (1.0 + 3.0 * yy / H + 0.5 * np.sin(xx / 90.0 + i)).astype(np.float32)
        depth[rng.random((H, W)) < 0.05] = 0
        out.append((color, np.round(depth * 1000) / np.float32(1000)))
    return out


def _timing_table(tmp, n_frames: int) -> None:
    import time

    from planar_vo.io import CameraIntrinsics, RGBDFrame, RGBDLogWriter, open_log
    from planar_vo.io import codecs

    intr = CameraIntrinsics(W, H, 540.7, 540.7, 479.5, 269.5)
    base = _base_frames()
    print(f"decode time per 960x540 frame ({n_frames} frames per log, best of 3 reads)")
    print(f"{'profile':9s} {'colour':6s} {'depth':16s} {'MB/frame':>8s} {'pixel decode ms':>16s} {'full read ms':>13s} "
          f"{'frames/s':>9s}")
    combos = [(c, "16UC1") for c in codecs.COLOR_ENCODINGS] + \
             [("bgr8", d) for d in codecs.DEPTH_ENCODINGS if d != "16UC1"] + [("jpeg", "png"), ("jpeg", "compressedDepth")]
    for profile in ("ros2", "foxglove"):
        for cenc, denc in combos:
            path = tmp / f"t_{profile}_{cenc}_{denc}.mcap"
            with RGBDLogWriter(path, intr, profile=profile, color_encoding=cenc, depth_encoding=denc) as w:
                for i in range(n_frames):
                    c, d = base[i % len(base)]
                    w.write(RGBDFrame(i, 1.7e9 + i / 30, c, d))
            # Pure pixel decode of one encoded frame.
            c, d = base[0]
            ce, de = codecs.encode_color(c, cenc), codecs.encode_depth(d, denc)
            t0 = time.perf_counter()
            for _ in range(n_frames):
                (codecs.decode_raw_color(ce.encoding, H, W, ce.step, ce.data) if ce.raw
                 else codecs.decode_compressed_color(ce.data))
                (codecs.decode_raw_depth(de.encoding, H, W, de.step, de.data) if de.raw
                 else codecs.decode_compressed_depth(de.format, de.data))
            pixel_ms = (time.perf_counter() - t0) / n_frames * 1e3
            best = float("inf")
            for _ in range(3):
                with open_log(path) as log:
                    t0 = time.perf_counter()
                    count = sum(1 for _ in log.frames())
                    best = min(best, time.perf_counter() - t0)
            assert count == n_frames, (path, count)
            size_mb = path.stat().st_size / n_frames / 1e6
            print(f"{profile:9s} {cenc:6s} {denc:16s} {size_mb:8.2f} {pixel_ms:16.2f} {best / count * 1e3:13.2f} "
                  f"{count / best:9.1f}")
            path.unlink()


_READER = """
import json, resource, sys, time
from planar_vo.io import open_log
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
t0 = time.perf_counter()
n = 0
with open_log(sys.argv[1]) as log:
    for f in log.frames():
        n += 1
dt = time.perf_counter() - t0
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print(json.dumps([n, dt, before, after]))
"""


def _generate(tmp, container: str, size_gb: float):
    """A raw bgr8 + 16UC1 log of at least ``size_gb`` in ``container``: ``(path, frames, seconds)``."""
    import time

    import numpy as np

    from planar_vo.io import CameraIntrinsics, RGBDFrame
    from planar_vo.io.rosbags_writer import open_log_writer

    intr = CameraIntrinsics(W, H, 540.7, 540.7, 479.5, 269.5)
    per_frame = W * H * 3 + W * H * 2
    n = int(np.ceil(size_gb * 1e9 / per_frame))
    base = _base_frames(seed=1)
    path = tmp / {"mcap": "big.mcap", "bag": "big.bag", "mcap-ros1": "big_ros1.mcap"}.get(container, "big_rosbag2")
    t0 = time.perf_counter()
    with open_log_writer(path, intr, container=container, color_encoding="bgr8", depth_encoding="16UC1",
                         chunk_compression="none") as w:
        for i in range(n):
            c, d = base[i % len(base)]
            shift = (i * 7) % W  # cheap variety between frames
            w.write(RGBDFrame(i, 1.7e9 + i / 30, np.roll(c, shift, axis=1), np.roll(d, shift, axis=1)))
    return path, n, time.perf_counter() - t0


def _memory_run(tmp, size_gb: float, container: str = "mcap") -> bool:
    import json
    import shutil
    import subprocess
    import sys

    path, n, gen_s = _generate(tmp, container, size_gb)
    size = path.stat().st_size if path.is_file() else sum(p.stat().st_size for p in path.iterdir())
    print(f"\nstreaming memory, {container}: generated {path} ({size / 1e9:.2f} GB, {n} raw bgr8 + 16UC1 "
          f"frames) in {gen_s:.1f} s")
    # A fresh process, so the peak RSS is the reader's alone (ru_maxrss is KiB on Linux).
    res = subprocess.run([sys.executable, "-c", _READER, str(path)], capture_output=True, text=True, check=False)
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()
    if res.returncode != 0:
        raise RuntimeError(f"reader process failed: {res.stderr.strip().splitlines()[-1:]}")
    frames, dt, before, after = json.loads(res.stdout.strip().splitlines()[-1])
    ok = frames == n and after < RSS_TARGET_MB
    print(f"read {frames} frames in {dt:.1f} s = {frames / dt:.1f} frames/s ({size / dt / 1e6:.0f} MB/s)")
    print(f"reader peak RSS: {before:.0f} MB after imports, {after:.0f} MB after streaming the whole log "
          f"(target < {RSS_TARGET_MB:.0f} MB): {'PASS' if ok else 'FAIL'}")
    return ok


def _containers(text: str) -> list[str]:
    from planar_vo.core.errors import InputError
    from planar_vo.io.rosbags_writer import CONTAINERS
    names = [c.strip() for c in text.split(",") if c.strip()]
    bad = [c for c in names if c not in CONTAINERS]
    if bad or not names:
        raise InputError(f"--containers {text!r}: use some of {', '.join(CONTAINERS)}")
    return names


def main(args: argparse.Namespace) -> int:
    import shutil
    import tempfile
    from pathlib import Path

    from planar_vo.core.errors import InputError

    tmp = Path(tempfile.mkdtemp(prefix="planar_vo_bench_io_"))
    need = args.size_gb * 1.1e9
    if not args.skip_memory and shutil.disk_usage(tmp).free < need:
        shutil.rmtree(tmp)
        raise InputError(f"bench io needs {need / 1e9:.1f} GB free in {tmp.parent}; "
                         "lower --size-gb or set TMPDIR")
    ok = True
    try:
        if not args.skip_timings:
            _timing_table(tmp, args.frames_per_encoding)
        if not args.skip_memory:
            ok = all([_memory_run(tmp, args.size_gb, c) for c in _containers(args.containers)])
    finally:
        if args.keep:
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0 if ok else 1
