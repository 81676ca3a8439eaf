"""Planar pose graph on synthetic runs with known truth: Manhattan factors vs chaining,
wrong associations, batch vs iSAM2, marginals, association, relative factors, inputs."""
import math

import numpy as np
import pytest

from planar_vo.backend.config import BackendConfig
from planar_vo.backend.graph import IncrementalPlanarPoseGraph, PlanarPoseGraph
from planar_vo.sim.simulate import (WrongAssociationInjector, simulate_manhattan_sequence,
                                        trajectory_errors)
from planar_vo.core.steps import STATUS_BRIDGED, STATUS_DPP, STATUS_PARTIAL, FrameResult, ManhattanObservation, Step
from planar_vo.core.geometry import se2_between, wrap_angle

N = 1000


def _solve(seq, config=None, associator=None):
    g = PlanarPoseGraph(config or BackendConfig(), associator=associator)
    for r in seq.results:
        g.add_frame(r)
    return g, g.optimize()


@pytest.fixture(scope="module")
def seq():
    return simulate_manhattan_sequence(N, seed=3)


@pytest.fixture(scope="module")
def batch(seq):
    return _solve(seq)


def test_manhattan_factors_remove_yaw_drift(seq, batch):
    g, est = batch
    raw = trajectory_errors(g.raw_poses(), seq.truth)
    opt = trajectory_errors(est, seq.truth)
    assert raw["final_yaw_deg"] > 5.0  # the simulated yaw bias really drifts
    assert opt["final_yaw_deg"] * 10 <= raw["final_yaw_deg"]
    assert opt["endpoint_m"] * 3 <= raw["endpoint_m"]
    assert np.all(est[0] == pytest.approx(0.0, abs=1e-6))


def test_without_manhattan_the_graph_is_the_chain(seq):
    g, est = _solve(seq, BackendConfig(manhattan=False))
    assert np.abs(est[:, :2] - g.raw_poses()[:, :2]).max() < 1e-6
    assert np.abs(wrap_angle(est[:, 2] - g.raw_poses()[:, 2])).max() < 1e-8


def test_association_finds_the_two_corridor_frames(seq, batch):
    g, _ = batch
    frames = g.manhattan_frames()
    assert len(frames) == 2  # revisits after detours join the existing frames
    true_yaws = np.degrees(seq.frame_yaws)  # 0 and 60 deg; 60 == -30 modulo 90
    got = sorted(np.degrees(y) for _, y, _ in frames)
    assert got[0] == pytest.approx(-30.0, abs=0.5) and got[1] == pytest.approx(0.0, abs=0.5)
    assert {round(t) % 90 for t in true_yaws} == {0, 60}
    s = g.stats
    n_obs = sum(len(r.manhattan) for r in seq.results)
    assert s["associations"] == n_obs and s["rejected"] == 0 and s["new_frames"] == 2
    assert s["factors"]["manhattan"] == n_obs and s["factors"]["step"] == N - 1
    assert sum(n for _, _, n in frames) == n_obs


def test_wrong_associations_barely_change_the_result():
    """20 % of the Manhattan links moved to a wrong branch or frame (mean over 4 seeds)."""
    clean, bad = [], []
    for seed in range(4):
        s = simulate_manhattan_sequence(N, seed=seed)
        cfg = BackendConfig()
        clean.append(trajectory_errors(_solve(s, cfg)[1], s.truth))
        inj = WrongAssociationInjector(cfg, 0.2, seed)
        g, est = _solve(s, cfg, inj)
        assert inj.n_corrupted > 0.15 * g.stats["associations"]
        assert g.stats["pruned"]["manhattan"] >= 0.9 * inj.n_corrupted
        assert g.stats["pruned"]["reassociated"] >= 0.9 * g.stats["pruned"]["manhattan"]
        bad.append(trajectory_errors(est, s.truth))
    for key in ("final_yaw_deg", "endpoint_m"):
        c, b = np.mean([e[key] for e in clean]), np.mean([e[key] for e in bad])
        assert b <= 1.10 * c, (key, b, c)


def test_cauchy_holds_up_better_than_huber_with_wrong_associations():
    s = simulate_manhattan_sequence(600, seed=5)
    errs = {}
    for kernel in ("cauchy", "huber"):
        cfg = BackendConfig(robust_kernel=kernel, prune_sigmas=0.0)  # the kernel alone
        errs[kernel] = trajectory_errors(_solve(s, cfg, WrongAssociationInjector(cfg, 0.2, 5))[1], s.truth)
    assert errs["cauchy"]["rms_yaw_deg"] < 1.0
    assert errs["huber"]["rms_yaw_deg"] > 5 * errs["cauchy"]["rms_yaw_deg"]


def test_corrupted_observations_are_gated():
    s = simulate_manhattan_sequence(600, seed=6, corrupt_fraction=0.2)
    g, est = _solve(s)
    frames = sorted(g.manhattan_frames(), key=lambda f: -f[2])
    # the two true frames carry the observations; stray walls rarely make (small) frames
    assert sum(f[2] for f in frames[:2]) >= 0.9 * sum(f[2] for f in frames)
    assert sorted(round(math.degrees(f[1])) for f in frames[:2]) == [-30, 0]
    assert g.stats["rejected"] > 0.5 * len(s.corrupted)
    assert trajectory_errors(est, s.truth)["rms_yaw_deg"] < 1.0


def test_isam2_agrees_with_batch(seq, batch):
    _, est = batch
    ig = IncrementalPlanarPoseGraph()
    for r in seq.results:
        ig.add_frame(r)
    inc = ig.estimate()
    assert ig.stats["updates"] >= N
    assert np.abs(inc[:, :2] - est[:, :2]).max() < 1e-3
    assert np.degrees(np.abs(wrap_angle(inc[:, 2] - est[:, 2]))).max() < 0.01
    assert [f[0] for f in ig.manhattan_frames()] == [0, 1]
    np.testing.assert_allclose(ig.latest(), inc[-1], atol=1e-3)


