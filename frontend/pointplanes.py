"""Matched corners on a detected wall or floor: their depths refined by the plane.

A corner's depth reading has the sensor's noise, ``sigma(Z) = c + q Z^2`` along the ray and
more at oblique incidence (a side wall a metre away seen 2-4 m ahead, the floor a few
metres ahead), and is the depth of the nearest pixel, not of the tracked sub-pixel
position (centimetres apart on a wall seen obliquely far ahead). Low-texture corridors
leave the 1-point translation (eq. 2) a dozen such corners per step, mostly on those
surfaces, and their noise adds up step after step.

The walls and the floor are fitted to thousands of depth pixels (the inverse-depth
histogram peaks and their least-squares planes, Sec. 3.1). A corner on a plane lies at a
fixed distance ``p`` beyond it (0 on bare wall; a door frame or poster stands a few
millimetres proud), the same in both frames, so along each view's ray it is at
``s = (offset + p) / (n . u)``. ``p`` is estimated once per match from both readings
(inverse-variance mean of ``n . X - offset``); an error in it moves both points alike
and changes their difference by only ``dp`` times the step over the plane distance
(a few per cent of it). What is left is the ray's own angular noise, ``s delta
tan(incidence)``, and the planes' fitted offsets (``plane_sigma``). Snapping to the plane
instead (``p = 0``) would scale every step by ``1 + p / distance``: about +0.5 % from
5 mm proud posters a metre away.
"""
from __future__ import annotations

import numpy as np

from planar_vo.frontend.planes import Plane


def _on_plane(P: np.ndarray, planes: list[Plane], sig: dict, gate_chi2: float):
    """Per point (N,): ``(plane index or -1, ray (N, 3), cos of incidence, reading's
    along-ray range, its variance)``; a point is on the plane its range agrees with best."""
    with np.errstate(invalid="ignore", divide="ignore"):
        s_m = np.linalg.norm(P, axis=1)
        u = P / s_m[:, None]
        sz = sig["const"] + sig["quad"] * P[:, 2] ** 2
        var_model = (sz * s_m / P[:, 2]) ** 2
        N = np.array([p.normal for p in planes])
        off = np.array([p.offset for p in planes])
        c = u @ N.T                                        # (N, K)
        cc = np.where(c >= sig["min_cos"], c, np.nan)
        s_p = off[None, :] / cc
        var_m = var_model[:, None] * (1.0 + sig["incidence"] * (1.0 / cc - 1.0)) ** 2
        var_p = (s_p * sig["ray"]) ** 2 * (1.0 - cc * cc) / (cc * cc) + (sig["plane"] / cc) ** 2
        chi = (s_m[:, None] - s_p) ** 2 / (var_m + var_p)
        chi = np.where(np.isfinite(chi), chi, np.inf)
    k = np.argmin(chi, axis=1)
    rows = np.arange(len(P))
    k = np.where(chi[rows, k] < gate_chi2, k, -1)
    kk = np.maximum(k, 0)
    return k, u, cc[rows, kk], s_m, var_m[rows, kk], var_model


