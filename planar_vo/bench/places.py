"""Place recognition and loop-closure verification on a rendered corridor ring: ``planar-vo bench places``.

``planar-vo bench places [--seeds 101-102] [--laps 1.4] [--lap-m 24] [--spacing 0.5] [--k 3]
[--resolution 960x540] [--repeat-designs] [--texture medium] [--json OUT]``

For each seed a ``loop`` corridor ring (``--lap-m`` metres a lap) is built and keyframes are
rendered every ``--spacing`` metres along ``--laps`` laps, each pass at its own lateral
offset and heading wobble (the revisit is never the same view). Each keyframe is made as
the pipeline makes it (:func:`make_keyframe`, a fresh :class:`PlanarOdometry` for its
Manhattan observations and levelling), queried against the index (keyframes less than
``--exclude-m`` metres of path back excluded), its best ``--k`` candidates verified, then
added. Printed: how often the true revisited keyframe (within ``--spacing`` of the query
and 25 deg) is ranked first / within k; verification verdicts of the candidates split into
true and false places (ground truth); accepted closures' errors against the ground-truth
relative pose and normalised by their stated information; CPU milliseconds per
make_keyframe, query and verification (one OpenCV thread), and what they add per frame at
0.4 m/s and 10 Hz; bytes per keyframe and index. ``--repeat-designs``: one poster design
and one door design all around (perceptual aliasing).
"""
from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from planar_vo.core.geometry import wrap_angle


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", default="101-102", metavar="A-B", help="inclusive seed range (default 101-102)")
    parser.add_argument("--laps", type=float, default=1.4, help="laps driven (default 1.4)")
    parser.add_argument("--lap-m", type=float, default=24.0, help="metres a lap (default 24)")
    parser.add_argument("--spacing", type=float, default=0.5, help="metres between keyframes (default 0.5)")
    parser.add_argument("--exclude-m", type=float, default=6.0, help="recent path excluded from queries (default 6 m)")
    parser.add_argument("--k", type=int, default=3, help="candidates verified per query (default 3)")
    parser.add_argument("--resolution", default="960x540", help="WxH (default 960x540)")
    parser.add_argument("--texture", default="medium", help="none|low|medium|rich (default medium)")
    parser.add_argument("--repeat-designs", action="store_true", help="one poster and one door design everywhere")
    parser.add_argument("--json", default=None, help="write the figures to this JSON file")


