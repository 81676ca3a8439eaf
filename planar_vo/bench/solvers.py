"""Synthetic solver benchmark (paper Sec. 3.1, Fig. 3-4): 2-point planar vs OpenCV 5-point.

Scene as in the paper: 500 points (half on the floor, half above), focal 1000 px, 50 deg
field of view, mean depth 1, baseline 15 % of it, yaw within +-15 deg, forward and sideways
motion. Sweeps: image noise 0-2 px; pitch and roll levelling error (standard deviation,
deg) at 0.5 px, either shared by both views (a miscalibrated mount, the paper's case) or
independent per view. Every method sees the same data and the same RANSAC threshold
(``max(1, 3 sigma)`` px, or ``--threshold-px``) and ends with a least-squares fit over its
inliers, except OpenCV's RANSAC which has no final refit. The planar methods' fit also tries
a levelling error shared by both views and keeps it when the data ask for it (see
:mod:`planar_vo.frontend.estimators`); they still report the planar motion only.

Errors (eq. 18): rotation ``|yaw_g - yaw_e|`` for planar methods; for the 5-point method the
angle of ``R_g^T R_e`` (it estimates a full 3-D rotation); translation: angle between the
true and estimated directions. Timing: 2-point RANSAC + refinement vs
``cv2.findEssentialMat(RANSAC) + cv2.recoverPose`` on 500 matches with 50 % outliers,
median over runs in this process.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

NOISE_LEVELS = [0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0]
TILT_LEVELS_DEG = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
QUICK_NOISE = [0.5, 1.0, 2.0]
QUICK_TILT = [0.5, 1.0]
FOCAL = 1000.0
TILT_NOISE_PX = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=1000, help="trials per condition (default 1000)")
    parser.add_argument("--quick", action="store_true",
                        help="few levels, 40 trials, 5 timing runs (for tests and a first look)")
    parser.add_argument("--seed", type=int, default=0, help="base seed of every trial (default 0)")
    parser.add_argument("--points", type=int, default=500, help="points per problem (default 500)")
    parser.add_argument("--threshold-px", type=float, default=None,
                        help="RANSAC threshold in pixels for every method (default max(1, 3 * noise))")
    parser.add_argument("--timing-runs", type=int, default=50, help="runs of the timing section (default 50)")
    parser.add_argument("--no-poselib", action="store_true", help="skip the optional PoseLib reference")
    parser.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    parser.add_argument("--plots", metavar="DIR", help="write PNG plots like the paper's Fig. 3 and 4")


# ------------------------------------------------------------------------- methods

def _method_2pt(prob, thr, seed):
    from planar_vo.frontend.estimators import TwoPointOptions, estimate_planar_motion_2pt

    m, _ = estimate_planar_motion_2pt(prob.x1, prob.x2, TwoPointOptions(max_error=thr, seed=seed))
    return None if m is None else (m.R, m.t)


def _method_5pt(prob, thr, seed):
    import cv2

    cv2.setRNGSeed(seed)
    E, mask = cv2.findEssentialMat(prob.x1, prob.x2, np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=thr)
    if E is None or E.shape[0] < 3:
        return None
    _, R, t, _ = cv2.recoverPose(E[:3], prob.x1, prob.x2, np.eye(3), mask=mask)
    return R, t.reshape(3)


def _poselib_solver(kind: str):
    import poselib

    def bearings(x):
        b = np.column_stack([x, np.ones(len(x))])
        return b / np.linalg.norm(b, axis=1, keepdims=True)

    def solve(x1, x2, idx):
        yaws, ts = [], []
        for row in idx:
            if kind == "2pt":
                # poselib 2.0.5 returned the true motion only with the views swapped (checked
                # against simulation), so solve 2 -> 1 and invert
                sols = [(np.asarray(p.R).T, -np.asarray(p.R).T @ np.asarray(p.t))
                        for p in poselib.relpose_upright_planar_2pt(bearings(x2[row]), bearings(x1[row]))]
            else:
                sols = [(np.asarray(p.R), np.asarray(p.t))
                        for p in poselib.relpose_upright_planar_3pt(bearings(x1[row]), bearings(x2[row]))]
            for R, t in sols:
                nt = math.hypot(t[0], t[2])
                if nt > 0 and np.isfinite(R).all():
                    yaws.append(math.atan2(R[0, 2], R[0, 0]))
                    ts.append((t[0] / nt, 0.0, t[2] / nt))
        return np.array(yaws), np.array(ts).reshape(-1, 3)

    return solve


def _method_poselib(kind: str):
    """PoseLib's minimal solver as a variant estimator: same sampling loop, scoring and
    refinement as planar-vo's 2-point estimator, only :meth:`generate` differs."""
    from planar_vo.frontend.estimators import (PlanarTwoPointEstimator, TwoPointOptions,
                                               estimate_planar_motion_2pt)

    solver = _poselib_solver(kind)

    class PoseLibEstimator(PlanarTwoPointEstimator):
        sample_size = 2 if kind == "2pt" else 3

        def generate(self, idx):
            return solver(self.x1, self.x2, idx)

    def run(prob, thr, seed):
        m, _ = estimate_planar_motion_2pt(prob.x1, prob.x2, TwoPointOptions(max_error=thr, seed=seed),
                                          estimator=PoseLibEstimator)
        return None if m is None else (m.R, m.t)

    return run