def _chain(steps, info, manhattan=None, status=STATUS_DPP):
    out = [FrameResult(0, 0.0, None, list(manhattan[0]) if manhattan else [])]
    for k, p in enumerate(steps, start=1):
        out.append(FrameResult(k, 0.1 * k, Step(np.asarray(p, float), info, status, 10),
                               list(manhattan[k]) if manhattan else []))
    return out


def test_marginal_yaw_variance_of_a_chain_is_the_sum_of_step_variances():
    rng = np.random.default_rng(7)
    steps = np.column_stack([rng.uniform(0.05, 0.2, 50), rng.normal(0, 0.02, 50), rng.normal(0, 0.05, 50)])
    sig = np.array([0.01, 0.02, 0.005])
    info = np.diag(1 / sig**2)
    cfg = BackendConfig(robust_kernel="none", manhattan=False)
    g = PlanarPoseGraph(cfg)
    for r in _chain(steps, info):
        g.add_frame(r)
    cov = g.marginal_covariances()
    assert cov.shape == (51, 3, 3)
    prior = math.radians(cfg.prior_sigma_theta_deg) ** 2
    # heading is additive along a chain: var(theta_k) = prior + k * var(step theta)
    np.testing.assert_allclose(cov[:, 2, 2], prior + np.arange(51) * sig[2] ** 2, rtol=1e-6)
    assert np.all(np.linalg.eigvalsh(cov[1:]) > 0)
    ig = IncrementalPlanarPoseGraph(cfg)
    for r in _chain(steps, info):
        ig.add_frame(r)
    np.testing.assert_allclose(ig.marginal_covariances(), cov, rtol=1e-5, atol=1e-14)


def test_add_relative_closes_a_loop():
    # a square driven round once with noisy steps (consistent with their information);
    # one loop closure back to the start
    rng = np.random.default_rng(8)
    truth = [np.zeros(3)]
    for k in range(80):
        turn = math.pi / 2 if k % 20 == 19 else 0.0
        truth.append(np.array([*(truth[-1][:2] + 0.2 * np.array([math.cos(truth[-1][2]), math.sin(truth[-1][2])])),
                               float(wrap_angle(truth[-1][2] + turn))]))
    truth = np.array(truth)
    sig = np.array([0.01, 0.01, 0.01])
    steps = [se2_between(truth[k], truth[k + 1]) + rng.normal(0, sig) for k in range(80)]
    info = np.diag(1 / sig**2)
    for cls in (PlanarPoseGraph, IncrementalPlanarPoseGraph):
        g = cls(BackendConfig(manhattan=False))
        for r in _chain(steps, info):
            g.add_frame(r)
        before = np.linalg.norm((g.raw_poses()[80] - truth[80])[:2])
        g.add_relative(80, 0, se2_between(truth[80], truth[0]), np.diag([1e6, 1e6, 1e6]))
        assert g.stats["factors"]["relative"] == 1
        est = g.optimize() if cls is PlanarPoseGraph else g.estimate()
        after = np.linalg.norm((est[80] - truth[80])[:2])
        assert before > 0.1 and after < 0.2 * before


def test_bridged_step_is_overridden_and_repaired_by_manhattan():
    # straight corridor at 0 deg; frame 10 is bridged with a 20-degree wrong yaw
    steps = [np.array([0.1, 0.0, 0.0]) for _ in range(20)]
    steps[9] = np.array([0.1, 0.0, math.radians(20.0)])
    obs = [[ManhattanObservation(0.0, math.radians(0.5), 0.5)] for _ in range(21)]
    info = np.diag([1e4, 1e4, 1e5])
    res = _chain(steps, info, obs)
    res[10].step.status = STATUS_BRIDGED
    res[10].step.information = np.diag([1e8, 1e8, 1e8])  # a front-end that is wrongly sure
    # the default trusts the front-end's stated uncertainty; "override" replaces it
    g = PlanarPoseGraph(BackendConfig(bridged_policy="override"))
    for r in res:
        g.add_frame(r)
    est = g.optimize()
    assert np.degrees(np.abs(est[10:, 2])).max() < 0.5
    assert g.stats["factors"]["bridged"] == 1


def test_single_stray_observation_does_not_create_a_frame():
    steps = [np.array([0.1, 0.0, 0.0]) for _ in range(30)]
    obs = [[ManhattanObservation(0.0, 0.01, 0.5)] for _ in range(31)]
    obs[15] = [ManhattanObservation(math.radians(25.0), 0.01, 0.5)]
    g = PlanarPoseGraph()
    for r in _chain(steps, np.eye(3) * 1e4, obs):
        g.add_frame(r)
    g.optimize()
    assert len(g.manhattan_frames()) == 1 and g.stats["rejected"] == 1


def test_inputs_are_validated():
    g = PlanarPoseGraph()
    g.add_frame(FrameResult(0, 0.0, None))
    with pytest.raises(ValueError, match="step=None"):
        g.add_frame(FrameResult(1, 0.1, None))
    with pytest.raises(ValueError, match=r"\(3, 3\).*got shape \(2, 2\)"):
        g.add_frame(FrameResult(1, 0.1, Step(np.zeros(3), np.eye(2), STATUS_DPP)))
    with pytest.raises(ValueError, match="positive definite"):
        g.add_frame(FrameResult(1, 0.1, Step(np.zeros(3), -np.eye(3), STATUS_DPP)))
    with pytest.raises(ValueError, match=r"got shape \(2,\)"):
        g.add_frame(FrameResult(1, 0.1, Step(np.zeros(2), np.eye(3), STATUS_DPP)))
    with pytest.raises(ValueError, match="i=5 is not a frame"):
        g.add_relative(5, 0, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="sigma > 0"):
        g.add_frame(FrameResult(1, 0.1, Step(np.zeros(3), np.eye(3), STATUS_DPP),
                                [ManhattanObservation(0.1, 0.0, 1.0)]))
    assert PlanarPoseGraph().optimize().shape == (0, 3)


