"""Is the motion planar? The verdict in ``report.json`` ``planarity``, from the data alone.

The paper's model holds for a robot on a flat floor; a handheld camera breaks it. Two
independent pieces of evidence, collected per frame by :func:`frame_summary` while the run
goes and judged once at the end by :func:`planarity_report`:

* floor: on a planar robot the floor normal in the camera frame and the camera height stay
  fixed (handheld cameras change both, or show no floor at all);
* motion (decides when the floor was not seen): the front-end's per-step 6-DoF fits
  (:mod:`planar_vo.frontend.planarity`) chained over windows must keep their height and
  vertical axis.
"""
from __future__ import annotations

import numpy as np


def frame_summary(result) -> dict:
    """What the verdict needs of one frame: floor normal in the camera, camera height, 6-DoF step."""
    d = result.diagnostics
    oop = d.out_of_plane
    return {
        "floor_normal_cam": d.floor_normal_cam,
        "camera_height_m": d.camera_height_m,
        "motion_6dof": (oop.R, oop.t) if oop is not None else None,
    }


#: Beyond these the motion is not planar: camera height (m) and tilt (deg) ranges, p5-p95.
PLANAR_HEIGHT_RANGE_M = 0.05
PLANAR_TILT_RANGE_DEG = 3.0


def _spread(values) -> float:
    v = np.asarray(values, dtype=float)
    return float(np.percentile(v, 95) - np.percentile(v, 5)) if len(v) else float("nan")


MOTION_WINDOW = 100


def _chain(steps) -> tuple[np.ndarray, np.ndarray]:
    """Camera positions (n+1, 3) and y axes (n+1, 3) in the first levelled frame from steps
    ``(R, t)`` with ``X2 = R X1 + t`` (None: no fit, taken as no motion)."""
    T = np.eye(4)
    pos, yax = [T[:3, 3].copy()], [T[:3, 1].copy()]
    for m in steps:
        if m is not None:
            T21 = np.eye(4)
            T21[:3, :3], T21[:3, 3] = np.asarray(m[0]), np.asarray(m[1])
            T = T @ np.linalg.inv(T21)
        pos.append(T[:3, 3].copy())
        yax.append(T[:3, 1].copy())
    return np.array(pos), np.array(yax)


def planarity_report(frame_infos: list[dict], levelled: bool) -> dict:
    """Is the motion planar? Two independent pieces of evidence, both from the data.

    * floor: on a planar robot the floor normal in the camera frame and the camera height
      stay fixed (handheld cameras change both, or show no floor at all);
    * motion (decides when the floor was not seen): the per-step 6-DoF fits
      (:mod:`planar_vo.frontend.planarity`) chained over windows of ``MOTION_WINDOW`` steps in
      the levelled frame must keep their height and vertical axis. Without a mount or a floor
      the estimator assumes a level camera, and so does this test.
    """
    n = len(frame_infos)
    rep: dict = {"frames": n}
    verdicts = []
    normals = [np.asarray(f["floor_normal_cam"], float) for f in frame_infos if f.get("floor_normal_cam") is not None]
    heights = [float(f["camera_height_m"]) for f in frame_infos if f.get("camera_height_m") is not None]
    rep["floor_seen_frames"] = len(normals)
    if len(normals) >= max(3, 0.2 * n):
        N = np.stack(normals)
        mean = N.mean(0) / np.linalg.norm(N.mean(0))
        tilt = _spread(np.degrees(np.arccos(np.clip(N @ mean, -1, 1))))
        h = _spread(heights)
        rep["floor"] = {"tilt_range_deg": round(tilt, 3), "height_range_m": round(h, 4)}
        verdicts.append(tilt < PLANAR_TILT_RANGE_DEG and h < PLANAR_HEIGHT_RANGE_M)

    # Chained 6-DoF steps random-walk (a few cm and degrees over hundreds of frames), so
    # they are judged over windows of at most MOTION_WINDOW steps, and only when the floor,
    # far more precise, was not seen.
    steps = [f.get("motion_6dof") for f in frame_infos[1:]]
    fitted = sum(m is not None for m in steps)
    if fitted >= max(3, 0.5 * len(steps)):
        heights, tilts = [], []
        w = MOTION_WINDOW
        for a in range(0, max(1, len(steps) - w // 2), w // 2):
            P, Y = _chain(steps[a:a + w])
            heights.append(_spread(P[:, 1]))
            tilts.append(_spread(np.degrees(np.arccos(np.clip(Y[:, 1], -1, 1)))))
        height, tilt = max(heights), max(tilts)
        rep["motion"] = {"steps_fitted": fitted, "window_steps": w, "height_range_m": round(height, 4),
                         "tilt_range_deg": round(tilt, 3), "gravity": "measured" if levelled else "assumed"}
        if not verdicts:
            verdicts.append(tilt < PLANAR_TILT_RANGE_DEG and height < PLANAR_HEIGHT_RANGE_M)

    if not verdicts:
        rep["verdict"] = "unverified"
        rep["message"] = (f"the floor was seen in {len(normals)} of {n} frames and the motion could not be "
                          "fitted: planar motion is unverified and the planar model may not hold")
    elif all(verdicts):
        rep["verdict"] = "planar"
        rep["message"] = "camera height and tilt stay constant: consistent with planar motion"
    else:
        worst = rep.get("floor") or rep.get("motion")
        rep["verdict"] = "not_planar"
        rep["message"] = (f"the camera's height varies by {worst['height_range_m']:.2f} m and its tilt by "
                          f"{worst['tilt_range_deg']:.1f} deg: the motion is NOT planar (handheld?), so the "
                          "planar estimates are approximations"
                          + ("" if levelled else "; no floor and no mount: the camera was assumed level, "
                             "give --pitch-deg/--roll-deg if it is a tilted robot camera"))
    return rep


def is_levelled(levelling, frame_infos) -> bool:
    """True when gravity is known: a mount tilt was given (configuration or the log's
    /tf_static), or the floor was seen."""
    if levelling.source in ("config", "mount"):
        return True
    return any(f.get("floor_normal_cam") is not None for f in frame_infos)
