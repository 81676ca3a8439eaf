"""The 6-DoF planarity check tells planar robot motion from handheld motion."""
import math

import numpy as np
import pytest

from planar_vo.frontend.planarity import out_of_plane_motion
from planar_vo.core.geometry import rot_x, rot_y, rot_z


def _points(rng, n=200):
    return np.c_[rng.uniform(-2, 2, n), rng.uniform(-1, 1.2, n), rng.uniform(1, 4.5, n)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_planar_motion_has_no_out_of_plane_part(seed):
    rng = np.random.default_rng(seed)
    P1 = _points(rng)
    R, t = rot_y(rng.uniform(-0.2, 0.2)), np.array([rng.uniform(-0.1, 0.1), 0.0, rng.uniform(-0.1, 0.1)])
    P2 = P1 @ R.T + t + rng.normal(scale=0.002, size=P1.shape)
    P2[:40] = _points(rng, 40)  # 20 % outliers
    o = out_of_plane_motion(P1, P2, seed=seed)
    assert o.tilt_deg < 0.2 and abs(o.dy_m) < 0.003
    assert 150 <= o.inliers <= 165


def test_handheld_motion_is_measured():
    rng = np.random.default_rng(4)
    P1 = _points(rng)
    R = rot_x(math.radians(3.0)) @ rot_y(0.1) @ rot_z(math.radians(-1.5))
    c = np.array([0.05, -0.04, 0.08])  # camera 4 cm up (y is down) between the views
    t = -R @ c
    P2 = P1 @ R.T + t + rng.normal(scale=0.001, size=P1.shape)
    o = out_of_plane_motion(P1, P2, seed=4)
    tilt_true = math.degrees(math.acos((R @ [0, 1, 0])[1]))
    assert o.tilt_deg == pytest.approx(tilt_true, abs=0.1)
    assert o.dy_m == pytest.approx(-0.04, abs=0.003)


def test_too_few_points_and_bad_shapes():
    assert out_of_plane_motion(np.zeros((2, 3)), np.zeros((2, 3))) is None
    with pytest.raises(ValueError, match=r"\(5, 2\)"):
        out_of_plane_motion(np.zeros((5, 2)), np.zeros((5, 2)))