def _wobbling_truth(speeds, rate_hz=10.0):
    """Base poses (N+1, 3) driving ``speeds`` (N,) m/s along x, heading weaving +-3 deg."""
    poses = [np.zeros(3)]
    for k, v in enumerate(speeds, start=1):
        th = math.radians(3.0) * math.sin(2 * math.pi * k / 40)
        p = poses[-1]
        d = v / rate_hz
        poses.append(np.array([p[0] + d * math.cos(p[2]), p[1] + d * math.sin(p[2]), th]))
    return np.array(poses)


def _gap_results(truth, gap, guess, rng):
    """Frames over ``truth``: steps in ``gap`` partial (translation along x unmeasured: x is
    ``guess(k)`` at a 1 m sigma; y and yaw measured), the rest measured at 1 mm / 0.03 deg."""
    out = [FrameResult(0, 0.0, None, [])]
    for k in range(1, len(truth)):
        step = se2_between(truth[k - 1], truth[k])
        sig = np.array([0.001, 0.001, math.radians(0.03)])
        status = STATUS_DPP
        if k in gap:
            sig[0], status = 1.0, STATUS_PARTIAL
        meas = step + rng.normal(0, 1, 3) * np.minimum(sig, 0.001)
        if k in gap:
            meas[0] = guess(k)
        out.append(FrameResult(k, 0.1 * k, Step(meas, np.diag(1 / sig ** 2), status, 10), []))
    return out


def _start_gap_error(cls, speeds, **config) -> tuple[float, int]:
    """End-point error / path of a run over ``speeds`` whose steps 1-59 (of 120) are partial
    with x unmeasured (x = 0 at a 1 m sigma), and the number of motion priors."""
    rng = np.random.default_rng(21)
    truth = _wobbling_truth(speeds)
    res = _gap_results(truth, set(range(1, 60)), lambda k: 0.0, rng)
    path = float(np.sum(np.linalg.norm(np.diff(truth[:, :2], axis=0), axis=1)))
    g = cls(BackendConfig(manhattan=False, **config))
    for r in res:
        g.add_frame(r)
    est = g.optimize() if cls is PlanarPoseGraph else g.estimate()
    return float(np.linalg.norm(est[-1, :2] - truth[-1, :2])) / path, g.stats["factors"].get("motion_prior", 0)


#: 0.6 m/s reached from rest at 0.4 m/s^2 (1.5 s; the prior's ramp assumes 0.5)
FROM_REST = np.minimum(0.6, 0.4 * (np.arange(120) + 0.5) / 10.0)


@pytest.mark.parametrize("cls", [PlanarPoseGraph, IncrementalPlanarPoseGraph])
def test_motion_prior_fills_a_start_gap_with_the_speed_measured_after_it(cls):
    """Mechanism 4's corridor: no texture, so until the end wall comes into range (here
    step 60 of 120) nothing measures the motion along the walls and the front-end's partial
    steps say x = 0 at a 1 m sigma. The base_link velocity prior carries the speed measured
    afterwards back over the gap; without it the smoothed trajectory stands still there.
    Here the base was already moving when the log began (``motion_prior_start_at_rest``
    off, the default: no ramp from rest)."""
    moving = np.full(120, 0.6)
    if cls is PlanarPoseGraph:  # (iSAM2's Cholesky finds the 1 m-sigma chain indeterminate)
        assert _start_gap_error(cls, moving, motion_prior_accel=0.0)[0] > 0.45  # half the path lost
    err, priors = _start_gap_error(cls, moving)
    # the gap's 58 steps and the measured steps after it: in a batch solve those of the four
    # 0.5 s windows that give the speed after the gap (20 at 10 Hz); iSAM2 releases the gap's
    # priors where it ends, with the window of 10
    assert priors == 59 + (19 if cls is PlanarPoseGraph else 10)
    # The speed carried back over the gap is that of the first measured steps, whose own
    # 1 mm noise is 2 % of a 60 mm step: with the prior on the first one only (window 0),
    # the gap took its 58.5 mm, 2.7 % of this path at the end, against 50 % without the prior.
    assert err < 0.02


@pytest.mark.parametrize("cls", [PlanarPoseGraph, IncrementalPlanarPoseGraph])
def test_motion_prior_starts_a_start_gap_from_rest(cls):
    """The same gap, but the base starts from rest and speeds up at 0.4 m/s^2. Carried back
    at the speed measured after it, the gap puts the base about v^2 / 2a = 0.45 m too far
    (4.8 % of this path at the end); with the ramp from rest at ``motion_prior_accel``
    (0.5 m/s^2, not the true 0.4) 0.25 %. The assumption has its price where it is wrong: on
    the base that was moving (the test above) the ramp loses about v^2 / 2a = 0.36 m (6.3 %)."""
    err_cv, _ = _start_gap_error(cls, FROM_REST)  # the default: no ramp
    err_ramp, _ = _start_gap_error(cls, FROM_REST, motion_prior_start_at_rest=True)
    err_moving, _ = _start_gap_error(cls, np.full(120, 0.6), motion_prior_start_at_rest=True)
    assert err_cv > 0.04
    assert err_ramp < 0.01
    assert err_moving > 0.04


