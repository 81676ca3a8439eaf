"""Minimal planar solvers against simulated ground truth (conventions of planar_vo.core.geometry)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.frontend.solvers import (
    PlanarMotion,
    essential_from_planar,
    heading_of_direction,
    homography_2pt_batch,
    manhattan_yaw_candidates,
    relpose_planar_dirpoint_1pt,
    relpose_upright_planar_homography_2pt,
    yaw_from_manhattan_headings,
)
from planar_vo.sim.problems import make_planar_problem
from planar_vo.core.geometry import levelled_motion_to_pose, rot_y, wrap_angle


def _closest(sols: list[PlanarMotion], yaw: float, t_dir: np.ndarray) -> tuple[float, float]:
    """(yaw error, t-direction error) of the solution closest to the truth."""
    errs = [(abs(float(wrap_angle(s.yaw - yaw))), float(np.linalg.norm(s.t - t_dir))) for s in sols]
    return min(errs, key=lambda e: e[0] + e[1])


@pytest.mark.parametrize("motion", ["forward", "sideways"])
def test_generator_matches_the_convention(motion):
    rng = np.random.default_rng(1)
    p = make_planar_problem(rng, 300, motion=motion)
    X2 = p.X1 @ p.R.T + p.t
    np.testing.assert_allclose(p.x2, X2[:, :2] / X2[:, 2:], atol=1e-12)
    np.testing.assert_allclose(p.P1, p.X1, atol=1e-12)
    assert p.t[1] == 0.0
    assert np.all(p.X1[:, 2] > 0) and np.all(X2[:, 2] > 0)
    # half on the floor 0.2 below the camera (y down), half strictly above it
    assert np.sum(np.isclose(p.X1[:, 1], 0.2)) == 150
    assert abs(p.X1[:, 2].mean() - 1.0) < 0.05
    # the levelled motion is the robot's SE(2) step: forward moves +x, sideways (camera +x) moves right (-y)
    pose = levelled_motion_to_pose(p.yaw, p.t)
    assert pose[2] == pytest.approx(p.yaw)
    if motion == "forward":
        assert pose[0] == pytest.approx(0.15) and pose[1] == pytest.approx(0.0, abs=1e-12)
    else:
        assert pose[1] == pytest.approx(-0.15) and pose[0] == pytest.approx(0.0, abs=1e-12)


def test_essential_matrix_holds_on_noise_free_data():
    p = make_planar_problem(np.random.default_rng(2), 100)
    E = essential_from_planar(p.yaw, p.t)
    h1 = np.column_stack([p.x1, np.ones(100)])
    h2 = np.column_stack([p.x2, np.ones(100)])
    assert np.abs(np.einsum("ni,ij,nj->n", h2, E, h1)).max() < 1e-14


@pytest.mark.parametrize("motion", ["forward", "sideways"])
def test_2pt_has_the_true_motion_among_its_solutions(motion):
    rng = np.random.default_rng(3 if motion == "forward" else 4)
    worst = 0.0
    for _ in range(20):
        p = make_planar_problem(rng, 40, motion=motion)
        i, j = rng.choice(40, 2, replace=False)
        sols = relpose_upright_planar_homography_2pt(p.x1[[i, j]], p.x2[[i, j]])
        assert 1 <= len(sols) <= 4
        ey, et = _closest(sols, p.yaw, p.t_dir)
        worst = max(worst, ey, et)
        for s in sols:
            assert abs(np.linalg.norm(s.t) - 1.0) < 1e-12 and s.t[1] == 0.0
            assert np.all(np.isfinite(s.t))
    assert worst < 1e-9


def test_2pt_sign_convention_and_virtual_plane():
    """Our H = R + t n^T / d: with d > 0 the first solution of the true root carries +t (eq. 17 sign)."""
    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(40):
        p = make_planar_problem(rng, 40, motion="forward" if checked % 2 else "sideways")
        i, j = rng.choice(40, 2, replace=False)
        Xa, Xb = p.X1[i], p.X1[j]
        # true virtual vertical plane through both points: horizontal normal, n . X = d > 0
        h = np.array([Xa[2] - Xb[2], 0.0, -(Xa[0] - Xb[0])])
        n = h / np.linalg.norm(h)
        d = float(n @ Xa)
        if d < 0:
            n, d = -n, -d
        if min(abs(n[0]), abs(n[2])) < 0.1 or d < 0.05:
            continue  # eq. 15/17 divide by n_x and n_z
        checked += 1
        H = rot_y(p.yaw) + np.outer(p.t, n) / d
        # both points obey p2 ~ H p1 with the scale fixed by the middle row
        for k in (i, j):
            q = H @ np.array([p.x1[k, 0], p.x1[k, 1], 1.0])
            np.testing.assert_allclose(q[:2] / q[2], p.x2[k], atol=1e-12)
        # eq. 10 as printed in the paper, solved independently of the module
        A = np.zeros((4, 4))
        rhs = np.zeros(4)
        for r, k in enumerate((i, j)):
            (x1, y1), (x2, y2) = p.x1[k], p.x2[k]
            A[2 * r] = [x1 * y2, y2, 0, 0]
            A[2 * r + 1] = [0, 0, x1 * y2, y2]
            rhs[2 * r], rhs[2 * r + 1] = x2 * y1, y1
        h1, h2, h3, h4 = np.linalg.solve(A, rhs)
        np.testing.assert_allclose([h1, h2, h3, h4], [H[0, 0], H[0, 2], H[2, 0], H[2, 2]], atol=1e-9)
        c = math.cos(p.yaw)
        paper_t = d * np.array([(c - h1) / n[0], 0.0, (c - h4) / n[2]])   # eq. 17 literally
        ours_t = d * np.array([(h1 - c) / n[0], 0.0, (h4 - c) / n[2]])
        np.testing.assert_allclose(ours_t, p.t, atol=1e-8)
        np.testing.assert_allclose(paper_t, -p.t, atol=1e-8)
        # the solver: the d > 0 solution of the true yaw root has +t and the true plane
        sols = relpose_upright_planar_homography_2pt(p.x1[[i, j]], p.x2[[i, j]])
        s = next(s for s in sols if abs(s.yaw - p.yaw) < 1e-9 and s.n @ p.X1[i] > 0)
        np.testing.assert_allclose(s.t, p.t_dir, atol=1e-9)
        np.testing.assert_allclose(s.n, n, atol=1e-9)
        assert s.t_over_d == pytest.approx(np.linalg.norm(p.t) / d, rel=1e-9)
    assert checked >= 10


def test_2pt_degenerate_inputs_give_no_solution_and_no_exception():
    p = make_planar_problem(np.random.default_rng(6), 10)
    x1, x2 = p.x1[:2].copy(), p.x2[:2].copy()
    same_x = x1.copy()
    same_x[1, 0] = same_x[0, 0]                      # vertically aligned in view 1
    assert relpose_upright_planar_homography_2pt(same_x, x2) == []
    horizon = x2.copy()
    horizon[0, 1] = 0.0                              # on the horizon in view 2
    assert relpose_upright_planar_homography_2pt(x1, horizon) == []
    nan = x1.copy()
    nan[0, 0] = np.nan
    assert relpose_upright_planar_homography_2pt(nan, x2) == []
    assert relpose_upright_planar_homography_2pt(x1[:1], x2[:1]) == []   # too few points
    yaw, t, n, tod, ok = homography_2pt_batch(np.vstack([x1[:1], nan[:1]]), np.vstack([same_x[1:], x1[1:]]),
                                              np.vstack([x2[:1], x2[:1]]), np.vstack([x2[1:], x2[1:]]))
    assert not ok.any() and np.isfinite(yaw).all() and np.isfinite(t).all() and np.isfinite(n).all()


def test_2pt_zero_translation_is_flagged_with_the_right_yaw():
    rng = np.random.default_rng(7)
    yaw = math.radians(8.0)
    X1 = np.column_stack([rng.uniform(-0.4, 0.4, 2), rng.uniform(-0.3, 0.3, 2), rng.uniform(0.5, 1.5, 2)])
    X2 = X1 @ rot_y(yaw).T
    sols = relpose_upright_planar_homography_2pt(X1[:, :2] / X1[:, 2:], X2[:, :2] / X2[:, 2:])
    assert len(sols) >= 1
    assert all(s.pure_rotation and np.all(s.t == 0.0) for s in sols)
    assert min(abs(s.yaw - yaw) for s in sols) < 1e-7


def test_manhattan_heading_gives_the_motion_yaw():
    rng = np.random.default_rng(8)
    for _ in range(20):
        p = make_planar_problem(rng, 20, yaw_range_deg=40.0)
        # every heading of the Manhattan frame (wall normal + k * 90 deg) gives the same yaw
        k1, k2 = rng.integers(0, 4, 2)
        h1 = p.wall_heading1 + k1 * math.pi / 2
        h2 = p.wall_heading2 + k2 * math.pi / 2
        assert yaw_from_manhattan_headings(h1, h2, prior_yaw=0.0) == pytest.approx(p.yaw, abs=1e-12)
        cands = manhattan_yaw_candidates(h1, h2)
        assert cands.shape == (4,) and np.min(np.abs(wrap_angle(cands - p.yaw))) < 1e-12
        # a prior near yaw + 90 deg selects that candidate (the ambiguity is real)
        other = yaw_from_manhattan_headings(h1, h2, prior_yaw=p.yaw + math.pi / 2 - 0.3)
        assert float(wrap_angle(other - p.yaw - math.pi / 2)) == pytest.approx(0.0, abs=1e-12)
    # heading sign: a direction to the left of forward (-x in lev) has positive heading
    assert heading_of_direction([-1.0, 0.0, 1.0]) == pytest.approx(math.pi / 4)


@pytest.mark.parametrize("motion", ["forward", "sideways"])
def test_dirpoint_recovers_the_metric_translation(motion):
    rng = np.random.default_rng(9)
    for _ in range(10):
        p = make_planar_problem(rng, 20, motion=motion)
        yaw = yaw_from_manhattan_headings(p.wall_heading1, p.wall_heading2)
        k = int(rng.integers(0, 20))
        sols = relpose_planar_dirpoint_1pt(yaw, p.P1[k], p.P2[k])
        assert len(sols) == 1
        assert abs(sols[0].yaw - p.yaw) < 1e-9
        np.testing.assert_allclose(sols[0].t, p.t, atol=1e-9)
    assert relpose_planar_dirpoint_1pt(0.1, [np.nan, 0, 1], [0, 0, 1]) == []
    assert relpose_planar_dirpoint_1pt(0.1, [0, 0], [0, 0, 1]) == []


def test_generator_tilt_modes_and_outliers():
    rng = np.random.default_rng(10)
    shared = make_planar_problem(rng, 50, tilt_error=(0.01, 0.01), tilt_mode="shared")
    assert np.array_equal(shared.tilt1, shared.tilt2) and not np.allclose(shared.tilt1, np.eye(3))
    indep = make_planar_problem(rng, 50, tilt_error=(0.01, 0.01), tilt_mode="independent")
    assert not np.allclose(indep.tilt1, indep.tilt2)
    out = make_planar_problem(rng, 50, outlier_ratio=0.3)
    assert (~out.inliers).sum() == 15
    with pytest.raises(ValueError, match="motion"):
        make_planar_problem(rng, 10, motion="diagonal")
