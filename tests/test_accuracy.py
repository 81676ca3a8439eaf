"""Accuracy fixes found on whole-system synthetic runs: walls with doors, iSAM2 conditioning."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.core import geometry as g
from planar_vo.frontend.planes import PlaneDetector
from planar_vo.core.types import CameraIntrinsics

K = CameraIntrinsics(960, 540, 540.7, 540.7, 479.5, 269.5)


def _corridor_with_door(yaw: float, rng, door=(2.0, 3.6), proud=0.012, left=1.0, right=1.1, h=0.8):
    """Depth (H, W) float32 of a corridor (heading ``yaw`` in lev 2-D) whose left wall carries
    a door ``proud`` metres proud of it between ``door`` metres along the axis, seen by a
    camera pitched 10 deg down and rolled 2 deg; Kinect-like noise, whole millimetres."""
    pitch, roll = math.radians(10.0), math.radians(2.0)
    R = g.levelling_rotation(pitch, roll)
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    r = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3) @ R.T
    c, s = math.cos(yaw), math.sin(yaw)
    axis, lft = np.array([-s, 0.0, c]), np.array([-c, 0.0, -s])  # lev directions
    planes = [(np.array([0.0, 1.0, 0.0]), h, None), (lft, left, None), (-lft, right, None),
              (axis, 9.0, None), (lft, left - proud, door)]
    best = np.full(len(r), np.inf)
    for n, d, span in planes:
        den = r @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(den > 1e-9, d / den, np.inf)
        if span is not None:  # bounded along the corridor axis
            along = (r @ axis) * np.where(np.isfinite(t), t, 0.0)
            t = np.where((along >= span[0]) & (along <= span[1]), t, np.inf)
        best = np.minimum(best, t)
    # Rays are levelled camera rays with camera z = 1, so t is the optical-axis depth.
    z = np.where(np.isfinite(best), best, 0.0)
    z = z + rng.standard_normal(z.shape) * (0.0015 + 0.0015 * z ** 2)
    z = np.round(z * 1000.0) / 1000.0
    z[(z > 4.5) | (z < 0.5)] = 0.0
    return z.reshape(K.height, K.width).astype(np.float32), R


@pytest.mark.parametrize("yaw_deg", [0.0, 6.0, -8.0])
def test_wall_heading_ignores_a_door_proud_of_it(yaw_deg):
    """A door 1.2 cm proud of a wall is a second, parallel layer inside the plane band; a
    single fit across both tilted the wall by 0.2-0.5 deg. The refits keep the dominant layer."""
    rng = np.random.default_rng(11)
    yaw = math.radians(yaw_deg)
    depth, R = _corridor_with_door(yaw, rng)
    det = PlaneDetector(K, R_lev_cam=R).detect(depth)
    side = [w for w in det.walls if w.support > 0.05 and abs(w.offset - 1.0) < 0.05]
    assert side, [(w.offset, w.support) for w in det.walls]
    err = math.degrees(float(g.wrap_quarter(side[0].yaw - yaw)))
    assert abs(err) < 0.05, err  # a single fit across both layers: 0.24-0.44 deg here


def _side_wall_error(depth, R, yaw, layer_step):
    from planar_vo.frontend.config import PlaneConfig
    det = PlaneDetector(K, PlaneConfig(layer_step=layer_step), R_lev_cam=R).detect(depth)
    side = [w for w in det.walls if w.support > 0.05 and abs(w.offset - 1.0) < 0.05]
    assert side, [(w.offset, w.support) for w in det.walls]
    return math.degrees(float(g.wrap_quarter(side[0].yaw - yaw))), side[0]


@pytest.mark.parametrize("door, proud, yaw_deg", [((0.5, 1.4), 0.010, -7.0), ((1.0, 1.9), 0.004, 0.0),
                                                  ((2.0, 3.6), 0.004, 0.0), ((0.8, 2.6), 0.004, 0.0)])
def test_a_door_holding_one_section_of_the_wall_is_fitted_as_a_second_layer(door, proud, yaw_deg):
    """A door 4-10 mm proud, filling one contiguous section of the wall's extent, leaves band
    medians nearly on one line with the wall's own: the dominant-layer test keeps both and
    the single fit tilts by 0.08-0.19 deg (measured here). The fit with the section's offset
    (PlaneConfig.layer_step) takes the tilt from within the two layers."""
    rng = np.random.default_rng(11)
    yaw = math.radians(yaw_deg)
    depth, R = _corridor_with_door(yaw, rng, door=door, proud=proud)
    single, _ = _side_wall_error(depth, R, yaw, layer_step=False)
    layered, wall = _side_wall_error(depth, R, yaw, layer_step=True)
    assert abs(single) > 0.075, single  # the bias the second layer removes
    assert abs(layered) < 0.04, (single, layered)
    # the distance stays the single fit's over both layers (consistent from frame to frame)
    assert 1.0 - proud - 0.001 < wall.offset < 1.001, wall.offset


@pytest.mark.parametrize("seed", range(4))
def test_a_wall_without_a_second_layer_keeps_the_single_fit(seed):
    """A flat wall (no door) never takes the section offset: its fit is bit for bit the single
    plane's, so the tilt keeps the precision of the whole wall."""
    rng = np.random.default_rng(seed)
    yaw = math.radians([0.0, 5.0, -7.0, 3.0][seed])
    depth, R = _corridor_with_door(yaw, rng, proud=0.0)
    single, a = _side_wall_error(depth, R, yaw, layer_step=False)
    layered, b = _side_wall_error(depth, R, yaw, layer_step=True)
    assert single == layered and a.n_points == b.n_points
    assert abs(layered) < 0.02, layered