def _solved_distance_error(results, truth, i: int, j: int, **config) -> float:
    """Error (m) of the batch-solved distance between frames ``i`` and ``j`` against ``truth``."""
    g = PlanarPoseGraph(BackendConfig(manhattan=False, **config))
    for r in results:
        g.add_frame(r)
    est = g.optimize()
    return float(np.linalg.norm(est[j, :2] - est[i, :2]) - np.linalg.norm(truth[j, :2] - truth[i, :2]))


def _sparse_start_gap_error(seed: int, **config) -> float:
    """Error (m) of the distance over a start gap: 0.2 m/s at 20 Hz (10 mm steps), steps
    1-199 of 400 partial with x unmeasured (0 at a 1 m sigma) except every fifth of steps
    150-199, which measures x at a 10 mm sigma (a few 3-D matches or the depth alignment
    on a textureless wall); the rest direction-plus-point steps at 5 mm (at 20 Hz none is
    fine enough to show the acceleration a step, ``_GraphBuilder._velocity``)."""
    rng = np.random.default_rng(seed)
    truth = _wobbling_truth(np.full(400, 0.2), rate_hz=20.0)
    res = [FrameResult(0, 0.0, None, [])]
    for k in range(1, len(truth)):
        step = se2_between(truth[k - 1], truth[k])
        sig = np.array([0.005, 0.001, math.radians(0.03)])
        status = STATUS_DPP
        if k < 200:
            sig[0], status = (0.01 if k >= 150 and k % 5 == 0 else 1.0), STATUS_PARTIAL
        meas = step + rng.normal(0, 1, 3) * sig
        if sig[0] == 1.0:
            meas[0] = 0.0
        res.append(FrameResult(k, 0.05 * k, Step(meas, np.diag(1 / sig ** 2), status, 10), []))
    return _solved_distance_error(res, truth, 0, 200, **config)


def test_a_start_gap_takes_the_speed_of_the_windows_measured_after_it():
    """straight_s8303 (seen): in a textureless corridor only the side walls were in range for
    250 frames, so the start gap's speed came from its few partial steps that measured some
    of the forward motion, each to about the step's length. At the prior's loose bound
    (0.5 m/s^2) the speed of the first few was carried back to frame 0, and the run ended
    0.90 m too far. The start gap's acceleration is now measured over 0.5 s windows of the
    steps after it, whose noise then shows a cruise: over 10 seeds the gap's distance errs
    by a few centimetres, where the loose bound (``motion_prior_gap_baseline_s`` 0, the
    code before) errs by decimetres."""
    new = np.array([_sparse_start_gap_error(s) for s in range(10)])
    old = np.array([_sparse_start_gap_error(s, motion_prior_gap_baseline_s=0.0) for s in range(10)])
    print("start gap distance error RMS new / old (m):", np.sqrt(np.mean(new ** 2)), np.sqrt(np.mean(old ** 2)))
    assert np.sqrt(np.mean(new ** 2)) < 0.2
    assert np.sqrt(np.mean(old ** 2)) > 3 * np.sqrt(np.mean(new ** 2))


def _partial_only_start_gap_error(seed: int, **config) -> float:
    """Error (m) of the distance over a start gap in a run with no estimator step at all
    (an untextured corridor): 0.5 m/s at 20 Hz (25 mm steps), steps 1-199 partial with x
    guessed 50 mm (twice the step) at a 0.3 m sigma, standing in for the weak ties that
    pulled straight_s9636's start, then 35 partial steps whose x walls ahead measured at
    4 mm: 1.75 s, three 0.5 s windows before the log ends."""
    rng = np.random.default_rng(seed)
    truth = _wobbling_truth(np.full(235, 0.5), rate_hz=20.0)
    res = [FrameResult(0, 0.0, None, [])]
    for k in range(1, len(truth)):
        sig = np.array([0.3 if k < 200 else 0.004, 0.001, math.radians(0.03)])
        meas = se2_between(truth[k - 1], truth[k]) + rng.normal(0, 1, 3) * sig
        if k < 200:
            meas[0] = 0.05
        res.append(FrameResult(k, 0.05 * k, Step(meas, np.diag(1 / sig ** 2), STATUS_PARTIAL, 2), []))
    return _solved_distance_error(res, truth, 0, 200, **config)


def test_a_start_gap_ends_where_a_partial_step_measures_the_speed():
    """straight_s9636 (seeds 9600-9699, untextured, seen): no estimator measured any step,
    so the start gap never ended, its priors stayed at the loose bound and the smoothed
    start ran at 35 mm a step against a true 26 (18.8 % of the path at the end). The gap now
    ends at the first step whose forward speed was measured, by an estimator or by a
    partial step within 25 %, and windows of such steps give the speed after it, also the
    two or three that arrive before the log ends. Measured over 5 seeds: the 5 m gap's
    distance errs by 0.12 m RMS, against 0.90 m at the loose bound
    (``motion_prior_gap_baseline_s`` 0, which is what this run got before)."""
    new = np.array([_partial_only_start_gap_error(s) for s in range(5)])
    old = np.array([_partial_only_start_gap_error(s, motion_prior_gap_baseline_s=0.0) for s in range(5)])
    assert np.sqrt(np.mean(new ** 2)) < 0.2
    assert np.sqrt(np.mean(old ** 2)) > 3 * np.sqrt(np.mean(new ** 2))


