"""Manhattan rotation factor: analytic vs numerical Jacobians, native == custom, kernels."""
import math

import gtsam
import numpy as np
import pytest

from planar_vo.backend.config import BackendConfig
from planar_vo.backend.factors import M, X, manhattan_factor, manhattan_residual, manhattan_value


def _values(theta, m, kind, xy=(0.3, -1.2)):
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose2(xy[0], xy[1], theta))
    v.insert(M(0), manhattan_value(m, kind))
    return v


def _numerical_jacobians(f, v, kind, eps=1e-6):
    """Central differences of the unwhitened error through each variable's retract."""
    cols = []
    pose = v.atPose2(X(0))
    for d in range(3):
        dv = np.zeros(3)
        dv[d] = eps
        vp, vm = gtsam.Values(v), gtsam.Values(v)
        vp.update(X(0), pose.retract(dv))
        vm.update(X(0), pose.retract(-dv))
        cols.append((f.unwhitenedError(vp) - f.unwhitenedError(vm)) / (2 * eps))
    Hp = np.column_stack(cols)
    if kind == "native":
        mm = v.atPose2(M(0))
        cols = []
        for d in range(3):
            dv = np.zeros(3)
            dv[d] = eps
            vp, vm = gtsam.Values(v), gtsam.Values(v)
            vp.update(M(0), mm.retract(dv))
            vm.update(M(0), mm.retract(-dv))
            cols.append((f.unwhitenedError(vp) - f.unwhitenedError(vm)) / (2 * eps))
        Hm = np.column_stack(cols)
    else:
        r = v.atRot2(M(0))
        vp, vm = gtsam.Values(v), gtsam.Values(v)
        vp.update(M(0), r.retract(np.array([eps])))
        vm.update(M(0), r.retract(np.array([-eps])))
        Hm = ((f.unwhitenedError(vp) - f.unwhitenedError(vm)) / (2 * eps)).reshape(-1, 1)
    return Hp, Hm


@pytest.mark.parametrize("kind", ["custom", "native"])
def test_jacobians_match_central_differences(kind):
    rng = np.random.default_rng(11)
    for _ in range(20):
        theta, m = rng.uniform(-math.pi, math.pi, 2)
        measured = rng.uniform(-math.pi / 4, math.pi / 4) + rng.integers(-2, 2) * math.pi / 2
        sigma = 0.5  # unit-ish whitening keeps the comparison in residual units
        f = manhattan_factor(0, 0, measured, sigma, kind=kind, kernel="none", parameter=1.0)
        v = _values(theta, m, kind, xy=rng.normal(size=2))
        Hp, Hm = _numerical_jacobians(f, v, kind)
        A = f.linearize(v).jacobian()[0] * sigma  # whitened analytic Jacobian, un-whitened
        rot = 2 if kind == "native" else 0  # the native factor's rotation row
        assert np.allclose(A[rot, :3], Hp[rot], atol=1e-7)
        assert np.allclose(A[rot, 3:], Hm[rot], atol=1e-7)
        assert np.allclose(Hp[rot], [0.0, 0.0, -1.0], atol=1e-7)
        # residual is the wrapped angle difference, whatever the translations
        assert f.unwhitenedError(v)[rot] == pytest.approx(manhattan_residual(theta, m, measured), abs=1e-12)


def test_native_translation_rows_carry_no_information():
    f = manhattan_factor(0, 0, 0.2, 0.01, kind="native", kernel="none", parameter=1.0)
    v = _values(0.1, 0.35, "native", xy=(5.0, -7.0))
    A, b = f.linearize(v).jacobian()
    assert np.all(A[:2] == 0) and np.all(b[:2] == 0)
    # whitened rotation residual: (0.35 - 0.1 - 0.2) / 0.01
    assert -b[2] == pytest.approx(5.0, rel=1e-9)


def test_residual_wraps_across_pi():
    assert manhattan_residual(math.pi - 0.01, -math.pi + 0.02, 0.0) == pytest.approx(0.03, abs=1e-12)
    f = manhattan_factor(0, 0, 0.0, 0.1, kind="custom", kernel="none", parameter=1.0)
    v = _values(math.pi - 0.01, -math.pi + 0.02, "custom")
    assert f.unwhitenedError(v)[0] == pytest.approx(0.03, abs=1e-12)


