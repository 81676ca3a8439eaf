"""Loop closures in the pose graph on simulated rings: drift removed, false closures removed,
batch vs iSAM2, cost.

Per seed: a ring (``--size``, ``--laps``) with and without Manhattan factors, true closures
every ``--every`` frames where the path comes back (2 cm / 0.5 deg noise), and ``--false``
random false closures plus a run of ``--alias`` mutually consistent wrong ones
(:func:`planar_vo.sim.simulate.ring_closure_measurements`). Prints, per case: ATE (unaligned,
against truth) without closures, with the true ones, with true and false; how many false were
removed and true kept; batch/iSAM2 difference; batch solve time; iSAM2 time per frame.
The tests use seeds 11 and 12; the default seeds here are others.
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", default="20-25", help="simulation seeds, 'A-B' or 'A,B,...' (default 20-25)")
    parser.add_argument("--size", type=float, nargs=2, default=(20.0, 10.0), metavar=("W", "H"),
                        help="ring rectangle in metres (default 20 10)")
    parser.add_argument("--laps", type=float, default=1.5, help="laps driven (default 1.5)")
    parser.add_argument("--every", type=int, default=10, help="a true closure every this many frames (default 10)")
    parser.add_argument("--false", type=int, default=8, help="random false closures (default 8)")
    parser.add_argument("--alias", type=int, default=5, help="consistent wrong closures, repeated doors (default 5)")
    parser.add_argument("--bad-steps", type=int, default=0,
                        help="steps made 0.5 m / 10 deg wrong while the front-end stays sure of them, "
                             "evenly spaced (default 0): a known limit of the closure selection")


def _seeds(text: str) -> list[int]:
    from planar_vo.core.errors import InputError
    try:
        if "-" in text:
            a, b = (int(v) for v in text.split("-"))
            return list(range(a, b + 1))
        return [int(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"--seeds must be 'A-B' or 'A,B,...' integers, got {text!r}") from None


def _run(cls, seq, closures, info):
    """Graph with ``closures`` added after their later frame: ``(graph, estimate, per-frame s, solve s)``."""
    import time
    g = cls()
    at: dict = {}
    for n, (i, j, p) in enumerate(closures):
        at.setdefault(j, []).append((i, p, n))
    per = []
    for k, r in enumerate(seq.results):
        t0 = time.perf_counter()
        g.add_frame(r)
        for i, p, n in at.get(k, []):
            g.add_closure(i, k, p, info, info={"n": n})
        per.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    est = g.optimize() if hasattr(g, "optimize") else g.estimate()
    return g, est, per, time.perf_counter() - t0


def _case(seed: int, manhattan: bool, args) -> dict:
    import math

    import numpy as np

    from planar_vo.backend.graph import IncrementalPlanarPoseGraph, PlanarPoseGraph
    from planar_vo.sim.simulate import ring_closure_measurements, simulate_ring_sequence, trajectory_errors

    sig = np.array([0.02, 0.02, math.radians(0.5)])
    info = np.diag(1.0 / sig**2)
    seq = simulate_ring_sequence(seed=seed, manhattan=manhattan, size=tuple(args.size), laps=args.laps)
    true, false = ring_closure_measurements(seq.truth, seed=seed, sigma=sig, n_false=args.false,
                                            alias=args.alias, every=args.every)
    for k in np.linspace(0, len(seq.results), args.bad_steps + 2)[1:-1].astype(int):
        seq.results[k].step.pose = seq.results[k].step.pose + np.array([0.5, -0.3, math.radians(10.0)])
    out = {"frames": len(seq.truth), "true": len(true), "false": len(false)}
    ate = lambda e: trajectory_errors(e, seq.truth)["ate_rms_m"]  # noqa: E731
    _, e0, per0, _ = _run(IncrementalPlanarPoseGraph, seq, [], info)
    out["ate_none"], out["isam_ms_none"] = ate(_run(PlanarPoseGraph, seq, [], info)[1]), 1e3 * np.mean(per0)
    est = {}
    for cls, name in ((PlanarPoseGraph, "batch"), (IncrementalPlanarPoseGraph, "isam")):
        for case, cl in (("clean", true), ("false", true + false)):
            g, e, per, solve = _run(cls, seq, cl, info)
            est[name, case] = e
            st = {c["n"]: c["status"] for c in g.closures()}
            out[f"{name}_{case}"] = {
                "ate": ate(e), "solve_s": solve, "ms_per_frame": 1e3 * np.mean(per), "max_ms": 1e3 * max(per),
                "true_kept": sum(st[n] == "active" for n in range(len(true))),
                "false_removed": sum(st[n] == "removed" for n in range(len(true), len(cl)))}
    out["batch_isam_mm"] = max(1e3 * np.abs(est["batch", c][:, :2] - est["isam", c][:, :2]).max()
                               for c in ("clean", "false"))
    return out


def _check(args) -> None:
    from planar_vo.core.errors import InputError
    if min(args.size) <= 0 or args.laps <= 0:
        raise InputError(f"--size and --laps must be > 0, got {args.size} and {args.laps}")
    if args.every < 1 or min(args.false, args.alias, args.bad_steps) < 0:
        raise InputError(f"--every must be >= 1 and --false, --alias, --bad-steps >= 0, got {args.every}, "
                         f"{args.false}, {args.alias}, {args.bad_steps}")


def main(args) -> int:
    _check(args)
    cases = [(s, m) for s in _seeds(args.seeds) for m in (False, True)]
    print(f"rings {args.size[0]:g} x {args.size[1]:g} m, {args.laps:g} laps; closures: true every {args.every} "
          f"frames where the path returns, {args.false} random false + {args.alias} consistent wrong; "
          f"{args.bad_steps} wrong steps the front-end is sure of")
    print("seed manh frames true false | ATE m: none  clean  +false | batch: kept removed solve s | "
          "iSAM2: kept removed ms/frame none clean +false, max ms | batch-iSAM2 mm")
    worst_ratio, all_ok = 0.0, True
    for seed, manhattan in cases:
        r = _case(seed, manhattan, args)
        b, i = r["batch_false"], r["isam_false"]
        ratio = max(b["ate"] / r["batch_clean"]["ate"], i["ate"] / r["isam_clean"]["ate"])
        worst_ratio = max(worst_ratio, ratio)
        ok = all(x["true_kept"] == r["true"] and x["false_removed"] == r["false"] for x in (b, i))
        all_ok &= ok
        print(f"{seed:4d} {'yes' if manhattan else 'no ':4s} {r['frames']:6d} {r['true']:4d} {r['false']:5d} | "
              f"{r['ate_none']:10.3f} {r['batch_clean']['ate']:6.3f} {b['ate']:6.3f} | "
              f"{b['true_kept']:11d} {b['false_removed']:7d} {b['solve_s']:7.2f} | "
              f"{i['true_kept']:11d} {i['false_removed']:7d} {r['isam_ms_none']:13.2f} "
              f"{r['isam_clean']['ms_per_frame']:5.2f} {i['ms_per_frame']:6.2f}, {i['max_ms']:6.0f} | "
              f"{r['batch_isam_mm']:8.2f}")
    print(f"every false closure removed and every true one kept: {'yes' if all_ok else 'NO'}; "
          f"worst ATE with false / clean: {worst_ratio:.3f}")
    return 0
