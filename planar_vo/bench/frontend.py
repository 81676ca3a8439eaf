"""Front-end time per 960x540 frame pair, per stage, on one core; KLT vs ORB accuracy.

Renders a short synthetic corridor (``io.synth``, Kinect v2 qhd, ground truth known),
then runs :class:`planar_vo.frontend.PlanarOdometry` over it once per feature method.
Each ``process()`` call after the first handles one new frame against the previous one:
that is the cost of a frame pair in steady state (every frame is processed once).

Printed per method: median and mean milliseconds of every stage (``FrameResult.timings``,
measured in CPU time of the calling thread) and of the whole call in wall and CPU time, and the accuracy of the
steps against the truth (translation error in mm, yaw error in degrees, estimator use).
OpenCV runs single-threaded and BLAS/OpenMP get one thread (the benchmark re-executes
itself with those variables set, since they must precede numpy's import). The machine's
load average is printed too: on a shared machine wall time includes waiting for a core,
CPU time does not.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

_CHILD = "PLANAR_VO_BENCH_FRONTEND_CHILD"
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")
TARGET_MS = 15.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--layout", default="lturn", help="synthetic layout (default lturn)")
    parser.add_argument("--frames", type=int, default=40, help="frames rendered and processed (default 40)")
    parser.add_argument("--start", type=int, default=30,
                        help="first frame of a 100-frame sequence (default 30: into the turn)")
    parser.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    parser.add_argument("--texture", default="medium", help="synthetic texture level (default medium)")
    parser.add_argument("--methods", default="klt,orb", help="feature methods, comma separated (default klt,orb)")
    parser.add_argument("--repeat", type=int, default=2, help="passes over the frames per method (default 2)")
    parser.add_argument("--json", metavar="PATH", help="also write the figures as JSON")


def main(args: argparse.Namespace) -> int:
    if os.environ.get(_CHILD) != "1":
        env = dict(os.environ, **{v: "1" for v in _THREAD_VARS}, **{_CHILD: "1"})
        argv = ["--layout", args.layout, "--frames", str(args.frames), "--start", str(args.start),
                "--seed", str(args.seed), "--texture", args.texture, "--methods", args.methods,
                "--repeat", str(args.repeat)] + (["--json", args.json] if args.json else [])
        return subprocess.call([sys.executable, "-m", "planar_vo.bench.frontend", *argv], env=env)
    return _run(args)


def _stats(values) -> dict:
    import numpy as np

    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "mean": float(a.mean()), "p90": float(np.percentile(a, 90))}


def _run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from planar_vo.core import geometry as g
    from planar_vo.core.errors import InputError
    from planar_vo.frontend.config import FeatureConfig, FrontendConfig
    from planar_vo.frontend.odometry import PlanarOdometry
    from planar_vo.sim.synth import SynthConfig, render_sequence, synth_intrinsics, synth_mount

    cv2.setNumThreads(1)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for m in methods:
        if m not in ("klt", "orb"):
            raise InputError(f"--methods: unknown feature method {m!r}; use klt and/or orb")
    if args.frames < 2:
        raise InputError("--frames must be at least 2")
    n_total = max(100, args.start + args.frames)
    cfg = SynthConfig(layout=args.layout, n_frames=n_total, seed=args.seed, texture=args.texture)
    K, mount = synth_intrinsics(cfg), synth_mount(cfg)
    t0 = time.perf_counter()
    frames = list(render_sequence(cfg, range(args.start, args.start + args.frames)))
    print(f"planar-vo bench frontend: {len(frames)} frames of '{args.layout}' ({K.width}x{K.height}, "
          f"texture {args.texture}) rendered in {time.perf_counter() - t0:.1f} s; "
          f"cv2 threads {cv2.getNumThreads()}, OMP/BLAS threads {os.environ.get('OMP_NUM_THREADS')}, "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    report = {"layout": args.layout, "frames": len(frames), "width": K.width, "height": K.height,
              "load_average": os.getloadavg()[0], "methods": {}}
    for method in methods:
        stage: dict[str, list[float]] = {}
        wall, cpu = [], []
        terr, yerr, status = [], [], {}
        for rep in range(args.repeat):
            odo = PlanarOdometry(K, mount, FrontendConfig(features=FeatureConfig(method=method)))
            odo.clock = time.thread_time  # stage figures in CPU time of this thread
            odo.process(frames[0].rgbd)
            for prev, f in zip(frames[:-1], frames[1:]):
                w0, c0 = time.perf_counter(), time.thread_time()
                r = odo.process(f.rgbd)
                wall.append(1e3 * (time.perf_counter() - w0))
                cpu.append(1e3 * (time.thread_time() - c0))
                for k, v in r.timings.items():
                    stage.setdefault(k, []).append(1e3 * v)
                if rep == 0:
                    truth = g.se2_between(prev.pose_world_base, f.pose_world_base)
                    e = r.step.pose - truth
                    terr.append(1e3 * float(np.hypot(e[0], e[1])))
                    yerr.append(abs(math.degrees(float(g.wrap_angle(e[2])))))
                    status[r.step.status] = status.get(r.step.status, 0) + 1
        res = {"stages_ms": {k: _stats(v) for k, v in stage.items()}, "wall_ms": _stats(wall),
               "cpu_ms": _stats(cpu), "within_target": float(np.mean(np.asarray(wall) <= TARGET_MS)),
               "cpu_within_target": float(np.mean(np.asarray(cpu) <= TARGET_MS)),
               "translation_error_mm": _stats(terr), "yaw_error_deg": _stats(yerr), "status": status}
        report["methods"][method] = res
        print(f"\n[{method}] {len(wall)} frame pairs")
        print(f"  {'stage (cpu)':<12}{'median ms':>11}{'mean ms':>10}{'p90 ms':>9}")
        for k, v in res["stages_ms"].items():
            print(f"  {k:<12}{v['median']:>11.2f}{v['mean']:>10.2f}{v['p90']:>9.2f}")
        print(f"  {'call (wall)':<12}{res['wall_ms']['median']:>11.2f}{res['wall_ms']['mean']:>10.2f}"
              f"{res['wall_ms']['p90']:>9.2f}")
        print(f"  {'call (cpu)':<12}{res['cpu_ms']['median']:>11.2f}{res['cpu_ms']['mean']:>10.2f}"
              f"{res['cpu_ms']['p90']:>9.2f}")
        print(f"  within {TARGET_MS:.0f} ms: {100 * res['within_target']:.0f} % of pairs by wall time, "
              f"{100 * res['cpu_within_target']:.0f} % by CPU time")
        print(f"  accuracy per step: translation {res['translation_error_mm']['median']:.2f} mm median, "
              f"{res['translation_error_mm']['p90']:.2f} mm p90; yaw {res['yaw_error_deg']['median']:.3f} deg "
              f"median, {res['yaw_error_deg']['p90']:.3f} deg p90; estimators {status}")
    if args.json:
        from planar_vo.io.atomic import atomic_path

        with atomic_path(args.json) as tmp:
            with open(tmp, "w") as fh:
                json.dump(report, fh, indent=2)
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":  # re-executed by main() with single-threaded BLAS/OpenMP
    p = argparse.ArgumentParser(prog="planar-vo bench frontend", description=__doc__.splitlines()[0])
    add_arguments(p)
    sys.exit(main(p.parse_args()))