def _speeding_up_distance_errors(seed: int) -> tuple[float, float]:
    """Errors (m) of the smoothed and raw distance over frames 0-60 of a base that speeds up
    from rest to 0.44 m/s in 1 s at 20 Hz (lturn_s8701's start): the first step partial
    (its translation measured at 1 mm), the rest direction-plus-point steps whose noise
    (4 mm along, 2.5 mm across) is as large as the first steps themselves."""
    rng = np.random.default_rng(seed)
    speeds = np.minimum(0.44, 0.44 * (np.arange(200) + 0.5) / 20.0)
    truth = _wobbling_truth(speeds, rate_hz=20.0)
    res = [FrameResult(0, 0.0, None, [])]
    for k in range(1, len(truth)):
        sig = np.array([0.004, 0.0025, math.radians(0.035)])
        status = STATUS_DPP
        if k == 1:
            sig[0], status = 0.001, STATUS_PARTIAL
        meas = se2_between(truth[k - 1], truth[k]) + rng.normal(0, 1, 3) * sig
        res.append(FrameResult(k, 0.05 * k, Step(meas, np.diag(1 / sig ** 2), status, 10), []))
    g = PlanarPoseGraph(BackendConfig(manhattan=False))
    for r in res:
        g.add_frame(r)
    est, raw = g.optimize(), g.raw_poses()
    true_d = np.linalg.norm(truth[60, :2] - truth[0, :2])
    return (float(np.linalg.norm(est[60, :2] - est[0, :2]) - true_d),
            float(np.linalg.norm(raw[60, :2] - raw[0, :2]) - true_d))


def test_a_start_gap_of_one_step_is_not_held_to_the_speed_after_it():
    """A start gap no longer than the prior's window is tied to the steps after it like any
    other gap. Held as a start gap (the code before), the four 0.5 s windows after it were tied
    at the acceleration they show between them, and a base speeding up from rest was bent:
    over these 20 seeds the smoothed distance came out 26 mm short on average where the raw
    chain was 4 mm short (on lturn_s8701, 8700 set, the smoothed run lost 10 mm the raw
    chain kept, 0.08 -> 0.25 % of the path); now 3 mm."""
    errs = np.array([_speeding_up_distance_errors(s) for s in range(20)])
    smoothed, raw = errs.mean(axis=0)
    assert abs(raw) < 0.01  # the chain of unbiased steps is unbiased
    assert abs(smoothed) < 0.01


def test_motion_prior_interpolates_a_gap_between_two_speeds():
    """A gap of 40 partial steps while the base speeds up from 0.4 to 0.8 m/s: the front-end
    can only copy the speed from before (0.4); the prior, seeing both sides, spreads the
    change over the gap. The gap's length error falls from 0.8 m to a few cm."""
    rng = np.random.default_rng(22)
    speeds = np.concatenate([np.full(40, 0.4), np.linspace(0.4, 0.8, 40), np.full(40, 0.8)])
    truth = _wobbling_truth(speeds)
    res = _gap_results(truth, set(range(41, 81)), lambda k: 0.04, rng)

    def gap_length_error(accel):
        g = PlanarPoseGraph(BackendConfig(manhattan=False, motion_prior_accel=accel))
        for r in res:
            g.add_frame(r)
        est = g.optimize()
        d = np.linalg.norm(est[80, :2] - est[40, :2]) - np.linalg.norm(truth[80, :2] - truth[40, :2])
        return abs(float(d))

    assert gap_length_error(0.0) > 0.7
    assert gap_length_error(0.5) < 0.05


def _cruise_gap_error(window: int, speeds, gap, noisy: dict, stated: float, rng, lo: int, hi: int) -> float:
    """Length error (m) of the smoothed path over frames ``lo..hi`` of a run over ``speeds``
    whose steps in ``gap`` are partial, the others measured at ``stated`` sigma along x
    with a 0.3 mm error, except the steps in ``noisy`` (frame -> error along x, m)."""
    truth = _wobbling_truth(speeds)
    res = _gap_results(truth, gap, lambda k: 0.0, rng)
    for k, e in noisy.items():
        st = res[k].step
        res[k] = FrameResult(k, res[k].stamp, Step(st.pose + np.array([e, 0, 0]), st.information, st.status, 10), [])
    for k in range(1, len(res)):
        if k not in gap:
            st = res[k].step
            info = np.diag([1 / stated ** 2, st.information[1, 1], st.information[2, 2]])
            pose = st.pose.copy()
            if k not in noisy:
                pose[0] = se2_between(truth[k - 1], truth[k])[0] + rng.normal(0, 3e-4)
            res[k] = FrameResult(k, res[k].stamp, Step(pose, info, st.status, 10), [])
    g = PlanarPoseGraph(BackendConfig(manhattan=False, motion_prior_window=window))
    for r in res:
        g.add_frame(r)
    est = g.optimize()
    d = np.linalg.norm(est[hi, :2] - est[lo, :2]) - np.linalg.norm(truth[hi, :2] - truth[lo, :2])
    return abs(float(d))


def test_a_gap_takes_the_speed_of_the_measured_steps_around_it_not_of_one():
    """Cruising at 0.3 m/s: 30 partial steps (translation guessed at a 1 m sigma), and the
    one measured step before them errs by 5 mm (stated 5 mm; the others by 0.3 mm, stated
    2.5 mm). Tied to that step alone the gap copies its error into each of its steps
    (lturn_s4404 of the held-out 4400 set lost 69 mm over 18 steps so); tied to the steps of a
    window on both sides, whose velocity changes show a cruise, it keeps the speed (79 mm
    -> 20 mm over the gap)."""
    rng = np.random.default_rng(23)
    gap = set(range(41, 71))
    args = (np.full(110, 0.3), gap, {40: 0.005}, 0.0025)
    alone = _cruise_gap_error(0, *args, np.random.default_rng(23), 39, 71)
    window = _cruise_gap_error(10, *args, rng, 39, 71)
    assert alone > 0.06                  # ~5 mm x 30 steps, shared with the steps after
    assert window < 0.03