def _methods(use_poselib: bool):
    """name -> (callable, planar?)."""
    methods = {"2pt": (_method_2pt, True), "5pt-opencv": (_method_5pt, False)}
    if use_poselib:
        try:
            import poselib  # noqa: F401
        except ImportError:
            print("poselib not importable: skipping the PoseLib reference (pip install poselib)")
        else:
            methods["poselib-2pt"] = (_method_poselib("2pt"), True)
            methods["poselib-3pt"] = (_method_poselib("3pt"), True)
    return methods


def _errors(prob, R, t, planar: bool) -> tuple[float, float]:
    """(rotation, translation) errors in degrees, eq. 18."""
    if planar:
        yaw_e = math.atan2(R[0, 2], R[0, 0])
        rot = abs((yaw_e - prob.yaw + math.pi) % (2 * math.pi) - math.pi)
    else:
        Rd = prob.R.T @ R
        rot = math.acos(max(-1.0, min(1.0, (np.trace(Rd) - 1.0) / 2.0)))
    tn = np.linalg.norm(t)
    trans = math.acos(max(-1.0, min(1.0, float(prob.t_dir @ t) / tn))) if tn > 0 else math.pi
    return math.degrees(rot), math.degrees(trans)


# ---------------------------------------------------------------------- experiment

def _conditions(quick: bool):
    """(sweep, tilt_mode, level, noise_px, (pitch_sd, roll_sd) rad) for every condition."""
    noise = QUICK_NOISE if quick else NOISE_LEVELS
    tilt = QUICK_TILT if quick else TILT_LEVELS_DEG
    out = [("noise", "none", lv, lv, (0.0, 0.0)) for lv in noise]
    for axis in ("pitch", "roll"):
        for mode in ("shared", "independent"):
            for lv in tilt:
                r = math.radians(lv)
                out.append((axis, mode, lv, TILT_NOISE_PX, (r, 0.0) if axis == "pitch" else (0.0, r)))
    return out


