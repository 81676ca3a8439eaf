"""Synthetic planar runs through several local Manhattan frames, with known truth.

The robot drives corridor segments aligned with the axes of local Manhattan frames (e.g.
corridors at 0 and 60 deg), turning between them and switching frames at random; each
frame sees the walls of its segment's frame (and, while turning from one frame into
another, both). The steps get Gaussian noise plus a constant yaw bias per step (the
drift the Manhattan factors must remove); the observations get Gaussian noise, dropouts
and, on request, a seeded fraction of corrupted values (wrong branch or frame). Pure
numpy, seeded; used by the tests and ``planar-vo bench backend``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.backend.association import AssociationOutcome, ManhattanAssociator
from planar_vo.backend.config import BackendConfig
from planar_vo.core.steps import (STATUS_BRIDGED, STATUS_DPP, FrameResult, ManhattanObservation,
                                      Step)
from planar_vo.core.geometry import se2_between, wrap_angle, wrap_quarter


@dataclass
class SyntheticSequence:
    """A simulated run.

    ``truth``: (N, 3) float64 true ``T_odom_base``; ``results``: the N front-end frames;
    ``frame_yaws``: (J,) true world headings of the local Manhattan frames (rad);
    ``frame_of_pose``: (N,) int, the frame whose walls each pose sees (dominant);
    ``corrupted``: (frame index, observation index) pairs whose yaw was corrupted.
    """

    truth: np.ndarray
    results: list[FrameResult]
    frame_yaws: np.ndarray
    frame_of_pose: np.ndarray
    corrupted: list[tuple[int, int]] = field(default_factory=list)


def _true_path(n: int, rng: np.random.Generator, frame_yaws: np.ndarray, step_length: float,
               segment_length: tuple[float, float], switch_probability: float, turn_rate: float,
               wiggle: float):
    """(N, 3) true poses and (N, 2) int (dominant frame, secondary frame or -1)."""
    poses = np.zeros((n, 3))
    seen = np.full((n, 2), -1, dtype=int)
    j = 0
    theta = 0.0
    heading = float(frame_yaws[0])
    poses[0] = [0.0, 0.0, heading]
    seen[0, 0] = 0
    k = 1
    while k < n:
        # Next segment: maybe switch frame, then pick an axis of that frame to turn onto.
        old = j
        if len(frame_yaws) > 1 and rng.random() < switch_probability:
            j = int(rng.choice([i for i in range(len(frame_yaws)) if i != old]))
        axes = frame_yaws[j] + np.arange(4) * 0.5 * math.pi
        rel = wrap_angle(axes - heading)
        ok = np.abs(rel) <= math.radians(110)
        if j == old:
            ok &= np.abs(rel) >= math.radians(30)  # same frame: a real corner
        heading = float(heading + rng.choice(rel[ok]))
        length = rng.uniform(*segment_length)
        phase = rng.uniform(0, 2 * math.pi)
        s = 0.0
        while k < n and s < length:
            turn = math.remainder(heading - theta, 2 * math.pi)
            if abs(turn) > 1e-9:  # turning: rotate at turn_rate, creep forward
                d = 0.3 * step_length
                theta += float(np.clip(turn, -turn_rate, turn_rate))
                seen[k] = (j, old if old != j else -1)
            else:
                d = step_length
                s += d
                seen[k, 0] = j
            target = heading + wiggle * math.sin(2 * math.pi * s / 4.0 + phase)
            th = theta if abs(turn) > 1e-9 else target
            x, y = poses[k - 1, :2] + d * np.array([math.cos(th), math.sin(th)])
            poses[k] = [x, y, th]
            if abs(turn) <= 1e-9:
                theta = heading  # the wiggle is around the segment heading
            k += 1
    poses[:, 2] = wrap_angle(poses[:, 2])
    return poses, seen


def _frame_results(truth, seen, frame_yaws, rng, crng, step_sigma_xy, step_sigma_theta_deg, yaw_bias_deg,
                   obs_sigma_deg, obs_dropout, bridged_fraction, corrupt_fraction):
    """Noisy front-end frames from the (N, 3) ``truth`` and the (N, 2) frames each pose sees
    (see :func:`simulate_manhattan_sequence`); returns ``(results, corrupted)``."""
    n_frames = len(truth)
    sxy, sth = step_sigma_xy, math.radians(step_sigma_theta_deg)
    info = np.diag([1 / sxy**2, 1 / sxy**2, 1 / sth**2])
    bridged_info = np.diag([1 / 0.5**2, 1 / 0.5**2, 1 / math.radians(30.0) ** 2])
    bias = math.radians(yaw_bias_deg)
    osig = math.radians(obs_sigma_deg)

    results: list[FrameResult] = []
    corrupted: list[tuple[int, int]] = []
    prev_step = np.zeros(3)
    for k in range(n_frames):
        step = None
        if k > 0:
            true = se2_between(truth[k - 1], truth[k])
            noisy = true + np.array([rng.normal(0, sxy), rng.normal(0, sxy), rng.normal(0, sth) + bias])
            bridged = rng.random() < bridged_fraction
            if bridged:  # the front-end lost it: constant-velocity guess
                step = Step(prev_step.copy(), bridged_info.copy(), STATUS_BRIDGED, 0)
            else:
                step = Step(noisy, info.copy(), STATUS_DPP, 50)
                prev_step = noisy
        obs = []
        dropped = rng.random() < obs_dropout
        for i, j in enumerate(seen[k]):
            if j < 0:
                continue
            yaw = float(wrap_quarter(frame_yaws[j] - truth[k, 2] + rng.normal(0, osig)))
            if not dropped:
                obs.append(ManhattanObservation(yaw=yaw, sigma=osig, score=0.5 / (i + 1), track_id=int(j)))
        for i, o in enumerate(obs):
            if crng.random() < corrupt_fraction:
                e = math.radians(crng.uniform(3.0, 45.0)) * (1 if crng.random() < 0.5 else -1)
                o.yaw = float(wrap_quarter(o.yaw + e))
                o.track_id = -1
                corrupted.append((k, i))
        results.append(FrameResult(index=k, stamp=0.1 * k, step=step, manhattan=obs))
    return results, corrupted


def simulate_manhattan_sequence(
    n_frames: int = 1000,
    *,
    seed: int = 0,
    frame_yaws_deg=(0.0, 60.0),
    step_length: float = 0.1,
    segment_length: tuple[float, float] = (3.0, 10.0),
    switch_probability: float = 0.35,
    turn_rate_deg: float = 10.0,
    wiggle_deg: float = 3.0,
    step_sigma_xy: float = 0.005,
    step_sigma_theta_deg: float = 0.1,
    yaw_bias_deg: float = 0.02,
    obs_sigma_deg: float = 0.5,
    obs_dropout: float = 0.1,
    bridged_fraction: float = 0.0,
    corrupt_fraction: float = 0.0,
) -> SyntheticSequence:
    """Simulate a run of ``n_frames`` frames (see module docstring); angles in degrees.

    The path, step noise and observation noise depend only on ``seed``; the corruption
    is drawn from an independent stream, so a clean and a corrupted run share everything
    else. A corrupted observation's yaw is offset by a random 3..45 deg (either sign):
    depending on the offset it fits another frame, fits its own frame badly, or fits none.
    """
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2, got {n_frames}")
    rng = np.random.default_rng(seed)
    frame_yaws = np.radians(np.asarray(frame_yaws_deg, dtype=float))
    truth, seen = _true_path(n_frames, rng, frame_yaws, step_length, segment_length, switch_probability,
                             math.radians(turn_rate_deg), math.radians(wiggle_deg))
    crng = np.random.default_rng([seed, 1])
    results, corrupted = _frame_results(truth, seen, frame_yaws, rng, crng, step_sigma_xy, step_sigma_theta_deg,
                                        yaw_bias_deg, obs_sigma_deg, obs_dropout, bridged_fraction,
                                        corrupt_fraction)
    return SyntheticSequence(truth, results, frame_yaws, seen[:, 0].copy(), corrupted)


def _ring_path(size: tuple[float, float], laps: float, step_length: float, turn_rate: float):
    """(N, 3) poses round a ``size`` (m) rectangle, counter-clockwise from its corner at the
    origin heading +x, turning in place-ish (forward creep) at each corner, for ``laps`` laps."""
    poses = [np.zeros(3)]
    side, theta, turned = 0, 0.0, 0.0
    total = laps * 2 * (size[0] + size[1])
    travelled, s = 0.0, 0.0
    while travelled < total:
        x, y, th = poses[-1]
        if s < size[side % 2]:  # straight along the side
            d = min(step_length, size[side % 2] - s)
            s += d
            th_new = theta
        else:                   # corner: rotate towards the next side, creeping forward
            dth = min(turn_rate, 0.5 * math.pi - turned)
            turned += dth
            d = 0.0
            th_new = th + dth
            if turned >= 0.5 * math.pi - 1e-12:
                side, s, turned = side + 1, 0.0, 0.0
                theta = (side % 4) * 0.5 * math.pi
                th_new = theta
        travelled += d
        poses.append(np.array([x + d * math.cos(th), y + d * math.sin(th), float(wrap_angle(th_new))]))
    return np.array(poses)


def simulate_ring_sequence(*, seed: int = 0, size: tuple[float, float] = (12.0, 6.0), laps: float = 1.5,
                           step_length: float = 0.1, turn_rate_deg: float = 10.0, step_sigma_xy: float = 0.005,
                           step_sigma_theta_deg: float = 0.1, yaw_bias_deg: float = 0.02, obs_sigma_deg: float = 0.5,
                           obs_dropout: float = 0.1, manhattan: bool = True) -> SyntheticSequence:
    """A closed loop with drift: ``laps`` laps round a ``size`` (m) rectangle (one Manhattan
    frame at 0 deg, seen every frame unless ``manhattan`` is False), steps and observations
    with the noise of :func:`simulate_manhattan_sequence`. Revisits after the first lap are
    the places loop closures link (:func:`ring_closures`)."""
    rng = np.random.default_rng(seed)
    truth = _ring_path(size, laps, step_length, math.radians(turn_rate_deg))
    seen = np.full((len(truth), 2), -1 if not manhattan else 0, dtype=int)
    seen[:, 1] = -1
    results, _ = _frame_results(truth, seen, np.zeros(1), rng, np.random.default_rng([seed, 1]), step_sigma_xy,
                                step_sigma_theta_deg, yaw_bias_deg, obs_sigma_deg, obs_dropout, 0.0, 0.0)
    return SyntheticSequence(truth, results, np.zeros(1), seen[:, 0].copy())


def ring_closures(truth: np.ndarray, *, every: int = 10, radius: float = 0.5, min_gap: int = 100) -> list[tuple[int, int]]:
    """``(i, j)`` frame pairs, ``i < j - min_gap``, with ``i`` the frame nearest to ``j`` in
    position within ``radius`` (m), for every ``every``-th frame ``j``: the places a loop
    closure detector should link on a (N, 3) ``truth``."""
    out = []
    for j in range(min_gap + 1, len(truth), every):
        d = np.linalg.norm(truth[: j - min_gap, :2] - truth[j, :2], axis=1)
        if d.size and d.min() <= radius:
            out.append((int(np.argmin(d)), j))
    return out


def ring_closure_measurements(truth: np.ndarray, *, seed: int, sigma, n_false: int = 8, alias: int = 5,
                              alias_shift: int = 40, every: int = 10):
    """Loop-closure measurements on a ring's (N, 3) ``truth``: ``(true, false)``, lists of
    ``(i, j, pose)`` with ``pose`` the (3,) ``T_base_i_base_j`` as a verification would state it.

    True: :func:`ring_closures` pairs with Gaussian noise ``sigma`` (3,) ``(m, m, rad)``.
    False: ``n_false`` between random frames at least 50 apart, their poses 0.5-2 m and
    3-30 deg off the truth, and a run of ``alias`` consecutive true closures (from the 6th)
    attached to the place ``alias_shift`` frames further along: repeated doors, mutually
    consistent and all wrong. Seeded by ``seed``.
    """
    n = len(truth)
    sigma = np.asarray(sigma, dtype=float)
    rng = np.random.default_rng([seed, 7])
    true = [(i, j, se2_between(truth[i], truth[j]) + rng.normal(0.0, sigma))
            for i, j in ring_closures(truth, every=every)]
    false = []
    while len(false) < n_false:
        a, b = sorted(int(v) for v in rng.integers(0, n, 2))
        if b - a > 50:
            off = rng.uniform(0.5, 2.0, 2) * rng.choice([-1, 1], 2)
            dth = math.radians(rng.uniform(3.0, 30.0)) * rng.choice([-1, 1])
            false.append((a, b, se2_between(truth[a], truth[b]) + np.array([*off, dth])))
    false += [(i + alias_shift, j, p) for i, j, p in true[5:5 + alias] if i + alias_shift < j - 50]
    return true, false


def trajectory_errors(est: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Errors of (N, 3) ``est`` against (N, 3) ``truth`` (same odom, no alignment).

    ``final_yaw_deg``, ``rms_yaw_deg``: heading error at the end / RMS over all poses;
    ``endpoint_m``: final position error; ``ate_rms_m``: RMS position error.
    """
    est, truth = np.asarray(est, dtype=float), np.asarray(truth, dtype=float)
    if est.shape != truth.shape or est.ndim != 2 or est.shape[1] != 3:
        raise ValueError(f"est and truth must both be (N, 3), got {est.shape} and {truth.shape}")
    dyaw = np.degrees(np.abs(wrap_angle(est[:, 2] - truth[:, 2])))
    dpos = np.linalg.norm(est[:, :2] - truth[:, :2], axis=1)
    return {"final_yaw_deg": float(dyaw[-1]), "rms_yaw_deg": float(np.sqrt(np.mean(dyaw**2))),
            "endpoint_m": float(dpos[-1]), "ate_rms_m": float(np.sqrt(np.mean(dpos**2)))}


class WrongAssociationInjector(ManhattanAssociator):
    """A :class:`ManhattanAssociator` that hands the graph wrong associations on purpose.

    After normal association, each link is, with probability ``fraction`` (seeded), moved to
    a wrong branch (``measured +- pi/2``) or, when another frame exists, to a wrong frame.
    The filter itself stays clean, so this isolates what the graph's robust kernel does
    with wrong Manhattan factors. ``n_corrupted`` counts the links changed.
    """

    def __init__(self, config: BackendConfig, fraction: float, seed: int):
        super().__init__(config)
        self.fraction = fraction
        self.rng = np.random.default_rng(seed)
        self.n_corrupted = 0

    def observe(self, pose, observations) -> AssociationOutcome:
        out = super().observe(pose, observations)
        for link in out.links:
            if self.rng.random() >= self.fraction:
                continue
            others = [j for j in range(self.n_frames) if j != link.frame]
            if others and self.rng.random() < 0.5:
                link.frame = int(self.rng.choice(others))
            else:
                link.measured += (0.5 * math.pi) * (1 if self.rng.random() < 0.5 else -1)
            self.n_corrupted += 1
        return out