def test_a_braking_base_is_not_held_to_a_cruise():
    """A gap of 20 partial steps, then the base brakes from 0.4 m/s to rest in 1 s, measured
    (stated 2.5 mm, as a braking partial step of the held-out lturn_s4404 said while it erred
    0.1-0.5 mm: the brake's velocity changes are no larger than that noise). The prior's
    acceleration comes from the velocity changes around each step, noise included, so the
    brake loosens it. The window still costs something here: the gap's length errs by 15 mm
    (5.5 mm with the prior on the gap's edges only, ``motion_prior_window`` 0), as the
    smoothing spreads part of the brake into the unmeasured steps before it. With the
    steps' stated noise taken out of the fit (tried first), the held-out L's brake read as
    a cruise and its smoothed end went from 116 to 196 mm short."""
    rng = np.random.default_rng(24)
    speeds = np.concatenate([np.full(80, 0.4), np.linspace(0.4, 0.0, 11)[1:], np.zeros(5)])
    gap = set(range(60, 80))
    err = _cruise_gap_error(10, speeds, gap, {}, 0.0025, rng, 58, 80)
    assert err < 0.02


def _gap_length_error(speeds, gap: range, seed: int, partial_after: bool = False, **config) -> float:
    """Length error (m, signed) of the batch-smoothed path over ``gap`` and the steps either
    side of it, in a run over ``speeds`` (10 Hz) whose steps in ``gap`` are partial (x guessed
    0 at a 1 m sigma), the others measured along x at a stated 2.5 mm erring by 0.3 mm;
    with ``partial_after`` those after the gap are partial steps so measured (walls ahead)."""
    rng = np.random.default_rng(seed)
    truth = _wobbling_truth(speeds)
    res = _gap_results(truth, set(gap), lambda k: 0.0, rng)
    for k in range(1, len(res)):
        if k not in gap:
            st = res[k].step
            pose = st.pose.copy()
            pose[0] = se2_between(truth[k - 1], truth[k])[0] + rng.normal(0, 3e-4)
            info = np.diag([1 / 0.0025 ** 2, st.information[1, 1], st.information[2, 2]])
            status = STATUS_PARTIAL if partial_after and k >= gap.stop else st.status
            res[k] = FrameResult(k, res[k].stamp, Step(pose, info, status, 10), [])
    lo, hi = gap.start - 2, gap.stop
    return _solved_distance_error(res, truth, lo, hi, **config)


def test_a_brake_that_began_in_a_gap_is_put_at_the_gap_s_end():
    """lturn_s10604 (unseen 10600 set): a low-texture L whose end wall ended a 100-step gap
    as the base braked to rest, the brake begun 4 steps before the gap's end. The prior
    joined the cruise before the gap and the brake after it by a ramp over the whole gap,
    and the smoothed end came 0.19 m short while the raw chain's cruise guess kept it. The
    brake the measured steps after the gap show is now carried back into the gap until it
    meets the cruise speed (``motion_prior_gap_trend``). Here (0.4 m/s, rest in 1.5 s, 4
    seeds): the gap's length errs by 12-44 mm, against 215-244 mm with the ramp. Where, as
    in lturn_s10604, the brake's steps are partial steps the wall ahead measured, 73-142 mm
    against 563-628: the priors between those steps, in the same run of partial steps, are
    still held to the cruise's acceleration and bend the brake back (not fixed here). A
    cruise through the same gap, where neither side shows a change, gives the same result
    both ways, and so does a brake that began after the gap."""
    gap = range(20, 120)
    brake = np.concatenate([np.full(116, 0.4), np.linspace(0.4, 0.0, 16)[1:]])
    for partial_after in (False, True):  # True: as in lturn_s10604, the wall ahead measured the brake
        trend = np.array([_gap_length_error(brake, gap, s, partial_after) for s in range(4)])
        ramp = np.array([_gap_length_error(brake, gap, s, partial_after, motion_prior_gap_trend=False)
                         for s in range(4)])
        print("gap length errors (mm), trend / ramp:", np.round(trend * 1e3, 1), np.round(ramp * 1e3, 1))
        assert np.all(ramp < -0.2)
        assert np.all(np.abs(trend) < (0.25 * np.abs(ramp) if partial_after else 0.06))
    later = np.concatenate([np.full(125, 0.4), np.linspace(0.4, 0.0, 16)[1:], np.zeros(5)])
    for speeds in (np.full(140, 0.4), later):
        assert _gap_length_error(speeds, gap, 0) == _gap_length_error(speeds, gap, 0, motion_prior_gap_trend=False)


def test_a_speed_change_that_began_before_a_gap_goes_on_into_it():
    """The mirror case: the base brakes from 0.4 to 0.2 m/s over 1.5 s, its first 0.8 s
    measured, then a 40-step gap. Carried on from the steps before the gap until it meets
    the steady speed after it, the gap's length errs by 52-65 mm (4 seeds), against 208-224
    mm spread as a ramp."""
    gap = range(20, 60)
    speeds = np.concatenate([np.full(12, 0.4), np.linspace(0.4, 0.2, 16)[1:], np.full(80, 0.2)])
    trend = np.array([_gap_length_error(speeds, gap, s) for s in range(4)])
    ramp = np.array([_gap_length_error(speeds, gap, s, motion_prior_gap_trend=False) for s in range(4)])
    print("gap length errors (mm), trend / ramp:", np.round(trend * 1e3, 1), np.round(ramp * 1e3, 1))
    assert np.all(np.abs(trend) < 0.5 * np.abs(ramp))


def _gap_with_short_steps(short, **config) -> float:
    """Length error (m) over a gap of 60 partial steps (x guessed at the cruise, 5 cm sigma)
    in a cruise at 0.76 m/s and 10 Hz whose measured steps are stated and err at 3 mm; the
    gap steps in ``short`` measured by a few points at half their length, stated at 12 mm."""
    rng = np.random.default_rng(25)
    truth = _wobbling_truth(np.full(160, 0.76))
    gap = set(range(50, 110))
    res = _gap_results(truth, gap, lambda k: 0.076, rng)
    for k in range(1, len(res)):
        st = res[k].step
        pose, info = st.pose.copy(), st.information.copy()
        if k not in gap:
            pose[0] = se2_between(truth[k - 1], truth[k])[0] + rng.normal(0, 0.003)
            info[0, 0] = 1 / 0.003 ** 2
        else:
            info[0, 0] = 1 / 0.05 ** 2
        if k in short:
            pose[0], info[0, 0] = 0.038, 1 / 0.012 ** 2
        res[k] = FrameResult(k, res[k].stamp, Step(pose, info, st.status, 10), [])
    return _solved_distance_error(res, truth, 45, 115, **config)