def run_condition(motion, noise_px, tilt, mode, trials, seed, cond_id, methods, points, threshold_px):
    from planar_vo.sim.problems import make_planar_problem

    thr_px = threshold_px if threshold_px is not None else max(1.0, 3.0 * noise_px)
    thr = thr_px / FOCAL
    errs = {name: [] for name in methods}
    fails = {name: 0 for name in methods}
    for k in range(trials):
        rng = np.random.default_rng([seed, cond_id, k])
        prob = make_planar_problem(rng, points, motion=motion, noise_px=noise_px, focal=FOCAL,
                                   tilt_error=tilt, tilt_mode="shared" if mode == "none" else mode)
        for name, (fn, planar) in methods.items():
            res = fn(prob, thr, k)
            if res is None:
                fails[name] += 1
                continue
            errs[name].append(_errors(prob, res[0], res[1], planar))
    out = {}
    for name in methods:
        e = np.array(errs[name]).reshape(-1, 2)
        out[name] = {
            "mean_rot_deg": float(e[:, 0].mean()) if len(e) else float("nan"),
            "median_rot_deg": float(np.median(e[:, 0])) if len(e) else float("nan"),
            "mean_trans_deg": float(e[:, 1].mean()) if len(e) else float("nan"),
            "median_trans_deg": float(np.median(e[:, 1])) if len(e) else float("nan"),
            "failures": fails[name],
        }
    return out, thr_px


def timing(runs: int, seed: int, points: int) -> dict:
    """Median ms of the 2-point estimator vs OpenCV 5-point on 50 % outliers, one process."""
    import cv2

    from planar_vo.frontend.estimators import TwoPointOptions, estimate_planar_motion_2pt
    from planar_vo.sim.problems import make_planar_problem

    thr = 1.0 / FOCAL
    t2, t5, e2, e5 = [], [], [], []
    for k in range(runs):
        prob = make_planar_problem(np.random.default_rng([seed, 999, k]), points, motion="forward",
                                   noise_px=0.5, focal=FOCAL, outlier_ratio=0.5)
        a = time.perf_counter()
        m, _ = estimate_planar_motion_2pt(prob.x1, prob.x2, TwoPointOptions(max_error=thr, seed=k))
        b = time.perf_counter()
        cv2.setRNGSeed(k)
        E, mask = cv2.findEssentialMat(prob.x1, prob.x2, np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=thr)
        _, R, t, _ = cv2.recoverPose(E[:3], prob.x1, prob.x2, np.eye(3), mask=mask)
        c = time.perf_counter()
        t2.append(b - a)
        t5.append(c - b)
        if m is not None:
            e2.append(_errors(prob, m.R, m.t, True))
        e5.append(_errors(prob, R, t.reshape(3), False))
    m2, m5 = float(np.median(t2)) * 1e3, float(np.median(t5)) * 1e3
    return {
        "points": points, "outlier_ratio": 0.5, "noise_px": 0.5, "runs": runs,
        "median_ms_2pt": m2, "median_ms_5pt_opencv": m5, "ratio_2pt_over_5pt": m2 / m5,
        "median_rot_deg_2pt": float(np.median(np.array(e2)[:, 0])) if e2 else float("nan"),
        "median_trans_deg_2pt": float(np.median(np.array(e2)[:, 1])) if e2 else float("nan"),
        "median_rot_deg_5pt": float(np.median(np.array(e5)[:, 0])),
        "median_trans_deg_5pt": float(np.median(np.array(e5)[:, 1])),
    }


def check_targets(rows: list[dict]) -> dict:
    """The README claims, evaluated on the measured rows."""
    def get(motion, sweep, mode, level, method):
        for r in rows:
            if (r["motion"], r["sweep"], r["tilt_mode"], r["level"], r["method"]) == (motion, sweep, mode, level, method):
                return r
        return None

    def beats(motion, sweep, mode, levels):
        ok = True
        for lv in levels:
            a, b = get(motion, sweep, mode, lv, "2pt"), get(motion, sweep, mode, lv, "5pt-opencv")
            if a is None or b is None:
                continue
            ok &= a["mean_rot_deg"] < b["mean_rot_deg"] and a["mean_trans_deg"] < b["mean_trans_deg"]
        return bool(ok)

    levels = sorted({r["level"] for r in rows if r["sweep"] == "noise"})
    tilt_levels = sorted({r["level"] for r in rows if r["sweep"] != "noise" and r["level"] <= 1.0})
    out = {}
    for motion in ("forward", "sideways"):
        out[f"{motion}: 2pt beats 5pt (mean rot & trans) at every noise >= 0.5 px"] = \
            beats(motion, "noise", "none", [lv for lv in levels if lv >= 0.5])
        for axis in ("pitch", "roll"):
            out[f"{motion}: 2pt beats 5pt across the shared {axis} sweep <= 1 deg"] = \
                beats(motion, axis, "shared", tilt_levels)
    r = get("forward", "noise", "none", 0.5, "2pt")
    if r is not None:
        out["forward 0.5 px: 2pt mean rot < 0.03 deg"] = r["mean_rot_deg"] < 0.03
        out["forward 0.5 px: 2pt mean trans < 0.15 deg"] = r["mean_trans_deg"] < 0.15
    return out