def refine_pairs_on_planes(P1: np.ndarray, P2: np.ndarray, planes1: list[Plane], planes2: list[Plane],
                           yaw: float, *, depth_sigma_const: float, depth_sigma_quad: float, incidence: float,
                           ray_sigma: float, plane_sigma: float, gate_chi2: float, min_cos: float = 0.05,
                           max_normal_deg: float = 5.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(Q1, Q2 (M, 3), scale1, scale2 (M,))``: matched levelled points ``P1``, ``P2``
    (M, 3), metres, NaN rows without depth, with the depths of matches on the same plane
    in both views refined, and each view's along-ray variance over the reading's modelled
    ``sigma(Z)^2`` (1 where unchanged).

    ``planes1``, ``planes2``: each view's levelled planes ``normal . X = offset``; a match
    is on one plane when both readings agree with a plane and the normals agree within
    ``max_normal_deg`` after the step's ``yaw`` (``X2 = R_y(yaw) X1 + t``). ``incidence``:
    the reading's sigma grows by ``1 + incidence (1 / cos - 1)``. ``ray_sigma``: the ray's
    angular noise (rad, pixel sigma / focal). ``plane_sigma``: a fitted offset's error (m).
    ``min_cos``: only corners seen at most ``acos(min_cos)`` from the plane's normal. A
    plane's orientation error ``e`` (a tenth of a degree of levelling or fit) moves a
    corner's offset by ``e`` times the step, which along the ray scales the step by about
    ``e / cos``; on the tuning log straight_s123 (camera 0.49 m high, pitched 21 deg) the
    refined steps came out 1.5 % long with ``min_cos`` 0.05 and 0.5 alike.
    """
    P1, P2 = np.asarray(P1, dtype=float), np.asarray(P2, dtype=float)
    Q1, Q2, sc1, sc2 = P1.copy(), P2.copy(), np.ones(len(P1)), np.ones(len(P2))
    if not planes1 or not planes2 or len(P1) == 0:
        return Q1, Q2, sc1, sc2
    sig = dict(const=depth_sigma_const, quad=depth_sigma_quad, incidence=incidence, ray=ray_sigma,
               plane=plane_sigma, min_cos=min_cos)
    k1, u1, c1, s1, v1, vm1 = _on_plane(P1, planes1, sig, gate_chi2)
    k2, u2, c2, s2, v2, vm2 = _on_plane(P2, planes2, sig, gate_chi2)
    n1 = np.array([p.normal for p in planes1])
    n2 = np.array([p.normal for p in planes2])
    cy, sy = np.cos(yaw), np.sin(yaw)
    R = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    same = (k1 >= 0) & (k2 >= 0)
    cos_n = np.ones(len(P1))
    cos_n[same] = np.einsum("ij,ij->i", n1[k1[same]] @ R.T, n2[k2[same]])
    same &= cos_n > np.cos(np.radians(max_normal_deg))
    if not same.any():
        return Q1, Q2, sc1, sc2
    # the corner's distance beyond the plane, from both readings (variance along the normal):
    # a static corner's is the same in both views, else the two are not one plane
    o1 = np.array([p.offset for p in planes1])[k1]
    o2 = np.array([p.offset for p in planes2])[k2]
    with np.errstate(invalid="ignore"):
        p1_all, p2_all = s1 * c1 - o1, s2 * c2 - o2
        v_p = v1 * c1 * c1 + v2 * c2 * c2
        same &= (p1_all - p2_all) ** 2 < gate_chi2 * v_p
    if not same.any():
        return Q1, Q2, sc1, sc2
    o1, o2, a1, a2 = o1[same], o2[same], c1[same], c2[same]
    p1, p2 = p1_all[same], p2_all[same]
    w1, w2 = 1.0 / (v1[same] * a1 * a1), 1.0 / (v2[same] * a2 * a2)
    p = (w1 * p1 + w2 * p2) / (w1 + w2)
    r1, r2 = (o1 + p) / a1, (o2 + p) / a2
    Q1[same] = u1[same] * r1[:, None]
    Q2[same] = u2[same] * r2[:, None]
    d2 = _normal_jitter(n1[k1[same]] @ R.T, n2[k2[same]], _shared_turn(n1 @ R.T, n2, planes2)) / 2.0
    for Q_sc, r, a, vm in ((sc1, r1, a1, vm1[same]), (sc2, r2, a2, vm2[same])):
        Q_sc[same] = _refined_variance(r, a, ray_sigma ** 2 + d2, plane_sigma) / vm
    return Q1, Q2, sc1, sc2


def _turn(m1: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """Angle (M,) rad about the vertical from normals ``m1`` to ``m2`` (M, 3)."""
    return np.arctan2(m1[:, 2] * m2[:, 0] - m1[:, 0] * m2[:, 2], m1[:, 0] * m2[:, 0] + m1[:, 2] * m2[:, 2])


def _shared_turn(m1: np.ndarray, m2: np.ndarray, planes2: list[Plane]) -> float:
    """The heading change (rad) from view 1's normals ``m1`` (K1, 3, turned by the prior
    yaw) to view 2's ``m2`` (K2, 3) of the largest vertical plane of view 2 and its nearest
    view-1 normal: the part of the step's yaw the prior missed (a wobbling robot's yaw
    changes by tenths of a degree from one step to the next), shared by all planes."""
    best, turn = -1.0, 0.0
    for j, q in enumerate(planes2):
        if abs(m2[j, 1]) < 0.5 and q.support > best:
            i = int(np.argmax(m1 @ m2[j]))
            best, turn = q.support, float(_turn(m1[i:i + 1], m2[j:j + 1])[0])
    return turn


def _normal_jitter(m1: np.ndarray, m2: np.ndarray, shared: float) -> np.ndarray:
    """Squared angle (M,) rad^2 between each match's plane normals ``m1`` (view 1, turned
    by the prior yaw) and ``m2`` (view 2), (M, 3), less the ``shared`` heading change of
    the largest plane (:func:`_shared_turn`): what is left is the planes' own error."""
    vert = np.abs(m1[:, 1]) < 0.5
    a = _turn(m1, m2)
    total = np.arccos(np.clip(np.einsum("ij,ij->i", m1, m2), -1.0, 1.0)) ** 2
    return np.where(vert, np.maximum(total - a * a, 0.0) + (a - shared) ** 2, total)


def _refined_variance(r: np.ndarray, cos_inc: np.ndarray, ang_var: np.ndarray, plane_sigma: float) -> np.ndarray:
    """Along-ray variance (M,) m^2 of refined ranges ``r`` (M,) at incidence cosines
    ``cos_inc`` (M,): an angular error of variance ``ang_var`` (M,) rad^2 between ray and
    plane, times ``r tan(incidence)``, and the plane offset's ``plane_sigma`` (m) along the
    ray (the shared ``p`` error cancels in the views' difference, up to step / distance).

    ``ang_var`` holds the ray's own angular noise and the plane's orientation error: a
    normal error tilts the plane against the ray as a ray error does. The two views'
    normals disagreeing by ``d`` (after the yaw) move the refined ranges' difference by
    ``r d tan(incidence)``, ``d^2 / 2`` per view. Small far planes (a 2 % end wall 3 m
    away) jitter by 1-3 deg from frame to frame: taken as exact they made a low-texture
    tuning step 51 mm long at a stated 1.9 mm.
    """
    return r * r * ang_var * (1.0 - cos_inc * cos_inc) / (cos_inc * cos_inc) + (plane_sigma / cos_inc) ** 2
