"""Local Manhattan frames: grouping, scoring, tracking through the 90-degree ambiguity."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planar_vo.core import geometry as g
from planar_vo.frontend.config import ManhattanConfig
from planar_vo.frontend.manhattan import ManhattanTracker, group_walls
from planar_vo.frontend.planes import Plane

D = math.radians


def wall(heading, support, sigma_deg=0.05, offset=1.5):
    """A vertical Plane whose normal has 2-D heading ``heading`` (rad) in lev."""
    n = np.array([-math.sin(heading), 0.0, math.cos(heading)])
    q = n / offset
    # a covariance of q giving the requested yaw sigma (isotropic in the x-z plane)
    s2 = (D(sigma_deg) * np.linalg.norm(q)) ** 2
    return Plane("wall", n, offset, support, int(support * 1e4), 0.001, np.diag([s2, 0.0, s2]), rms_rel=0.0)


def test_group_parallel_and_perpendicular_walls():
    walls = [wall(D(10.0), 0.30), wall(D(100.2), 0.20), wall(D(-80.1), 0.05),  # one frame
             wall(D(40.0), 0.10), wall(D(-50.3), 0.06),                        # a second one
             wall(D(25.0), 0.02)]                                              # clutter
    frames = group_walls(walls, ManhattanConfig(group_tol_deg=2.5))
    assert len(frames) == 3
    f0, f1, f2 = frames
    assert sorted(f0.walls) == [0, 1, 2] and f0.score == pytest.approx(0.55)
    # mean of 10.0, 10.2, 9.9 (mod 90) weighted by 1/sigma^2 (equal sigmas here)
    expect = (10.0 + 10.2 + 9.9) / 3
    assert math.degrees(f0.heading) == pytest.approx(expect, abs=1e-6)
    assert sorted(f1.walls) == [3, 4] and f1.score == pytest.approx(0.16)
    assert math.degrees(f1.heading) == pytest.approx(math.degrees(g.wrap_quarter(D(39.85))), abs=1e-6)
    assert f2.walls == [5]
    # wrapped to [-45, 45) degrees; sigma reflects the walls' scatter and is floored
    for f in frames:
        assert -math.pi / 4 <= f.heading < math.pi / 4
        assert f.sigma >= D(ManhattanConfig().min_sigma_deg) - 1e-12
    assert f0.sigma > D(0.05)  # 10.0 / 10.2 / 9.9 disagree by more than their fit sigma


def test_group_across_the_wrap():
    frames = group_walls([wall(D(44.5), 0.2, 0.4), wall(D(-44.5), 0.1, 0.4), wall(D(135.8), 0.1, 0.8)])
    assert len(frames) == 1
    # the mean lands across the +-45 deg seam: 44.5, 45.5, 45.8 mod 90, weighted by 1/sigma^2
    m = math.degrees(float(g.wrap_quarter(frames[0].heading - D(45.0))))
    assert m == pytest.approx((4 * -0.5 + 4 * 0.5 + 1 * 0.8) / 9, abs=1e-6)
    # walls that disagree beyond their sigmas are not one frame (a box 1.3 deg off)
    assert len(group_walls([wall(D(44.5), 0.2, 0.05), wall(D(135.8), 0.1, 0.05)])) == 2


def test_tracker_follows_a_turn_through_the_ambiguity():
    """The robot turns left 3 deg per frame for 40 frames: the observed heading of a fixed
    Manhattan frame decreases by 3 deg per frame and wraps from -45 to +45 deg; the track
    keeps its id, and a second local frame keeps its own."""
    trk = ManhattanTracker(ManhattanConfig())
    yaw_step = D(3.0)
    ids_a, ids_b = set(), set()
    for i in range(40):
        ha = float(g.wrap_quarter(D(20.0) - i * yaw_step))
        hb = float(g.wrap_quarter(D(-10.0) - i * yaw_step))
        frames = group_walls([wall(ha + D(90.0), 0.3), wall(hb, 0.1)])
        assert len(frames) == 2
        trk.associate(frames, yaw_prior=yaw_step)
        a = next(f for f in frames if abs(float(g.wrap_quarter(f.heading - ha))) < 1e-6)
        b = next(f for f in frames if f is not a)
        ids_a.add(a.track_id)
        ids_b.add(b.track_id)
        if i > 0:
            assert a.prev_heading is not None
            yaw = a.prev_heading - a.heading
            assert math.degrees(float(g.wrap_quarter(yaw - yaw_step))) == pytest.approx(0.0, abs=1e-6)
        trk.commit(frames, yaw_step)
    assert len(ids_a) == 1 and len(ids_b) == 1 and ids_a != ids_b


def test_tracker_carries_unseen_frames_and_prunes():
    cfg = ManhattanConfig(max_missed=3)
    trk = ManhattanTracker(cfg)
    f = group_walls([wall(D(5.0), 0.3)])
    trk.associate(f, 0.0)
    trk.commit(f, 0.0)
    tid = f[0].track_id
    sigma0 = f[0].sigma
    # two frames without walls while turning 2 deg per frame, each step's yaw 0.1 deg uncertain
    for _ in range(2):
        trk.associate([], D(2.0))
        trk.commit([], D(2.0), D(0.1) ** 2)
    f = group_walls([wall(D(1.0), 0.3)])
    trk.associate(f, D(2.0))
    assert f[0].track_id == tid
    # the reference is carried by the two steps (5 - 2 - 2 deg) and carries their variance,
    # so the direction-plus-point yaw of this step (prev_heading - heading) is the third step's
    assert f[0].prev_heading == pytest.approx(D(1.0), abs=1e-12)
    assert f[0].prev_sigma == pytest.approx(math.sqrt(sigma0 ** 2 + 2 * D(0.1) ** 2), rel=1e-9)
    assert f[0].age == 1  # not seen in the previous frame: too young for direction-plus-point
    trk.commit(f, D(2.0))
    for _ in range(4):
        trk.associate([], 0.0)
        trk.commit([], 0.0)
    assert trk.tracks == []


# --------------------------------------------------------------------- synthetic corridor
@pytest.fixture(scope="module")
def synth_frames():
    from planar_vo.sim.synth import SynthConfig, render_sequence, synth_intrinsics, synth_mount

    cfg = SynthConfig(layout="lturn", n_frames=100, seed=5)
    return synth_intrinsics(cfg), synth_mount(cfg), list(render_sequence(cfg, range(2, 100, 10)))


def test_dominant_manhattan_yaw_on_synthetic_corridor(synth_frames):
    from planar_vo.frontend.planes import PlaneDetector

    K, mount, frames = synth_frames
    pitch, roll, myaw = g.mount_angles(mount.T_base_cam[:3, :3])
    det = PlaneDetector(K, R_lev_cam=g.levelling_rotation(pitch, roll))
    errs = []
    for f in frames:
        truth = f.truth["manhattan_yaws_base"]
        mf = group_walls(det.detect(f.rgbd.depth).walls)
        if not truth:
            continue
        assert mf, f"frame {f.rgbd.index}: walls in view but no Manhattan frame"
        errs.append(abs(math.degrees(float(g.wrap_quarter(mf[0].heading + myaw - truth[0])))))
    assert len(errs) >= 8
    assert np.median(errs) < 0.3, errs
    assert max(errs) < 1.5, errs


def test_a_narrow_face_joins_a_frame_but_not_its_compass_heading():
    """A box face 2 deg off a corridor's walls, within the grouping tolerance and its
    sigmas, joins their frame; weighted in by its small sigma it pulls the frame's heading
    (what the steps difference, eq. 1) by 0.8 deg, but not the heading the back-end takes
    (``compass_heading``, from the walls at least ``min_wall_width_m`` wide:
    ``manhattan._compass``). Without such a wall the narrow faces give both."""
    walls = [wall(D(-1.0), 0.09, sigma_deg=0.5), wall(D(89.0), 0.05, sigma_deg=0.6),  # 2.7 m, 1.7 m
             wall(D(90.5), 0.066, sigma_deg=0.37)]                                     # a box face
    for w, width in zip(walls, (2.7, 1.7, 0.36)):
        w.width = width
    f = group_walls(walls, ManhattanConfig())
    assert len(f) == 1 and sorted(f[0].walls) == [0, 1, 2] and f[0].score == pytest.approx(0.206)
    assert math.degrees(f[0].compass_heading) == pytest.approx(-1.0, abs=1e-9)
    assert math.degrees(f[0].compass_sigma) == pytest.approx(1 / math.hypot(1 / 0.5, 1 / 0.6), abs=1e-9)
    assert math.degrees(f[0].heading) > -0.5      # every wall: the face pulls it by 0.5 deg and more
    everything = group_walls(walls, ManhattanConfig(min_wall_width_m=0.0))[0]
    assert everything.compass_heading == pytest.approx(f[0].heading, abs=1e-12)
    boxes = group_walls(walls[2:] + [wall(D(1.4), 0.03, sigma_deg=0.25)], ManhattanConfig())  # two faces
    expect = (0.5 / 0.37 ** 2 + 1.4 / 0.25 ** 2) / (1 / 0.37 ** 2 + 1 / 0.25 ** 2)  # weighted by 1/sigma^2
    assert len(boxes) == 1 and math.degrees(boxes[0].compass_heading) == pytest.approx(expect, abs=1e-9)
    assert boxes[0].compass_heading == boxes[0].heading


def test_heading_sigma_splits_into_image_to_image_and_common_parts():
    """A frame's sigma keeps the walls' systematic term and the floor (one heading); its
    ``sigma_fit`` is the fit noise alone, what does not cancel in a heading difference."""
    w = wall(D(5.0), 0.3, sigma_deg=0.02)
    w.systematic, w.rms_rel, w.extent = 0.3, 0.01, 0.5      # systematic 0.006 rad = 0.34 deg
    assert w.yaw_sigma_fit == pytest.approx(D(0.02), rel=1e-6)
    assert w.yaw_sigma == pytest.approx(math.hypot(D(0.02), 0.006), rel=1e-6)
    f = group_walls([w], ManhattanConfig())[0]
    assert f.sigma == pytest.approx(w.yaw_sigma, rel=1e-6)
    assert f.sigma_fit == pytest.approx(D(0.02), rel=1e-6)
    f.prev_sigma_fit = D(0.03)
    assert f.step_sigma() == pytest.approx(math.hypot(D(0.02), D(0.03)), rel=1e-9)


@pytest.fixture(scope="module")
def box_off_the_walls():
    """The start of a randomized straight corridor (seed 10102 of the sweep's scenes, mount
    pitched and rolled, medium texture) whose first box stands 2 deg off the right wall,
    0.8 m from the camera: its faces are nearly parallel and perpendicular to the walls."""
    from planar_vo.sim.synth import render_sequence, synth_intrinsics, synth_mount
    from planar_vo.sim.synth_random import randomized_config

    cfg = randomized_config(10102, "straight")
    return synth_intrinsics(cfg), synth_mount(cfg), list(render_sequence(cfg, range(16)))


def test_a_box_off_the_walls_does_not_turn_the_corridor(box_off_the_walls, monkeypatch):
    """A regression of an unseen straight corridor that ended 0.51 % off (raw 0.33 %): in
    the frames where the box's faces joined the walls' frame, the heading the back-end
    took was 0.4-1.5 deg off. From the frame's wide walls alone (``manhattan._compass``)
    every observation is within 0.1 deg of the truth."""
    from planar_vo.frontend import manhattan
    from planar_vo.frontend.config import FrontendConfig
    from planar_vo.frontend.odometry import PlanarOdometry

    K, mount, frames = box_off_the_walls

    def observation_errors():
        odo = PlanarOdometry(K, mount, FrontendConfig())
        res = [odo.process(f.rgbd) for f in frames]
        return np.array([abs(math.degrees(float(g.wrap_quarter(r.manhattan[0].yaw - f.truth["manhattan_yaws_base"][0]))))
                         for r, f in zip(res, frames) if r.manhattan])

    obs = observation_errors()
    assert len(obs) == len(frames) and obs.max() < 0.1, obs
    # the mechanism is in this log: every wall weighted in, faces included
    monkeypatch.setattr(manhattan, "_compass", lambda walls, config: walls)
    assert observation_errors().max() > 1.0