# ---------------------------------------------------------------------------- output

def _print_tables(rows: list[dict], methods: list[str]) -> None:
    for motion in ("forward", "sideways"):
        for sweep, mode in [("noise", "none"), ("pitch", "shared"), ("pitch", "independent"),
                            ("roll", "shared"), ("roll", "independent")]:
            sel = [r for r in rows if (r["motion"], r["sweep"], r["tilt_mode"]) == (motion, sweep, mode)]
            if not sel:
                continue
            unit = "px" if sweep == "noise" else "deg"
            title = f"{motion} motion, {sweep} sweep" + ("" if sweep == "noise" else f" ({mode} tilt, 0.5 px)")
            print(f"\n{title}: mean / median error in degrees ({sweep} in {unit})")
            head = f"{'level':>6} " + " ".join(f"{m + ' rot':>22} {m + ' trans':>22}" for m in methods)
            print(head)
            for lv in sorted({r["level"] for r in sel}):
                cells = []
                for m in methods:
                    r = next((x for x in sel if x["level"] == lv and x["method"] == m), None)
                    if r is None:
                        cells.append(f"{'-':>22} {'-':>22}")
                        continue
                    f = f" ({r['failures']} fail)" if r["failures"] else ""
                    cells.append(f"{r['mean_rot_deg']:>10.4f} /{r['median_rot_deg']:>9.4f}"
                                 f" {r['mean_trans_deg']:>10.4f} /{r['median_trans_deg']:>9.4f}{f}")
                print(f"{lv:>6.2f} " + " ".join(cells))


