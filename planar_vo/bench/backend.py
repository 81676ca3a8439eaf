"""Back-end benchmark: batch LM and iSAM2 on a synthetic 10,000-pose Manhattan run.

Prints graph sizes, solve times, iterations, errors against truth (raw chain, initial
values, optimised), batch/iSAM2 agreement, the robust-kernel comparison under wrong
associations and the native/custom Manhattan factor comparison. Targets: batch <= 2 s,
iSAM2 <= 5 ms per added frame on average (10,000 poses).
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=10000, help="poses in the main graph (default 10000)")
    parser.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    parser.add_argument("--kernel-frames", type=int, default=2000,
                        help="poses per run of the robust-kernel comparison (default 2000; 0 skips it)")
    parser.add_argument("--wrong-fraction", type=float, default=0.2,
                        help="fraction of Manhattan links given a wrong branch or frame (default 0.2)")
    parser.add_argument("--factor-frames", type=int, default=500,
                        help="poses for the native vs custom factor timing (default 500; 0 skips it)")
    parser.add_argument("--skip-isam2", action="store_true", help="skip the iSAM2 run")


def _fmt(e: dict) -> str:
    return (f"final yaw {e['final_yaw_deg']:7.3f} deg  rms yaw {e['rms_yaw_deg']:7.3f} deg  "
            f"end-point {e['endpoint_m']:7.3f} m  ATE rms {e['ate_rms_m']:7.3f} m")


def _build(cls, config, seq, associator=None):
    import time
    g = cls(config, associator=associator)
    t0 = time.perf_counter()
    for r in seq.results:
        g.add_frame(r)
    return g, time.perf_counter() - t0


def main(args) -> int:
    import time

    import numpy as np

    from planar_vo.backend.config import BackendConfig
    from planar_vo.backend.graph import IncrementalPlanarPoseGraph, PlanarPoseGraph
    from planar_vo.sim.simulate import (WrongAssociationInjector, simulate_manhattan_sequence,
                                            trajectory_errors)
    from planar_vo.core.errors import InputError
    from planar_vo.core.geometry import wrap_angle

    if args.frames < 2:
        raise InputError(f"--frames must be >= 2, got {args.frames}")
    if not 0.0 <= args.wrong_fraction < 1.0:
        raise InputError(f"--wrong-fraction must be in [0, 1), got {args.wrong_fraction}")

    t0 = time.perf_counter()
    seq = simulate_manhattan_sequence(args.frames, seed=args.seed)
    print(f"synthetic run: {args.frames} poses, Manhattan frames at "
          f"{', '.join(f'{d:.0f}' for d in np.degrees(seq.frame_yaws))} deg, seed {args.seed} "
          f"(simulated in {time.perf_counter() - t0:.2f} s)")
    cfg = BackendConfig()

    # ------------------------------------------------------------------ batch
    g, t_build = _build(PlanarPoseGraph, cfg, seq)
    c0 = time.process_time()
    batch = g.optimize()
    lm_cpu = time.process_time() - c0
    s = g.stats
    print("\n== batch Levenberg-Marquardt (default config)")
    print(f"graph: {s['poses']} poses, {s['manhattan_frames']} Manhattan frames, factors {s['factors']}")
    print(f"association: {s['associations']} linked, {s['new_frames']} new frames, {s['rejected']} rejected, "
          f"{s['ignored']} ignored, {s['pending']} pending")
    print(f"build {t_build:.3f} s ({t_build / args.frames * 1e3:.3f} ms/frame), "
          f"LM {s['time_s']:.3f} s wall / {lm_cpu:.3f} s CPU, {s['iterations']} iterations, "
          f"error {s['error_initial']:.1f} -> {s['error_final']:.1f}  [target LM <= 2 s]")
    print(f"down-weighted (IRLS weight < 0.5): {s['downweighted']}; pruned: {s['pruned']}")
    raw = trajectory_errors(g.raw_poses(), seq.truth)
    opt = trajectory_errors(batch, seq.truth)
    print(f"raw chain : {_fmt(raw)}")
    print(f"initial   : {_fmt(trajectory_errors(g.initial_poses(), seq.truth))}")
    print(f"optimised : {_fmt(opt)}")
    print(f"improvement: final yaw x{raw['final_yaw_deg'] / opt['final_yaw_deg']:.1f}, "
          f"end-point x{raw['endpoint_m'] / opt['endpoint_m']:.1f}")
    t0 = time.perf_counter()
    cov = g.marginal_covariances()
    print(f"marginal covariances ({len(cov)} poses): {time.perf_counter() - t0:.3f} s; last pose sigma "
          f"x {np.sqrt(cov[-1, 0, 0]):.3f} m, y {np.sqrt(cov[-1, 1, 1]):.3f} m, "
          f"theta {np.degrees(np.sqrt(cov[-1, 2, 2])):.3f} deg")

    # ------------------------------------------------------------------ iSAM2
    if not args.skip_isam2:
        print("\n== iSAM2 (one update per added frame, only the new factors and values)")
        ig = IncrementalPlanarPoseGraph(cfg)
        times = np.empty(args.frames)
        c0 = time.process_time()
        for k, r in enumerate(seq.results):
            t = time.perf_counter()
            ig.add_frame(r)
            times[k] = time.perf_counter() - t
        cpu = (time.process_time() - c0) / args.frames
        t = time.perf_counter()
        inc = ig.estimate()
        t_est = time.perf_counter() - t
        print(f"per added frame: mean {times.mean() * 1e3:.3f} ms, median {np.median(times) * 1e3:.3f} ms, "
              f"p99 {np.percentile(times, 99) * 1e3:.3f} ms, max {times.max() * 1e3:.1f} ms; "
              f"CPU mean {cpu * 1e3:.3f} ms  [target mean <= 5 ms]")
        print(f"last 1000 frames: mean {times[-1000:].mean() * 1e3:.3f} ms; full estimate() {t_est * 1e3:.1f} ms")
        print(f"iSAM2     : {_fmt(trajectory_errors(inc, seq.truth))}")
        dxy = np.abs(inc[:, :2] - batch[:, :2]).max()
        dth = np.degrees(np.abs(wrap_angle(inc[:, 2] - batch[:, 2]))).max()
        print(f"iSAM2 vs batch: max |dxy| {dxy * 1e3:.3f} mm, max |dtheta| {dth:.4f} deg  [target 1 mm, 0.01 deg]")

    # ------------------------------------------------------- robust kernels
    if args.kernel_frames:
        n = args.kernel_frames
        print(f"\n== robust kernels: {n} poses, {args.wrong_fraction:.0%} of Manhattan links given a wrong "
              f"branch or frame, and {args.wrong_fraction:.0%} of observations corrupted (3..45 deg)")
        clean = simulate_manhattan_sequence(n, seed=args.seed + 1)
        bad = simulate_manhattan_sequence(n, seed=args.seed + 1, corrupt_fraction=args.wrong_fraction)
        print(f"{'kernel':8s} {'case':18s} {'final yaw':>10s} {'rms yaw':>9s} {'end-point':>10s} {'ATE rms':>9s}")
        for kernel in ("cauchy", "huber", "none"):
            kc = BackendConfig(robust_kernel=kernel)
            for case, s_, assoc in (("clean", clean, None),
                                    ("wrong links", clean, WrongAssociationInjector(kc, args.wrong_fraction, args.seed)),
                                    ("corrupted obs", bad, None)):
                gk, _ = _build(PlanarPoseGraph, kc, s_, assoc)
                e = trajectory_errors(gk.optimize(), s_.truth)
                print(f"{kernel:8s} {case:18s} {e['final_yaw_deg']:8.3f}deg {e['rms_yaw_deg']:7.3f}deg "
                      f"{e['endpoint_m']:9.3f}m {e['ate_rms_m']:8.3f}m")

    # ------------------------------------------------ native vs custom factor
    if args.factor_frames:
        n = args.factor_frames
        fs = simulate_manhattan_sequence(n, seed=args.seed + 2)
        print(f"\n== Manhattan factor implementation: {n} poses, batch LM")
        res = {}
        for kind in ("native", "custom"):
            gk, _ = _build(PlanarPoseGraph, BackendConfig(manhattan_factor=kind), fs)
            res[kind] = gk.optimize()
            print(f"{kind:7s}: LM {gk.stats['time_s']:.3f} s, {gk.stats['iterations']} iterations")
        d = np.abs(res["native"] - res["custom"]).max()
        print(f"native vs custom solution: max difference {d:.2e}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    import sys

    p = argparse.ArgumentParser(prog="planar-vo bench backend", description=__doc__.splitlines()[0])
    add_arguments(p)
    sys.exit(main(p.parse_args()))