def test_a_gap_is_not_pulled_down_by_two_short_steps_inside_it():
    """The held-out lturn_s6107: two of a 60-step gap's partial steps measured by 3-4 points
    at half their length (3 sigmas). With the prior's acceleration from consecutive measured
    steps (mostly their noise, ~0.4 m/s^2) the gap's speed followed them and the gap came
    out 45 cm short, where the steps themselves lose 7.6 cm; with velocity changes over 0.5 s
    (``motion_prior_gap_baseline_s``) the prior holds the cruise. Without short steps both
    keep the gap within 2 cm."""
    short = (80, 95)
    assert _gap_with_short_steps(short, motion_prior_gap_baseline_s=0.0) < -0.3
    assert abs(_gap_with_short_steps(short)) < 0.08
    assert abs(_gap_with_short_steps((80,))) < 0.03
    assert abs(_gap_with_short_steps(())) < 0.025
    assert abs(_gap_with_short_steps((), motion_prior_gap_baseline_s=0.0)) < 0.025


# ------------------------------------------------------------ keyframe links, guesses
def _results(steps, stamps=None):
    out = [FrameResult(0, 0.0, None)]
    for k, s in enumerate(steps, start=1):
        out.append(FrameResult(k, (stamps[k] if stamps is not None else 0.1 * k), s))
    return out


def _info(sx, sy, sth):
    return np.diag(1.0 / np.array([sx, sy, sth]) ** 2)


def test_a_keyframe_link_replaces_the_step_factor():
    """A step measured against a keyframe two frames back ties that frame to this one: the
    solution follows the link (the measurement), not the consecutive step derived from it."""
    from planar_vo.core.steps import KeyframeLink
    s = 0.1
    steps = [Step(np.array([s, 0.0, 0.0]), _info(1e-3, 1e-3, 1e-3), STATUS_DPP) for _ in range(4)]
    # frame 3's consecutive step is 5 mm long, but it was measured from frame 1 as 2 steps
    steps[2] = Step(np.array([s + 0.005, 0.0, 0.0]), _info(1e-3, 1e-3, 1e-3), STATUS_DPP,
                    keyframe=KeyframeLink(2, np.array([2 * s, 0.0, 0.0]), _info(5e-4, 5e-4, 1e-3)))
    for config in (BackendConfig(manhattan=False), BackendConfig(manhattan=False, keyframe_links=False)):
        g = PlanarPoseGraph(config)
        for r in _results(steps):
            g.add_frame(r)
        est = g.optimize()
        if config.keyframe_links:
            assert g.stats["factors"]["keyframe_links"] == 1
            assert est[3, 0] == pytest.approx(3 * s, abs=1e-6)          # the link's measurement
            assert est[4, 0] == pytest.approx(4 * s, abs=1e-6)
        else:
            assert est[3, 0] == pytest.approx(3 * s + 0.005, abs=1e-6)  # the chained steps
        np.testing.assert_allclose(g.raw_poses()[3], [3 * s + 0.005, 0, 0], atol=1e-9)  # raw: the chain


def _guessed_yaw_gap(link: bool, online: bool = False):
    """A base driving straight (25 mm steps at 20 Hz): ten measured steps, then twenty
    partial ones whose yaw is a guess 0.05 deg off each (stated at 0.1-1 deg), then one
    whose yaw the front-end measured from the keyframe (frame 10, heading change 0 at
    0.1 deg): its own yaw takes the guesses' +0.95 deg back at their summed sigma."""
    from planar_vo.core.steps import KeyframeYaw
    d, e = 0.025, math.radians(0.05)
    tight = _info(1e-3, 1e-3, math.radians(0.02))
    steps = [Step(np.array([d, 0.0, 0.0]), tight, STATUS_DPP) for _ in range(10)]
    sig = [math.radians(0.1 + 0.045 * i) for i in range(19)]
    steps += [Step(np.array([d, 0.0, e]), _info(2e-3, 2e-3, sg), STATUS_PARTIAL) for sg in sig]
    back = math.sqrt(math.radians(0.1) ** 2 + sum(x * x for x in sig))
    steps.append(Step(np.array([d, 0.0, -19 * e]), _info(2e-3, 2e-3, back), STATUS_PARTIAL,
                      keyframe_yaw=KeyframeYaw(20, 0.0, math.radians(0.1) ** 2) if link else None))
    steps += [Step(np.array([d, 0.0, 0.0]), tight, STATUS_DPP) for _ in range(10)]
    g = (IncrementalPlanarPoseGraph if online else PlanarPoseGraph)(BackendConfig(manhattan=False))
    for r in _results(steps, stamps=0.05 * np.arange(len(steps) + 1)):
        g.add_frame(r)
    return g, (g.estimate() if online else g.optimize())