def test_cauchy_downweights_large_residuals_more_than_huber():
    from planar_vo.backend.factors import robust_weight
    assert robust_weight("cauchy", 2.0, 60.0) < 0.01 < robust_weight("huber", 2.0, 60.0)
    assert robust_weight("huber", 2.0, 1.0) == 1.0 and robust_weight("none", 2.0, 1e6) == 1.0


def test_config_validation():
    from planar_vo.configtools import from_dict
    from planar_vo.core.errors import ConfigError
    cfg = from_dict(BackendConfig, {"robust_kernel": "huber", "gate_max_deg": 8})
    assert cfg.robust_kernel == "huber" and cfg.gate_max_deg == 8.0
    with pytest.raises(ConfigError, match="robust_kernel"):
        from_dict(BackendConfig, {"robust_kernel": "tukey"})
    with pytest.raises(ConfigError, match="gate_max_deg"):
        from_dict(BackendConfig, {"gate_max_deg": 50.0})
    with pytest.raises(ConfigError, match="gate_sigma"):
        from_dict(BackendConfig, {"gate_sigma": 3.0})


def test_constant_velocity_jacobians_match_central_differences():
    """The motion prior's analytic Jacobians (through GTSAM's Pose2 retract) against
    central differences, on random poses and unequal step durations."""
    from planar_vo.backend.factors import constant_velocity_factor, constant_velocity_residual

    rng = np.random.default_rng(12)
    eps = 1e-6
    for _ in range(20):
        poses = [np.array([*rng.normal(0, 2, 2), rng.uniform(-math.pi, math.pi)]) for _ in range(3)]
        dt1, dt2 = rng.uniform(0.03, 0.2, 2)
        f = constant_velocity_factor(2, dt1, dt2, sigma=1.0, sigma_yaw=1.0)  # whitened == unwhitened
        v = gtsam.Values()
        for i, p in enumerate(poses):
            v.insert(X(i), gtsam.Pose2(*p))
        np.testing.assert_allclose(f.unwhitenedError(v), constant_velocity_residual(*poses, dt1, dt2), atol=1e-12)
        A = f.linearize(v).jacobian()[0]
        for i in range(3):
            cols = []
            for d in range(3):
                dv = np.zeros(3)
                dv[d] = eps
                vp, vm = gtsam.Values(v), gtsam.Values(v)
                vp.update(X(i), v.atPose2(X(i)).retract(dv))
                vm.update(X(i), v.atPose2(X(i)).retract(-dv))
                cols.append((f.unwhitenedError(vp) - f.unwhitenedError(vm)) / (2 * eps))
            np.testing.assert_allclose(A[:, 3 * i:3 * i + 3], np.column_stack(cols), atol=1e-5)


def test_constant_velocity_residual_is_zero_on_an_arc():
    """Constant speed and turn rate: every step is the same in its own base_link, so the
    body-frame velocity and the turn rate do not change (a straight line is not needed)."""
    from planar_vo.backend.factors import constant_velocity_residual

    step = np.array([0.07, 0.0012, 0.034])  # an arc's chord: y = x tan(theta / 2)
    step[1] = step[0] * math.tan(step[2] / 2)
    a = np.array([1.0, -2.0, 0.4])
    b = np.array([*(a[:2] + _rot2(a[2]) @ step[:2]), a[2] + step[2]])
    c = np.array([*(b[:2] + _rot2(b[2]) @ step[:2]), b[2] + step[2]])
    np.testing.assert_allclose(constant_velocity_residual(a, b, c, 0.1, 0.1), 0.0, atol=1e-12)
    # twice the step in twice the time is the same velocity
    c2 = np.array([*(b[:2] + _rot2(b[2]) @ (2 * step[:2])), b[2] + 2 * step[2]])
    np.testing.assert_allclose(constant_velocity_residual(a, b, c2, 0.1, 0.2), 0.0, atol=1e-12)
    # a 10 mm longer step in 0.1 s is 0.1 m/s faster
    c3 = np.array([*(b[:2] + _rot2(b[2]) @ (step[:2] + [0.01, 0.0])), b[2]])
    np.testing.assert_allclose(constant_velocity_residual(a, b, c3, 0.1, 0.1), [0.1, 0.0, -step[2] / 0.1],
                               atol=1e-12)  # (c3 kept b's heading: the turn stopped)


def _rot2(t):
    return np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