def _write_json(path: str, payload: dict) -> None:
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".solvers-", suffix=".json", dir=d)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(payload, f, indent=1)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_plots(rows: list[dict], methods: list[str], outdir: str) -> list[str]:
    """One PNG per motion, laid out like the paper's Fig. 3/4 (mean errors).

    Rows: image noise, then pitch and roll sweeps with the tilt shared by both views and
    independent per view; columns: rotation and translation error.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(outdir, exist_ok=True)
    style = {"2pt": ("tab:red", "o", 3), "5pt-opencv": ("tab:blue", "s", 2),
             "poselib-2pt": ("tab:green", "x", 1), "poselib-3pt": ("tab:purple", "^", 1)}
    panels = [("noise", "none", "image noise (px)"),
              ("pitch", "shared", "pitch error sd (deg), shared by both views, 0.5 px"),
              ("pitch", "independent", "pitch error sd (deg), independent per view, 0.5 px"),
              ("roll", "shared", "roll error sd (deg), shared by both views, 0.5 px"),
              ("roll", "independent", "roll error sd (deg), independent per view, 0.5 px")]
    written = []
    for motion in ("forward", "sideways"):
        fig, axes = plt.subplots(len(panels), 2, figsize=(10, 3.0 * len(panels)))
        for i, (sweep, mode, xlabel) in enumerate(panels):
            for j, (key, label) in enumerate((("mean_rot_deg", "rotation"), ("mean_trans_deg", "translation"))):
                ax = axes[i, j]
                for m in methods:
                    sel = sorted((r for r in rows if (r["motion"], r["sweep"], r["tilt_mode"], r["method"])
                                  == (motion, sweep, mode, m)), key=lambda r: r["level"])
                    if sel:
                        color, marker, z = style.get(m, (None, "o", 1))
                        ax.plot([r["level"] for r in sel], [r[key] for r in sel], marker=marker, ms=4,
                                color=color, label=m, zorder=z)
                ax.set_xlabel(xlabel, fontsize=8)
                ax.set_ylabel(f"mean {label} error (deg)", fontsize=8)
                ax.grid(alpha=0.3)
                if j == 0:
                    ax.legend(fontsize=7)
        fig.suptitle(f"{motion} motion: 2-point planar vs 5-point")
        fig.tight_layout()
        path = os.path.join(outdir, f"solvers_{motion}.png")
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written


def main(args) -> int:
    from planar_vo.core.errors import InputError

    trials = 40 if args.quick and args.trials == 1000 else args.trials
    if trials < 1:
        raise InputError(f"--trials must be >= 1, got {trials}")
    if args.points < 10:
        raise InputError(f"--points must be >= 10, got {args.points}")
    timing_runs = 5 if args.quick and args.timing_runs == 50 else args.timing_runs
    methods = _methods(not args.no_poselib)
    names = list(methods)
    print(f"planar-vo bench solvers: {trials} trials/condition, {args.points} points, focal {FOCAL:g} px, "
          f"methods {', '.join(names)}")
    rows = []
    t0 = time.perf_counter()
    conds = _conditions(args.quick)
    for motion in ("forward", "sideways"):
        for ci, (sweep, mode, level, noise, tilt) in enumerate(conds):
            cond_id = ci + (0 if motion == "forward" else 1000)
            res, thr_px = run_condition(motion, noise, tilt, mode, trials, args.seed, cond_id, methods,
                                        args.points, args.threshold_px)
            for name, r in res.items():
                rows.append({"motion": motion, "sweep": sweep, "tilt_mode": mode, "level": level,
                             "noise_px": noise, "threshold_px": thr_px, "method": name, "trials": trials, **r})
        print(f"  {motion}: {len(conds)} conditions done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    _print_tables(rows, names)
    tm = timing(timing_runs, args.seed, args.points)
    print(f"\ntiming ({tm['points']} matches, 50 % outliers, 0.5 px, {tm['runs']} runs, one process): "
          f"2pt RANSAC + refinement {tm['median_ms_2pt']:.2f} ms, OpenCV 5-pt RANSAC + recoverPose "
          f"{tm['median_ms_5pt_opencv']:.2f} ms, ratio {tm['ratio_2pt_over_5pt']:.3f}")
    print(f"  median errors there: 2pt rot {tm['median_rot_deg_2pt']:.4f} trans {tm['median_trans_deg_2pt']:.4f} deg; "
          f"5pt rot {tm['median_rot_deg_5pt']:.4f} trans {tm['median_trans_deg_5pt']:.4f} deg")
    targets = check_targets(rows)
    targets["2pt at most 1/10 of the 5-pt time"] = tm["ratio_2pt_over_5pt"] <= 0.1
    print("\ntargets:")
    for k, v in targets.items():
        print(f"  [{'x' if v else ' '}] {k}")
    if args.json:
        _write_json(args.json, {
            "config": {"trials": trials, "points": args.points, "focal_px": FOCAL, "fov_deg": 50.0,
                       "scene_depth": 1.0, "baseline": 0.15, "yaw_range_deg": 15.0, "seed": args.seed,
                       "threshold_px": args.threshold_px, "quick": bool(args.quick), "methods": names,
                       "tilt_noise_px": TILT_NOISE_PX,
                       "rotation_error": "planar: |yaw_g - yaw_e|; 5pt: angle of R_g^T R_e"},
            "results": rows, "timing": tm, "targets": targets,
        })
        print(f"wrote {args.json}")
    if args.plots:
        for p in write_plots(rows, names, args.plots):
            print(f"wrote {p}")
    return 0
