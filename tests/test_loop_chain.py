"""The loop closer's proximity gate: the odometry chain's relative pose and covariance."""
import math

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from planar_vo.core.geometry import se2_between, se2_chain  # noqa: E402
from planar_vo.loops import _Chain, compose_covariance  # noqa: E402


def _perturbed(pose, cov, rng, n):
    """n samples of ``pose * Exp(xi)``, xi ~ N(0, cov) (gtsam's right perturbation)."""
    xi = rng.multivariate_normal(np.zeros(3), cov, size=n)
    P = gtsam.Pose2(*pose)
    out = []
    for v in xi:
        q = P.compose(gtsam.Pose2.Expmap(v))
        out.append([q.x(), q.y(), q.theta()])
    return np.array(out)


def test_compose_covariance_matches_monte_carlo():
    rng = np.random.default_rng(3)
    steps = [np.array([0.5, 0.02, 0.1]), np.array([0.4, -0.05, -0.3]), np.array([0.6, 0.0, 0.2])]
    covs = [np.diag([0.01, 0.005, 0.02]) ** 2, np.diag([0.02, 0.01, 0.01]) ** 2, np.diag([0.01, 0.01, 0.03]) ** 2]
    cov = np.zeros((3, 3))
    for s, c in zip(steps, covs):
        cov = compose_covariance(cov, s, c)
    mean = se2_chain(steps)[-1]
    n = 4000
    samples = np.zeros((n, 3))
    for i in range(n):
        acc = gtsam.Pose2()
        for s, c in zip(steps, covs):
            acc = acc.compose(gtsam.Pose2(*s).compose(gtsam.Pose2.Expmap(rng.multivariate_normal(np.zeros(3), c))))
        samples[i] = gtsam.Pose2.Logmap(gtsam.Pose2(*mean).between(acc))
    mc = np.cov(samples.T)
    # first order vs sampling: within 10 % on the diagonal (4000 samples: ~4.5 % sampling error)
    np.testing.assert_allclose(np.diag(cov), np.diag(mc), rtol=0.1)


def test_chain_relative_pose_and_covariance_per_keyframe():
    """Keyframes at steps 0 and 3; after 6 steps each keyframe's relative pose to now is the
    chain's, and its covariance the composition of the steps since it."""
    rng = np.random.default_rng(5)
    steps = [np.array([0.3, 0.01 * k, 0.05 * (-1) ** k]) for k in range(6)]
    covs = [np.diag(rng.uniform(0.005, 0.02, 3)) ** 2 for _ in steps]
    ch = _Chain()
    ch.new_keyframe(*ch.relative_to_now())  # keyframe 0 at the start
    for k, (s, c) in enumerate(zip(steps, covs)):
        ch.step(s, c)
        if k == 2:
            ch.new_keyframe(*ch.relative_to_now())  # keyframe 1 after three steps
    rel, cov = ch.relative_to_now()
    poses = se2_chain(steps)
    np.testing.assert_allclose(rel[0], se2_between(poses[0], poses[6]), atol=1e-12)
    np.testing.assert_allclose(rel[1], se2_between(poses[3], poses[6]), atol=1e-12)
    expect = np.zeros((3, 3))
    for s, c in zip(steps[3:], covs[3:]):
        expect = compose_covariance(expect, s, c)
    np.testing.assert_allclose(cov[1], expect, atol=1e-15)
    assert math.isclose(ch.path_m, sum(math.hypot(s[0], s[1]) for s in steps))
    assert np.all(np.diag(cov[0]) > np.diag(cov[1]))
