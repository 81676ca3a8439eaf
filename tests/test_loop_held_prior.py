"""The loop closer's defences against look-alike places, against ground truth:

* the verification prior with the headings held by the Manhattan frames
  (``loops.prior_heading: manhattan``, :class:`planar_vo.loops._HeldChain`), on simulated
  rings: consistent (errors normalised by its covariance have a mean chi-square of 3 dof)
  and tight enough to reject a look-alike a wall-texture period (5.12 m) away that the
  chain's prior let through;
* guessed steps at their own sigmas (``loops.guessed_sigma_scale``): a rendered look-alike
  pair 10.24 m apart (the renderer's texture period) that verification accepted with every
  step's sigma scaled by 3 is rejected, and a true revisit is still accepted;
* the check against the latest nearby closure (``loops.consistency_path_m``)."""
import math

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from planar_vo.core.geometry import se2_between, se2_compose, wrap_angle  # noqa: E402
from planar_vo.config import LoopConfig  # noqa: E402
from planar_vo.frontend.config import PlaceConfig  # noqa: E402
from planar_vo.frontend.places import prior_distance, verify_closure  # noqa: E402
from planar_vo.loops import _Chain, _HeldChain, step_prior_covariance  # noqa: E402

SCALE = 3.0          # loops.odometry_sigma_scale
GATE = 16.27         # places.prior_gate_chi2
# per 4 cm step; the yaw sigma is ~10x the tuning rings' (0.022 deg), so that the heading
# dominates the chain's width, as it does on longer loops
STEP_SIGMA = np.array([0.004, 0.002, math.radians(0.25)])
LINK_SIGMA = math.radians(0.3)


def _ring_steps(lap_m: float = 40.0, laps: float = 1.5, step_m: float = 0.04):
    """True steps round a 2:1 rectangle of ``lap_m`` starting in the middle of a long side (as
    the building ring), 90-degree left turns in place over 9 steps: ``[(step (3,), keyframe
    after it)]``, a keyframe every 12 steps of travel (0.48 m) and after each turn."""
    a, b = lap_m / 3.0, lap_m / 6.0
    out, total = [], 0.0
    for side in [a / 2, b, a, b, a, b, a, b]:
        for k in range(int(round(side / step_m))):
            if total >= laps * lap_m - 1e-9:
                return out
            out.append((np.array([step_m, 0.0, 0.0]), (k + 1) % 12 == 0))
            total += step_m
        out += [(np.array([0.0, 0.0, math.pi / 18]), k == 8) for k in range(9)]
    return out


def _drive(seed: int, steps):
    """Noisy odometry over ``steps`` (:func:`_ring_steps`), each keyframe with a link to the
    walls (frame 0, world heading 0): ``(chain, held, true poses of the keyframes)``."""
    rng = np.random.default_rng(seed)
    cov = np.diag(STEP_SIGMA ** 2)
    ch, held = _Chain(), _HeldChain()
    truth = np.zeros(3)
    kf_truth = []

    def keyframe():   # as LoopCloser.offer and _held_update: prior-scaled steps and links
        rel, c = ch.relative_to_now()
        meas = float(wrap_angle(-truth[2] + rng.normal(0.0, LINK_SIGMA)))
        held.predict(ch.seg_pose, ch.seg_prior)
        held.observe(0, meas, SCALE * LINK_SIGMA)
        ch.new_keyframe(rel, c, ch.prior_to_now())
        held.new_keyframe([(0, meas, SCALE * LINK_SIGMA)])
        kf_truth.append(truth.copy())

    keyframe()
    for s, due in steps:
        truth = se2_compose(truth, s)
        ch.step(s + rng.normal(0.0, STEP_SIGMA), cov, step_prior_covariance(cov, "dpp", LoopConfig()))
        if due:
            keyframe()
    return ch, held, np.array(kf_truth)


