"""python docs/bench/bound_untextured_straight.py A-B SPEC [SPEC ...]: how well could any method
know the forward distance of an untextured straight corridor from its walls alone?

An oracle, not planar-vo: for the straight layout of every seed A-B (``randomized_config``'s
path, ground truth only, nothing rendered) it is given each frame's exact heading, and each
frame's position across the corridor (what the side walls measure) with i.i.d. noise
``sigma``. The base is wheeled: each step runs along its mean heading, off it sideways by a
slip of sigma ``floor + slip x step length + lever x |step's heading change|`` (all 0: exact
non-holonomy, as the renderer drives). The forward speed comes from the back-end's motion
prior (velocity change per step at 0.5 m/s^2, ``backend.motion_prior_accel``). Least squares
over the whole log gives every step's length; printed: the forward end-point error in % of
the path, median / p90 / worst over the logs.

SPEC is ``sigma_mm:slip:floor_mm:lever_m``. What the walls measure of the step is
``length x sin(psi)`` (psi the heading off the corridor's axis), so the forward distance is
observable only through the heading's weave; a corridor driven straight would give none.
Results: docs/bench/changes_session56.md section 2.
"""
import sys

import numpy as np

from planar_vo.backend.config import BackendConfig
from planar_vo.core.geometry import wrap_angle
from planar_vo.sim.synth import synth_trajectory
from planar_vo.sim.synth_random import randomized_config

ACCEL = BackendConfig().motion_prior_accel  # m/s^2: the back-end's motion prior, as planar-vo run uses it


def step_lengths(psi_mid, z, sigma, accel_dt2, slip_sigma):
    """Least-squares step lengths (n,) from across positions ``z`` (n+1,) at ``sigma`` (m), the
    steps' mean headings off the axis ``psi_mid`` (n,), a velocity-change prior of sigma
    ``accel_dt2`` per step and per-step sideways slips of sigma ``slip_sigma`` (n,), or None."""
    n = len(psi_mid)
    slips = slip_sigma is not None
    m = 1 + n + (n if slips else 0)  # unknowns: first across position, step lengths, slips
    A = np.zeros((2 * n + (n if slips else 0), m))
    rhs = np.zeros(len(A))
    L = np.tril(np.ones((n + 1, n)), -1)  # across_k = across_0 + sum_{j<k} (s_j sin psi_j + e_j cos psi_j)
    A[:n + 1, 0] = 1.0 / sigma
    A[:n + 1, 1:n + 1] = L * np.sin(psi_mid) / sigma
    if slips:
        A[:n + 1, n + 1:] = L * np.cos(psi_mid) / sigma
        A[2 * n:, n + 1:] = np.diag(1.0 / slip_sigma)
    rhs[:n + 1] = z / sigma
    k = np.arange(n - 1)
    A[n + 1 + k, 1 + k], A[n + 1 + k, 2 + k] = -1.0 / accel_dt2, 1.0 / accel_dt2
    return np.linalg.lstsq(A, rhs, rcond=None)[0][1:n + 1]


def forward_error_pct(seed: int, sigma: float, slip: float, floor: float, lever: float) -> tuple[float, float, int]:
    """(forward end-point error % of path, rms heading off the axis deg, frames) of one log."""
    stamps, P = synth_trajectory(randomized_config(seed, "straight"))
    d = np.diff(P[:, :2], axis=0)
    s_true = np.hypot(d[:, 0], d[:, 1])
    axis = (P[-1, :2] - P[0, :2]) / np.linalg.norm(P[-1, :2] - P[0, :2])
    psi = wrap_angle(P[:, 2] - np.arctan2(axis[1], axis[0]))
    psi_mid = 0.5 * (psi[1:] + psi[:-1])
    across = (P[:, :2] - P[0, :2]) @ np.array([-axis[1], axis[0]])
    z = across + np.random.default_rng(seed).normal(0.0, sigma, len(across))
    dt = float(np.median(np.diff(stamps)))
    slip_sigma = floor + slip * s_true + lever * np.abs(wrap_angle(np.diff(P[:, 2])))
    exact = not (slip > 0 or floor > 0 or lever > 0)
    s_hat = step_lengths(psi_mid, z, sigma, ACCEL * dt * dt, None if exact else slip_sigma)
    err = (s_hat - s_true) @ np.cos(psi_mid)
    return 100.0 * abs(err) / s_true.sum(), float(np.degrees(np.sqrt(np.mean(psi ** 2)))), len(P)


def main() -> None:
    lo, hi = (int(v) for v in sys.argv[1].split("-"))
    for spec in sys.argv[2:]:
        sigma_mm, slip, floor_mm, lever = (float(v) for v in spec.split(":"))
        r = np.array([forward_error_pct(s, sigma_mm / 1000, slip, floor_mm / 1000, lever) for s in range(lo, hi + 1)])
        e = r[:, 0]
        print(f"across sigma {sigma_mm:g} mm, slip {slip:g} x length + {floor_mm:g} mm + {lever:g} m x |dtheta|: "
              f"{len(e)} logs ({int(r[:, 2].min())}-{int(r[:, 2].max())} frames, heading off the axis rms median "
              f"{np.median(r[:, 1]):.1f} deg): forward error % of path median {np.median(e):.2f} / p90 "
              f"{np.percentile(e, 90):.2f} / worst {e.max():.2f}", flush=True)


if __name__ == "__main__":
    main()