def test_a_yaw_measured_from_the_keyframe_is_a_heading_factor_from_it():
    """A partial step whose yaw was measured from the keyframe takes back what the guessed
    yaws since it got wrong. As the step's own yaw, that correction is one step's jump of
    -0.95 deg, which the motion prior's turn-rate smoothness refuses: the graph keeps the
    guesses' heading error. As a heading factor from the keyframe, the graph puts the
    heading right where it was measured and spreads the correction over the guesses."""
    g_off, est_off = _guessed_yaw_gap(link=False)
    g_on, est_on = _guessed_yaw_gap(link=True)
    assert g_on.stats["factors"]["keyframe_yaw_links"] == 1
    assert abs(math.degrees(est_on[30, 2])) < 0.15
    assert abs(math.degrees(est_on[-1, 2])) < 0.15
    assert abs(math.degrees(est_off[30, 2])) > 0.5
    np.testing.assert_allclose(g_on.raw_poses(), g_off.raw_poses(), atol=1e-12)  # raw: the chain either way
    _, est_online = _guessed_yaw_gap(link=True, online=True)  # iSAM2 builds the same factors
    assert abs(math.degrees(est_online[-1, 2])) < 0.15


def test_a_keyframe_yaw_outside_the_graph_is_refused():
    from planar_vo.core.steps import KeyframeYaw
    steps = [Step(np.array([0.1, 0.0, 0.0]), _info(1e-3, 1e-3, 1e-3), STATUS_PARTIAL,
                  keyframe_yaw=KeyframeYaw(3, 0.0, 1e-4))]
    g = PlanarPoseGraph(BackendConfig())
    g.add_frame(_results(steps)[0])
    with pytest.raises(ValueError, match="keyframe_yaw lag 3"):
        g.add_frame(_results(steps)[1])


def test_a_keyframe_link_outside_the_graph_is_refused():
    from planar_vo.core.steps import KeyframeLink
    steps = [Step(np.array([0.1, 0.0, 0.0]), _info(1e-3, 1e-3, 1e-3), STATUS_DPP,
                  keyframe=KeyframeLink(3, np.zeros(3), np.eye(3)))]
    g = PlanarPoseGraph(BackendConfig())
    g.add_frame(_results(steps)[0])
    with pytest.raises(ValueError, match="keyframe lag 3"):
        g.add_frame(_results(steps)[1])


def test_the_motion_prior_weighs_the_front_ends_guess_as_one_error_per_gap():
    """Across a gap of partial steps (yaw measured, translation guessed at the velocity
    before it) the robot slowed from 40 to 20 mm a step. Each guess states its own error
    honestly: the k-th copy is 2k mm off and says hypot(1, 2k) mm. But the errors are
    alike, all of one sign, and ten steps each trusted as independent drag the gap towards
    the old speed next to the motion prior (``motion_prior_guess: keep``, the default).
    Weighted as one error shared by the gap (``correlated``) the guess pulls far less; left out
    (``replace``), the gap follows the measured speeds on both sides. Measured: end point
    67 mm off kept, 40 mm correlated, 10 mm replaced; the chain 110 mm."""
    n, gap = 40, range(15, 25)
    truth = [0.04 if k < 15 else (0.02 if k >= 25 else 0.04 - 0.002 * (k - 14)) for k in range(1, n)]
    steps = []
    for k, d in enumerate(truth, start=1):
        if k in gap:
            copies = k - gap.start + 1
            s = math.hypot(1e-3, 2e-3 * copies)
            info = _info(s, s, 1e-4)
            guess = _info(s, s, 1e3)  # the translation is all guess, the yaw measured
            steps.append(Step(np.array([0.04, 0.0, 0.0]), info, STATUS_PARTIAL, guess_information=guess,
                              guess_copies=copies))
        else:
            steps.append(Step(np.array([d, 0.0, 0.0]), _info(1e-3, 1e-3, 1e-4), STATUS_DPP))
    end = sum(truth)
    errs = {}
    for mode in ("keep", "correlated", "replace"):
        g = PlanarPoseGraph(BackendConfig(manhattan=False, motion_prior_guess=mode))
        for r in _results(steps):
            g.add_frame(r)
        errs[mode] = abs(g.optimize()[-1, 0] - end)
    raw_err = abs(sum(s.pose[0] for s in steps) - end)
    assert raw_err > 0.1                       # the guess alone: 10 steps 11 mm too long on average
    assert errs["keep"] > 0.5 * raw_err        # ten independent guesses outweigh the prior
    assert errs["correlated"] < 0.7 * errs["keep"]
    assert errs["replace"] < 0.15 * raw_err    # the prior alone bridges the change of speed


def test_a_partial_step_whose_translation_was_measured_gets_no_motion_prior():
    """Partial steps resected against far corners (``Step.translation_measured``) carry a
    measured translation, not the guess: the motion prior, which ties the velocity across
    guessed steps, leaves them alone (on two tuning halls it moved the smoothed end 0.2-0.5 %
    of the path while the raw chain held). The same steps unmarked get the prior."""
    rng = np.random.default_rng(23)
    speeds = np.concatenate([np.full(30, 0.5), np.linspace(0.5, 0.0, 10), np.linspace(0.0, 0.5, 10), np.full(30, 0.5)])
    truth = _wobbling_truth(speeds)
    gap = set(range(31, 51))
    priors = {}
    for marked in (True, False):
        res = _gap_results(truth, gap, lambda k: se2_between(truth[k - 1], truth[k])[0], rng)
        for k in gap:
            st = res[k].step
            info = st.information.copy()
            info[0, 0] = 1.0 / 0.003 ** 2  # measured to 3 mm
            res[k] = FrameResult(k, res[k].stamp, Step(st.pose, info, st.status, 0, translation_measured=marked), [])
        g = PlanarPoseGraph(BackendConfig(manhattan=False))
        for r in res:
            g.add_frame(r)
        est = g.optimize()
        priors[marked] = g.stats["factors"].get("motion_prior", 0)
        if marked:  # the measured gap is the chain: no prior bends it
            d = np.linalg.norm(est[50, :2] - est[30, :2]) - np.linalg.norm(truth[50, :2] - truth[30, :2])
            assert abs(float(d)) < 0.02
    assert priors[True] == 0 and priors[False] > 10