def test_held_prior_is_consistent_and_rejects_a_look_alike_the_chain_let_through():
    steps = _ring_steps()
    nees, chain_sigma, held_sigma, chain_alias, held_alias = [], [], [], 0, 0
    for seed in range(12):
        ch, held, kf = _drive(seed, steps)
        now = len(kf) - 1
        a = int(np.argmin(np.hypot(*(kf[:now - 50, :2] - kf[now, :2]).T)))   # the start, a lap back
        true_rel = se2_between(kf[a], kf[now])
        P = held.P[a, :3, :3]            # the prior as the loop closer uses it (scaled)
        e = np.asarray(gtsam.Pose2.Logmap(gtsam.Pose2(*held.pose[a]).between(gtsam.Pose2(*true_rel))))
        nees.append(float(e @ np.linalg.solve(P / SCALE ** 2, e)))
        chain_sigma.append(math.sqrt(np.linalg.eigvalsh(ch.kf_cov[a][:2, :2])[-1]))
        held_sigma.append(math.sqrt(np.linalg.eigvalsh(P[:2, :2])[-1]) / SCALE)
        floor = np.diag([0.01, 0.01, math.radians(0.1)]) ** 2
        for period in (5.12, -5.12):
            # what verification finds at a look-alike a wall-texture period along the
            # corridor: the pose of the place that looks the same, the true one shifted by it
            alias = se2_compose(true_rel, [period, 0.0, 0.0])
            chain_alias += prior_distance(alias, floor, (ch.kf_rel[a], SCALE ** 2 * ch.kf_cov[a])) <= GATE
            held_alias += prior_distance(alias, floor, (held.pose[a], P)) <= GATE
        # the true revisit stays inside the held prior's gate
        assert prior_distance(true_rel, floor, (held.pose[a], P)) <= GATE
    # consistent: mean NEES of 3 dof within sampling error (12 runs: std of the mean ~0.7)
    assert 1.5 <= np.mean(nees) <= 4.5, nees
    # the chain's translation sigma at lap scale grows with heading drift times path; the held one stays at decimetres
    assert np.median(chain_sigma) > 0.6 and np.median(held_sigma) < 0.15, (chain_sigma, held_sigma)
    assert chain_alias >= 9 and held_alias == 0, (chain_alias, held_alias)   # of 24


def test_held_chain_without_links_is_the_chain():
    """No Manhattan frame seen: the held prior is the chain's, pose and covariance."""
    rng = np.random.default_rng(4)
    ch, held = _Chain(), _HeldChain()
    for k in range(40):
        if k % 8 == 0:
            rel, c = ch.relative_to_now()
            held.predict(ch.seg_pose, ch.seg_cov)
            ch.new_keyframe(rel, c)
            held.new_keyframe([])
        ch.step(np.array([0.05, 0.0, 0.02]) + rng.normal(0, 0.001, 3), np.diag([1e-4, 4e-5, 1e-5]))
    rel, c = ch.relative_to_now()
    held.predict(ch.seg_pose, ch.seg_cov)
    np.testing.assert_allclose(held.pose, rel, atol=1e-12)
    np.testing.assert_allclose(held.P, c, atol=1e-15)


# ------------------------------------------------------------- a rendered look-alike pair

W, H = 960, 540


def _keyframe(renderer, K, mount, pose, n):
    import cv2

    from planar_vo.frontend.odometry import PlanarOdometry
    from planar_vo.frontend.places import make_keyframe
    f = renderer.render(np.asarray(pose, float), index=n)
    odo = PlanarOdometry(K, mount)
    res = odo.process(f.rgbd)
    gray = cv2.cvtColor(f.rgbd.color, cv2.COLOR_BGR2GRAY)
    return make_keyframe(n, 0.0, gray, f.rgbd.depth, K, odo.levelling.R_lev_cam, res.manhattan, PlaceConfig())


def _straight_drive_prior(config, length_m: float, seed: int):
    """The verification prior over a straight drive of ``length_m`` as the loop closer builds
    it (:func:`step_prior_covariance`): the run's first step bridged at the bridge's cap
    (1 m; nothing was measured before it), then 4 cm steps, every third partial (walls give
    the yaw and the sideways motion, the speed along the corridor is a constant-velocity
    guess stated at 5 cm), the others measured (2 mm, 0.02 deg)."""
    rng = np.random.default_rng(seed)
    ch = _Chain()
    ch.new_keyframe(*ch.relative_to_now())
    n = int(round(length_m / 0.04))
    for k in range(n):
        if k == 0:
            status, sig = "bridged", np.array([1.0, 1.0, math.radians(5.0)])
        elif k % 3 == 0:
            status, sig = "partial", np.array([0.05, 0.003, math.radians(0.05)])
        else:
            status, sig = "dpp", np.array([0.002, 0.0015, math.radians(0.02)])
        cov = np.diag(sig ** 2)
        true = np.array([length_m / n, 0.0, 0.0])
        odo = true + rng.normal(0.0, [0.002, 0.0015, math.radians(0.02)])  # what the odometry really erred by
        ch.step(odo, cov, step_prior_covariance(cov, status, config))
    rel, _ = ch.relative_to_now()
    return rel[0], ch.prior_to_now()[0]