def _poses(scene, lap: float, laps: float, spacing: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe base poses (K, 3) and their arc lengths (K,): a lateral offset and a heading
    offset per pass, plus a small wobble per keyframe."""
    s = np.arange(0.0, laps * lap, spacing)
    pos, head, _ = scene.path.evaluate(s)
    n_pass = int(math.ceil(laps)) + 1
    lateral = rng.uniform(-0.3, 0.3, n_pass)
    turn = np.radians(rng.uniform(-8.0, 8.0, n_pass))
    k = (s // lap).astype(int)
    d = lateral[k] + rng.normal(0.0, 0.03, len(s))
    nrm = np.stack([-np.sin(head), np.cos(head)], -1)
    theta = head + turn[k] + np.radians(rng.normal(0.0, 3.0, len(s)))
    return np.column_stack([pos + d[:, None] * nrm, np.asarray(wrap_angle(theta))]), s


def _keyframes(seed: int, args, config):
    """Rendered keyframes of one seed: ``(keyframes, ground-truth poses, arc lengths, T_base_cam, ms)``."""
    import cv2

    from planar_vo.frontend.odometry import PlanarOdometry
    from planar_vo.frontend.places import make_keyframe
    from planar_vo.sim.synth import SynthConfig, SynthRenderer, synth_intrinsics, synth_mount
    from planar_vo.sim.synth_scene import build_scene

    w, h = (int(v) for v in args.resolution.lower().split("x"))
    cfg = SynthConfig(layout="loop", seed=seed, texture=args.texture).at_resolution(w, h)
    designs = dict(n_posters=1, n_doors=1) if args.repeat_designs else {}
    scene = build_scene("loop", args.lap_m, seed, **designs)
    renderer = SynthRenderer(cfg, scene=scene)
    K, mount = synth_intrinsics(cfg), synth_mount(cfg)
    poses, s = _poses(scene, scene.path.length, args.laps, args.spacing, np.random.default_rng([seed, 5]))
    kfs, ms = [], []
    for i, pose in enumerate(poses):
        f = renderer.render(pose, index=i)
        odo = PlanarOdometry(K, mount)
        res = odo.process(f.rgbd)
        gray = cv2.cvtColor(f.rgbd.color, cv2.COLOR_BGR2GRAY)
        t0 = time.thread_time()
        kfs.append(make_keyframe(i, float(i), gray, f.rgbd.depth, K, odo.levelling.R_lev_cam, res.manhattan, config))
        ms.append(1e3 * (time.thread_time() - t0))
    return kfs, poses, s, mount.T_base_cam, ms, scene.path.length


def _same_place(pa, pb, radius: float) -> bool:
    return math.hypot(pb[0] - pa[0], pb[1] - pa[1]) <= radius and \
        abs(math.degrees(float(wrap_angle(pb[2] - pa[2])))) <= 25.0


def _run_seed(seed: int, args, config, out: dict) -> None:
    from planar_vo.core.geometry import se2_between
    from planar_vo.frontend.places import PlaceIndex, verify_closure

    kfs, poses, s, T_bc, ms_kf, lap = _keyframes(seed, args, config)
    out["ms_keyframe"] += ms_kf
    index = PlaceIndex(config)
    for q, kf in enumerate(kfs):
        recent = int(round(args.exclude_m / args.spacing))
        t0 = time.thread_time()
        ranked = index.query(kf, max_index=kf.index - recent, k=args.k) if q >= recent else []
        out["ms_query"].append(1e3 * (time.thread_time() - t0))
        truth = [p for p in range(max(q - recent + 1, 0)) if _same_place(poses[p], poses[q], args.spacing)]
        if truth:
            out["revisits"] += 1
            got = [p for p, _ in ranked]
            out["top1"] += bool(got) and got[0] in truth
            out["topk"] += any(p in truth for p in got)
        closed = False
        for p, _score in ranked:
            t0 = time.thread_time()
            c = verify_closure(kfs[p], kf, T_bc, config, seed=q)
            out["ms_verify"].append(1e3 * (time.thread_time() - t0))
            same = _same_place(poses[p], poses[q], 1.0)
            key = ("true" if same else "false") + "_candidates"
            out[key][c.reason] = out[key].get(c.reason, 0) + 1
            closed |= c.accepted and same
            if c.accepted:
                gt = se2_between(poses[p], poses[q])
                e = c.pose - gt
                e[2] = float(wrap_angle(e[2]))
                out["errors"].append([float(v) for v in e])
                out["normalised"].append([float(v) for v in np.linalg.cholesky(c.information).T @ e])
                out["accepted_distance_m"].append(float(math.hypot(gt[0], gt[1])))
                if math.hypot(e[0], e[1]) > 0.05 or abs(math.degrees(e[2])) > 0.5:
                    out["wrong"].append({"seed": seed, "a": p, "b": q, "error": [float(v) for v in e],
                                         "inliers": c.inliers, "spread_m": c.spread_m})
        out["closed"] += bool(truth) and closed
        index.add(kf)
    out["bytes_keyframe"].append(float(np.mean([k.nbytes for k in kfs])))
    out["bytes_index_per_keyframe"].append(index.nbytes / max(len(index), 1))


def _report(out: dict, args) -> None:
    ms = {k: float(np.median(out[k])) if out[k] else 0.0 for k in ("ms_keyframe", "ms_query", "ms_verify")}
    n_rev = max(out["revisits"], 1)
    print(f"revisits {out['revisits']}: true keyframe ranked first {out['top1']} ({100 * out['top1'] / n_rev:.0f} %), "
          f"within {args.k} {out['topk']} ({100 * out['topk'] / n_rev:.0f} %); closed (a closure accepted within 1 m) "
          f"{out['closed']} ({100 * out['closed'] / n_rev:.0f} %)")
    print(f"candidates at the same place: {out['true_candidates']}")
    print(f"candidates at other places:  {out['false_candidates']}")
    E = np.array(out["errors"]).reshape(-1, 3)
    print(f"wrong closures accepted (error > 5 cm or 0.5 deg against ground truth): {len(out['wrong'])} "
          f"{out['wrong']}")
    if len(E):
        d = np.array(out["accepted_distance_m"])
        print(f"accepted closures' baselines: median {np.median(d):.2f} m, max {d.max():.2f} m")
        print(f"accepted closures {len(E)}: max error {100 * np.hypot(E[:, 0], E[:, 1]).max():.2f} cm, "
              f"{np.degrees(np.abs(E[:, 2])).max():.3f} deg; normalised RMS (x, y, theta) "
              + " / ".join(f"{v:.2f}" for v in np.sqrt((np.array(out['normalised']) ** 2).mean(0))))
    per_kf = ms["ms_keyframe"] + ms["ms_query"] + args.k * ms["ms_verify"]
    frames_per_kf = args.spacing / 0.04
    print(f"CPU ms (median): make_keyframe {ms['ms_keyframe']:.1f}, query {ms['ms_query']:.2f}, "
          f"verify {ms['ms_verify']:.1f}; per keyframe with {args.k} verifications {per_kf:.1f} ms = "
          f"{per_kf / frames_per_kf:.2f} ms per frame at 0.4 m/s, 10 Hz, a keyframe every {args.spacing} m")
    print(f"memory: {np.mean(out['bytes_keyframe']) / 1e3:.0f} kB per keyframe, "
          f"{np.mean(out['bytes_index_per_keyframe']) / 1e3:.0f} kB per keyframe in the index")


def main(args: argparse.Namespace) -> int:
    import cv2

    from planar_vo.frontend.config import PlaceConfig

    cv2.setNumThreads(1)
    a, _, b = args.seeds.partition("-")
    seeds = range(int(a), int(b or a) + 1)
    config = PlaceConfig()
    out = {"revisits": 0, "top1": 0, "topk": 0, "closed": 0, "true_candidates": {}, "false_candidates": {}, "errors": [],
           "normalised": [], "wrong": [], "accepted_distance_m": [], "ms_keyframe": [], "ms_query": [], "ms_verify": [], "bytes_keyframe": [],
           "bytes_index_per_keyframe": []}
    for seed in seeds:
        _run_seed(seed, args, config, out)
    _report(out, args)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0