def test_a_wall_read_while_passing_a_door_keeps_its_heading_and_distance_from_frame_to_frame():
    """Frames 2 cm apart along a corridor past a door 10 mm proud. Wall offsets are differenced
    between frames (a wall read nearer by the door's 10 mm in one frame than in the last
    reads as a 10 mm step), so the distance must not jump as the door's share of the wall
    changes or as the second layer is taken in one frame and not the next. Measured here:
    the single fit errs by up to 0.14 deg and its distance jumps by up to 2.8 mm from one
    frame to the next; with the second layer 0.06 deg and 1.7 mm."""
    yaw = math.radians(-7.0)
    errs, offsets = [], []
    for i in range(15):
        s = 0.02 * i  # the camera has moved s along the corridor: the door is s nearer
        depth, R = _corridor_with_door(yaw, np.random.default_rng(100 + i), door=(1.0 - s, 1.9 - s), proud=0.01)
        e, wall = _side_wall_error(depth, R, yaw, layer_step=True)
        errs.append(e)
        offsets.append(wall.offset)
    jumps = np.abs(np.diff(offsets))
    assert np.max(np.abs(errs)) < 0.07, np.round(errs, 3)
    assert jumps.max() < 0.002, np.round(jumps * 1000, 2)  # mm


def test_the_ends_of_a_wall_are_not_taken_for_its_base_layer():
    """Band medians of a wall whose two ends (where it meets the next walls) read 3 mm a
    metre off: a section covering all but those ends explains them as well as a door would,
    and a held-out wall so fitted (its base layer three end bands) tilted by 0.76 deg. The
    base layer keeps at least a quarter of the wall, so the ends stay what they are."""
    from planar_vo.frontend.planes import _layer_step
    rng = np.random.default_rng(5)
    n = 12000
    u = np.sort(rng.uniform(-0.2, 0.85, n))
    w = 0.5 + 0.1 * u  # inverse depth along an oblique wall
    r = rng.normal(0.0, 2e-3, n)
    ends = (u < -0.18) | (u > 0.81)
    r[ends] += 3e-3 * w[ends]
    out = _layer_step(u, r, w, np.ones(n, bool))
    if out is not None:
        keep, sections = out
        base = keep & ~np.any(sections, axis=0)
        assert base.sum() >= 0.2 * keep.sum(), (base.sum(), keep.sum())
