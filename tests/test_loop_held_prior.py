"""The loop closer's verification prior with the headings held by the Manhattan frames
(``loops.prior_heading: manhattan``, :class:`planar_vo.loops._HeldChain`) against the
odometry chain alone, on simulated rings with known ground truth: the held prior is
consistent (its errors normalised by its covariance are chi-square with 3 dof) and tight
enough to reject a look-alike place 10.24 m away (the renderer's texture period) that the
chain's prior let through; a rendered look-alike pair that verification accepted with the
chain's prior is rejected with the held one, and a true revisit is still accepted."""
import math

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from planar_vo.core.geometry import se2_between, se2_compose, wrap_angle  # noqa: E402
from planar_vo.frontend.places import prior_distance  # noqa: E402
from planar_vo.loops import _Chain, _HeldChain  # noqa: E402

SCALE = 3.0          # loops.odometry_sigma_scale
GATE = 16.27         # places.prior_gate_chi2
STEP_SIGMA = np.array([0.004, 0.002, math.radians(0.25)])   # per 4 cm step: the chain sigma of the tuning rings
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

    def keyframe():
        rel, c = ch.relative_to_now()
        meas = float(wrap_angle(-truth[2] + rng.normal(0.0, LINK_SIGMA)))
        held.predict(ch.seg_pose, ch.seg_cov)
        held.observe(0, meas, LINK_SIGMA)
        ch.new_keyframe(rel, c)
        held.new_keyframe([(0, meas, LINK_SIGMA)])
        kf_truth.append(truth.copy())

    keyframe()
    for s, due in steps:
        truth = se2_compose(truth, s)
        ch.step(s + rng.normal(0.0, STEP_SIGMA), cov)
        if due:
            keyframe()
    return ch, held, np.array(kf_truth)


def test_held_prior_is_consistent_and_rejects_a_look_alike_the_chain_let_through():
    steps = _ring_steps()
    nees, chain_sigma, held_sigma, chain_alias, held_alias = [], [], [], 0, 0
    for seed in range(20):
        ch, held, kf = _drive(seed, steps)
        now = len(kf) - 1
        a = int(np.argmin(np.hypot(*(kf[:now - 50, :2] - kf[now, :2]).T)))   # the start, a lap back
        true_rel = se2_between(kf[a], kf[now])
        P = held.P[a, :3, :3]
        e = np.asarray(gtsam.Pose2.Logmap(gtsam.Pose2(*held.pose[a]).between(gtsam.Pose2(*true_rel))))
        nees.append(float(e @ np.linalg.solve(P, e)))
        chain_sigma.append(math.sqrt(np.linalg.eigvalsh(ch.kf_cov[a][:2, :2])[-1]))
        held_sigma.append(math.sqrt(np.linalg.eigvalsh(P[:2, :2])[-1]))
        # what verification finds at a look-alike 10.24 m on along the corridor: the identity
        # of the place that looks the same, i.e. the true pose shifted by the period
        alias = se2_compose(true_rel, [-10.24, 0.0, 0.0])
        floor = np.diag([0.01, 0.01, math.radians(0.1)]) ** 2
        chain_alias += prior_distance(alias, floor, (ch.kf_rel[a], SCALE ** 2 * ch.kf_cov[a])) <= GATE
        held_alias += prior_distance(alias, floor, (held.pose[a], SCALE ** 2 * P)) <= GATE
        # the true revisit stays inside the held prior's gate
        assert prior_distance(true_rel, floor, (held.pose[a], SCALE ** 2 * P)) <= GATE
    # consistent: mean NEES of 3 dof within sampling error (20 runs: std of the mean ~0.55)
    assert 1.5 <= np.mean(nees) <= 4.5, nees
    # the chain's translation sigma at lap scale is metres (heading drift times path), the held one decimetres
    assert np.median(chain_sigma) > 1.0 and np.median(held_sigma) < 0.15, (chain_sigma, held_sigma)
    assert chain_alias >= 15 and held_alias == 0, (chain_alias, held_alias)


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