def test_look_alike_that_passed_the_old_prior_is_rejected():
    """Straight corridor whose walls, floor and ceiling repeat every 10.24 m (the renderer's
    texture period, as on tuning log straight_s127): a keyframe 10.24 m on verifies as the
    first one's place. With every step's sigma scaled by 3 (the prior before) the pair is
    accepted -- a closure 10.24 m off the ground truth; with guessed steps at their own
    sigmas it is rejected before matching (``out_of_view``: that prior puts the first
    keyframe's points behind the second). A true revisit still passes the new prior."""
    synth = pytest.importorskip("planar_vo.sim.synth")
    from planar_vo.sim.synth_scene import build_scene
    cfg = synth.SynthConfig(layout="straight", seed=31, n_frames=400).at_resolution(W, H)
    renderer = synth.SynthRenderer(cfg, scene=build_scene("straight", 16.0, 31))
    K, mount = synth.synth_intrinsics(cfg), synth.synth_mount(cfg)
    pa, pb = (1.5, 0.1, 0.0), (1.5 + 10.24, 0.1, 0.0)
    a, b = _keyframe(renderer, K, mount, pa, 0), _keyframe(renderer, K, mount, pb, 1)
    old_cfg, new_cfg = LoopConfig(guessed_sigma_scale=3.0), LoopConfig()
    truth = se2_between(np.array(pa), np.array(pb))
    old = verify_closure(a, b, mount.T_base_cam, PlaceConfig(), prior=_straight_drive_prior(old_cfg, 10.24, 1))
    assert old.accepted, old.reason
    assert math.hypot(*(old.pose - truth)[:2]) > 9.0     # a wrong closure, against the ground truth
    new = verify_closure(a, b, mount.T_base_cam, PlaceConfig(), prior=_straight_drive_prior(new_cfg, 10.24, 1))
    # the new prior puts the first keyframe's points 10 m behind the second: not even matched
    assert not new.accepted and new.reason == "out_of_view", new.reason
    # a true revisit 3 m on (sideways and turned) against the same kind of prior
    c = _keyframe(renderer, K, mount, (4.5, -0.2, math.radians(10)), 2)
    d = _keyframe(renderer, K, mount, (4.55, 0.15, math.radians(-5)), 3)
    c.gt, d.gt = np.array([4.5, -0.2, math.radians(10)]), np.array([4.55, 0.15, math.radians(-5)])
    _, lap_cov = _straight_drive_prior(new_cfg, 40.0, 2)          # a lap's worth of prior
    true_cd = se2_between(c.gt, d.gt)
    ok = verify_closure(c, d, mount.T_base_cam, PlaceConfig(), prior=(true_cd + [0.15, -0.1, 0.01], lap_cov))
    assert ok.accepted, ok.reason
    assert math.hypot(*(ok.pose - true_cd)[:2]) < 0.05 and abs(math.degrees(wrap_angle(ok.pose[2] - true_cd[2]))) < 0.5


def test_closure_must_agree_with_the_latest_nearby_closure():
    """A 20 m circle driven back to its start: the keyframe 0.5 m before the end closed the
    loop to keyframe 0 (its true pose). The next closure, now -> keyframe 1, agrees with it
    through the chain when it is the true pose, and not when it is a look-alike 5.12 m off
    (the renderer's wall period)."""
    from planar_vo.core.types import CameraIntrinsics
    from planar_vo.loops import LoopCloser
    lc = LoopCloser(CameraIntrinsics(64, 48, 50.0, 50.0, 31.5, 23.5), np.eye(4), LoopConfig(), PlaceConfig(),
                    graph=None)
    rng = np.random.default_rng(9)
    ch, cov = lc._chain, np.diag([0.003, 0.002, math.radians(0.03)]) ** 2
    truth = [np.zeros(3)]
    # first pass: keyframes 0 and 1 (0.5 m apart), then round a 20 m loop back next to keyframe 0
    path = [np.array([0.05, 0.0, 0.0])] * 10 + [np.array([0.05, 0.0, 2 * math.pi / 390])] * 390
    kf_at = {0, 10, 390}
    for k, s in enumerate(path):
        if k in kf_at:
            rel, c = ch.relative_to_now()
            ch.new_keyframe(rel, c, ch.prior_to_now())
        truth.append(se2_compose(truth[-1], s))
        ch.step(s + rng.normal(0, [0.003, 0.002, math.radians(0.03)]), cov, 9 * cov)
    T = {0: truth[0], 1: truth[10], 2: truth[390]}
    now = truth[-1]
    rel, prior = ch.relative_to_now()[0], ch.prior_to_now()
    lc._now = (rel, prior)
    floor = np.diag([0.005, 0.005, math.radians(0.05)]) ** 2
    # the closure (keyframe 0 -> keyframe 2) accepted when keyframe 2 was made
    lc._closed.append((0, 2, se2_between(T[0], T[2]), floor))
    good = se2_between(T[1], now)
    d2 = lc._consistency(1, good, floor)
    assert d2 is not None and d2 < 16.27, d2
    alias = se2_compose(good, [5.12, 0.0, 0.0])
    d2 = lc._consistency(1, alias, floor)
    assert d2 is not None and d2 > 16.27, d2
    # without a closure within consistency_path_m there is nothing to compare with
    lc.config = LoopConfig(consistency_path_m=0.0)
    assert lc._consistency(1, alias, floor) is None
