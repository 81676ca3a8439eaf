"""Loop closure, front-end half: keyframe contents, place recognition and geometric verification.

A :class:`Keyframe` holds what recognising and verifying a place needs and no image: ORB
descriptors and pixels, the levelled normalised coordinates and the levelled 3-D points
of its keypoints (metres, lifted with depth as the odometry lifts its corners), and the
frame's Manhattan observations.

Place recognition (:class:`PlaceIndex`) is a bag of words whose words need no trained
vocabulary and no file: ``hash_tables`` random subsets of ``hash_bits`` of the 256
descriptor bits (locality-sensitive hashing for the Hamming distance). Two descriptors of
the same physical point a few bits apart land in the same bucket of at least one table
with high probability, two unrelated ones almost never; every bucket is a word. Words
are weighted by their inverse document frequency over the keyframes indexed so far
(tf-idf with binary term frequency), so texture every keyframe sees -- and the repeated
doors and posters of a building, as they recur -- weighs less as the run goes. The index
is sorted arrays of (word, keyframe position), 8 bytes per word of a keyframe.

Verification (:func:`verify_closure`) uses the paper's own geometry (Sec. 2): descriptor
matches passing a ratio test, lifted to 3-D in the levelled frames, where a planar motion
``X_b = R_y(yaw) X_a + t`` keeps each point's height -- a test of every match before any
model. A planar 2-point RANSAC on the 3-D points (yaw from the direction between the two
points, ``t`` from their mean), scored by the Mahalanobis distance under the depth and
pixel noise model, then Gauss-Newton over the inliers gives ``(yaw, t)`` and its
covariance (``(J^T J)^-1`` times the reduced chi-square, at least 1). When both
keyframes see a local Manhattan frame, the difference of the two headings (eq. 1; the
90-degree ambiguity resolved by the points' yaw) must agree with the points' yaw within
a few sigmas; the yaw is then taken from it (``yaw_from``: alone, the paper's
direction-plus-point, or fused with the points' yaw) and the translation refitted at that
yaw (eq. 2 over the inliers). A closure is accepted only with enough inliers, spread in
both horizontal directions (not one poster, not one wall: a repeated poster or door at
another place gives a consistent transform whose inliers all lie on it).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from planar_vo.core import geometry
from planar_vo.core.types import CameraIntrinsics
from planar_vo.frontend.config import DEFAULT_DEPTH_RANGE, FeatureConfig, PlaceConfig
from planar_vo.frontend.features import FeatureSet, lift, undistort
from planar_vo.frontend.odometry import lev_motion_to_base_step, levelled_features
from planar_vo.frontend.solvers import yaw_from_manhattan_headings

__all__ = ["Keyframe", "make_keyframe", "bag_of_words", "PlaceIndex", "ClosureCheck", "verify_closure",
           "match_descriptors"]

# ClosureCheck.reason values
ACCEPTED = "accepted"
FEW_MATCHES = "few_matches"
NO_SOLUTION = "no_solution"
FEW_INLIERS = "few_inliers"
POOR_SPREAD = "poor_spread"
MANHATTAN_MISMATCH = "manhattan_mismatch"
PRIOR_MISMATCH = "prior_mismatch"
OUT_OF_VIEW = "out_of_view"


@dataclass
class Keyframe:
    """What place recognition and verification keep of one frame (no image).

    ``index``: the frame's index in the run (= its pose index in the graph). ``desc``:
    (N, 32) uint8 ORB descriptors; ``px``: (N, 2) float32 pixels; ``xy_lev``: (N, 2)
    float64 levelled normalised coordinates (NaN behind the camera); ``P_lev``: (N, 3)
    float64 levelled points (metres), NaN rows without depth; ``manhattan``: the frame's
    ManhattanObservation list (yaw relative to base_link). ``words``: (W,) int32 sorted
    bag-of-words ids (:func:`bag_of_words`); ``focal_px``: the camera's fx; ``octave``:
    (N,) uint8 the pyramid level each keypoint was found at (its position error grows with
    the level's scale).
    """

    index: int
    stamp: float
    desc: np.ndarray
    px: np.ndarray
    xy_lev: np.ndarray
    P_lev: np.ndarray
    manhattan: list
    words: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    focal_px: float = 525.0  # the camera's focal length (pixel noise to normalised units)
    octave: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))  # (N,) ORB pyramid level

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        return sum(a.nbytes for a in (self.desc, self.px, self.xy_lev, self.P_lev, self.words, self.octave))


# ------------------------------------------------------------------------ keyframes

def _grid_select(pts: np.ndarray, resp: np.ndarray, shape: tuple[int, int], config: PlaceConfig) -> np.ndarray:
    """Indices of at most ``orb_features`` keypoints (pixels ``pts`` (N, 2), responses
    ``resp`` (N,)), round-robin over a ``grid_cols`` x ``grid_rows`` grid, strongest first
    in each cell: the best of every cell, then the second best..."""
    if len(pts) <= config.orb_features:
        return np.arange(len(pts))
    h, w = shape
    cell = (np.minimum((pts[:, 1] * config.grid_rows / h).astype(int), config.grid_rows - 1) * config.grid_cols
            + np.minimum((pts[:, 0] * config.grid_cols / w).astype(int), config.grid_cols - 1))
    order = np.argsort(-resp, kind="stable")
    c = cell[order]
    grouped = np.argsort(c, kind="stable")
    cs = c[grouped]
    rank = np.empty(len(c), np.int64)
    rank[grouped] = np.arange(len(c)) - np.searchsorted(cs, cs, side="left")
    return order[np.lexsort((np.arange(len(c)), rank))[:config.orb_features]]


#: ORB's pyramid scale factor (OpenCV's default, stated so the noise model can use it).
ORB_SCALE = 1.2


def _orb(gray: np.ndarray, depth: np.ndarray, intrinsics: CameraIntrinsics, config: PlaceConfig,
         lift_args: tuple) -> tuple[np.ndarray, ...]:
    """``(px (N, 2) float32, xy (N, 2), P_cam (N, 3), desc (N, 32) uint8, octave (N,) uint8)`` of evenly spread
    ORB keypoints with a depth reading (verification needs 3-D points; far texture without
    depth would only crowd the matches: from a metre away the far end of a corridor
    looks the same and matches best)."""
    threshold = config.orb_fast_threshold
    while True:
        orb = cv2.ORB_create(nfeatures=3 * config.orb_features, scaleFactor=ORB_SCALE, fastThreshold=threshold)
        kps = orb.detect(gray, None)
        if kps:
            # KeyPoint_convert: the same float32 pixels as reading k.pt, without a Python
            # loop over the ~3000 keypoints (a quarter of a keyframe's time)
            px = cv2.KeyPoint_convert(kps).reshape(-1, 2)
            ok = np.flatnonzero(np.isfinite(lift(px, undistort(px, intrinsics), depth, *lift_args)[:, 2]))
            kps, px = [kps[i] for i in ok], px[ok]
        # plain walls: at the default threshold a low-contrast frame gave 3-8 keypoints
        # where a threshold of 4 gave 600-800 (what the odometry's corners track there)
        if len(kps) >= config.orb_features or threshold <= config.orb_min_fast_threshold:
            break
        threshold = max(threshold // 2, config.orb_min_fast_threshold)
    if len(kps) > config.orb_features:
        resp = np.array([k.response for k in kps])
        kps = [kps[i] for i in _grid_select(px.astype(np.float64), resp, gray.shape, config)]
    kps, desc = orb.compute(gray, kps)
    if desc is None or not kps:
        return (np.zeros((0, 2), np.float32), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 32), np.uint8),
                np.zeros(0, np.uint8))
    px = cv2.KeyPoint_convert(kps).reshape(-1, 2)
    xy = undistort(px, intrinsics)
    octave = np.array([k.octave for k in kps], np.uint8)
    return px, xy, lift(px, xy, depth, *lift_args), desc, octave


def make_keyframe(index: int, stamp: float, gray: np.ndarray, depth: np.ndarray, intrinsics: CameraIntrinsics,
                  R_lev_cam: np.ndarray, manhattan: list, config: PlaceConfig, *,
                  feature_config: FeatureConfig | None = None,
                  depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE) -> Keyframe:
    """A keyframe of one frame: ORB keypoints, lifted with ``depth`` and levelled.

    ``gray``: (H, W) uint8; ``depth``: (H, W) float32 metres (0 or NaN: no reading);
    ``R_lev_cam``: (3, 3) the odometry's levelling (``PlanarOdometry.levelling.R_lev_cam``);
    ``manhattan``: the frame's ``FrameResult.manhattan``. ``feature_config`` and
    ``depth_range``: the front-end's depth lifting settings (``frontend.features``,
    ``frontend.min_depth/max_depth``), so keyframe points are lifted as the odometry's.
    """
    if gray.ndim != 2 or gray.dtype != np.uint8 or depth.shape != gray.shape:
        raise ValueError(f"make_keyframe needs gray (H, W) uint8 and depth of the same shape, got "
                         f"{gray.shape} {gray.dtype} and {depth.shape}")
    # NaN and inf need no replacing: lifting reads only depths within the range (a whole
    # image's nan_to_num cost a keyframe 1.3 ms)
    depth = depth.astype(np.float32, copy=False)
    px, xy, P_cam, desc, octave = _orb(gray, depth, intrinsics, config, (feature_config or FeatureConfig(), depth_range))
    x_lev, P_lev = levelled_features(FeatureSet(px=px, xy=xy, P_cam=P_cam), np.asarray(R_lev_cam, float))
    return Keyframe(int(index), float(stamp), desc, px, x_lev, P_lev, list(manhattan), bag_of_words(desc, config),
                    float(intrinsics.fx), octave)


# ----------------------------------------------------------------- place recognition

@functools.lru_cache(maxsize=8)
def _hash_bits(tables: int, bits: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Bit positions (tables, bits) of each table's key and their weights (bits,)."""
    rng = np.random.default_rng([int(seed), 8191])
    sel = np.stack([rng.choice(256, bits, replace=False) for _ in range(tables)])
    return sel, (1 << np.arange(bits)).astype(np.int64)


def bag_of_words(desc: np.ndarray, config: PlaceConfig) -> np.ndarray:
    """Sorted unique word ids (W,) int32 of descriptors ``desc`` (N, 32) uint8: per table
    ``k``, the ``hash_bits`` selected bits as an integer, plus ``k << hash_bits``."""
    if len(desc) == 0:
        return np.zeros(0, np.int32)
    sel, weights = _hash_bits(config.hash_tables, config.hash_bits, config.hash_seed)
    bits = np.unpackbits(np.ascontiguousarray(desc, np.uint8), axis=1)     # (N, 256)
    keys = bits[:, sel].astype(np.int64) @ weights                          # (N, tables)
    words = keys + (np.arange(config.hash_tables, dtype=np.int64) << config.hash_bits)[None, :]
    # sorted unique ids by a sort: np.unique hashes first (2.6 ms a keyframe, numpy 2.4,
    # against 0.08 ms), and gives the same array
    w = np.sort(words, axis=None)
    return w[np.concatenate(([True], w[1:] != w[:-1]))].astype(np.int32)


class PlaceIndex:
    """Inverted index of keyframes' words, scored by tf-idf (binary term frequency).

    :meth:`add` keyframes in order; :meth:`query` ranks the earlier ones by appearance.
    The postings (word id, keyframe position) are kept in two sorted runs: recent
    keyframes are inserted into a small one, merged into the large one when it reaches
    an eighth of its size, so an add costs a pass over the small run, not the whole index
    (8 bytes per word of a keyframe, ~60 kB a keyframe at the defaults).
    """

    def __init__(self, config: PlaceConfig):
        self.config = config
        empty = (np.zeros(0, np.int32), np.zeros(0, np.int32))
        self._runs = [empty, empty]             # (sorted word ids, keyframe positions): large, recent
        self._sizes: list[int] = []             # words per keyframe
        self._frame_index: list[int] = []       # Keyframe.index per position

    def __len__(self) -> int:
        return len(self._sizes)

    @property
    def nbytes(self) -> int:
        """Bytes held by the postings."""
        return sum(w.nbytes + p.nbytes for w, p in self._runs)

    def frame_index(self, position: int) -> int:
        """``Keyframe.index`` of the keyframe added at ``position``."""
        return self._frame_index[position]

    @staticmethod
    def _insert(run, words: np.ndarray, pos: np.ndarray):
        at = np.searchsorted(run[0], words)
        return np.insert(run[0], at, words), np.insert(run[1], at, pos)

    def add(self, kf: Keyframe) -> None:
        """Index ``kf`` at the next position."""
        words = kf.words if len(kf.words) or not len(kf.desc) else bag_of_words(kf.desc, self.config)
        big, small = self._runs
        small = self._insert(small, words, np.full(len(words), len(self._sizes), np.int32))
        if len(small[0]) > max(len(big[0]) // 8, 1 << 16):
            big, small = self._insert(big, *small), (np.zeros(0, np.int32), np.zeros(0, np.int32))
        self._runs = [big, small]
        self._sizes.append(len(words))
        self._frame_index.append(int(kf.index))

    def query(self, kf: Keyframe, max_index: int, k: int) -> list[tuple[int, float]]:
        """The best ``k`` indexed keyframes with ``Keyframe.index <= max_index``:
        ``[(position in the order added, score)]``, best first, scores > 0 only.

        Score: ``sum over shared words of idf^2 / (sqrt(|W_q| |W_d|) log(N + 1)^2)``,
        ``idf = log((N + 1) / df)`` over the ``N`` keyframes indexed; 1 for a keyframe
        sharing every word, each of them unique to it.
        """
        n = len(self)
        words = kf.words if len(kf.words) or not len(kf.desc) else bag_of_words(kf.desc, self.config)
        if n == 0 or k <= 0 or len(words) == 0:
            return []
        spans = [(np.searchsorted(w, words, side="left"), np.searchsorted(w, words, side="right")) for w, _ in self._runs]
        df = sum(hi - lo for lo, hi in spans)        # keyframes holding each query word
        idf2 = np.log((n + 1.0) / np.maximum(df, 1)) ** 2
        acc = np.zeros(n)
        for (lo, hi), (_, pos) in zip(spans, self._runs):
            cnt = hi - lo
            total = int(cnt.sum())
            if total:
                at = np.repeat(lo - np.cumsum(cnt) + cnt, cnt) + np.arange(total)
                acc += np.bincount(pos[at], np.repeat(idf2, cnt), minlength=n)
        sizes = np.maximum(np.asarray(self._sizes, float), 1.0)
        score = acc / (np.sqrt(sizes * len(words)) * math.log(n + 1.0) ** 2)
        score[np.asarray(self._frame_index) > max_index] = 0.0
        best = np.argsort(-score, kind="stable")[:k]
        return [(int(p), float(score[p])) for p in best if score[p] > 0]


# ----------------------------------------------------------------------- verification

@dataclass
class ClosureCheck:
    """Verdict of :func:`verify_closure`.

    ``pose``: (3,) float64 SE(2) ``T_base_a_base_b`` ``(x, y, theta)`` (base_link, REP 103)
    or None; ``information``: (3, 3) float64 in gtsam.Pose2 tangent order ``[x, y, theta]``
    or None. ``reason``: ``"accepted"`` or why not (``few_matches``, ``no_solution``,
    ``few_inliers``, ``poor_spread``, ``manhattan_mismatch``, ``prior_mismatch``,
    ``out_of_view``). ``spread_m``: std of the inliers' horizontal positions in their
    narrowest direction (robust width, :func:`_spread`).
    ``yaw_source``: ``"manhattan"`` (direction-plus-point), ``"fused"`` (Manhattan and points)
    or ``"2pt"`` (the points alone). ``covariance``: (3, 3) base_link, the inverse of
    ``information``; ``lev_motion``: the levelled motion; ``inlier_pairs``: the inliers'
    keypoint indices (for drawing or checks).
    """

    accepted: bool
    reason: str
    pose: np.ndarray | None
    information: np.ndarray | None
    matches: int = 0
    inliers: int = 0
    spread_m: float = 0.0
    yaw_source: str = ""
    covariance: np.ndarray | None = None   # (3, 3) base_link, the inverse of ``information``
    lev_motion: tuple | None = None        # levelled (yaw, t (3,)) with X_b = R_y(yaw) X_a + t
    inlier_pairs: np.ndarray | None = None  # (K, 2) int64 keypoint indices [i_a, i_b] of the inliers
    prior_d2: float | None = None          # squared Mahalanobis distance to ``prior`` (when given and checked)


def match_descriptors(d1: np.ndarray, d2: np.ndarray, config: PlaceConfig) -> np.ndarray:
    """Matches (M, 2) int64 ``[i1, i2]``: nearest neighbours in Hamming distance within
    ``max_hamming`` and better than ``ratio`` times the second nearest; a point of ``d2``
    claimed by several keeps the closest (one brute-force pass; the reverse pass of a
    mutual check doubled the cost and gained nothing after the geometric tests)."""
    if len(d1) < 2 or len(d2) < 2:
        return np.zeros((0, 2), np.int64)
    fwd = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(d1, d2, k=2)
    m = np.array([(p[0].queryIdx, p[0].trainIdx, p[0].distance, p[1].distance) for p in fwd if len(p) == 2],
                 float).reshape(-1, 4)
    m = m[(m[:, 2] <= config.max_hamming) & (m[:, 2] < config.ratio * m[:, 3])]
    m = m[np.lexsort((m[:, 2], m[:, 1]))]
    first = np.concatenate([[True], m[1:, 1] != m[:-1, 1]]) if len(m) else np.zeros(0, bool)
    return m[first, :2].astype(np.int64)


def _point_cov(P: np.ndarray, octave: np.ndarray, config: PlaceConfig, focal: float) -> tuple[np.ndarray, ...]:
    """Noise of levelled points (N, 3) found at pyramid levels ``octave`` (N,): horizontal
    (x, z) covariance entries ``(cxx, cxz, czz)`` and the vertical variance, each (N,). A
    point is ``(u Z, v Z, Z)``: depth noise ``sigma_Z`` lies along the ray, the keypoint's
    position noise ``pixel_sigma * 1.2^octave / f * Z`` across it."""
    Z = P[:, 2]
    u, v = P[:, 0] / Z, P[:, 1] / Z
    sz2 = (config.depth_sigma_const + config.depth_sigma_quad * Z * Z) ** 2
    pix2 = (config.pixel_sigma * ORB_SCALE ** octave.astype(float) / focal) ** 2 * Z * Z
    return u * u * sz2 + pix2, u * sz2, sz2, v * v * sz2 + pix2


def _rotated_cov(c, s, cov1, cov2):
    """Entries ``(xx, xz, zz)`` of ``cov2 + R cov1 R^T`` with ``R = [[c, s], [-s, c]]`` acting
    on ``(x, z)`` (broadcasting ``c``, ``s`` against the per-point entries)."""
    a, b, d = cov1
    xx = c * c * a + 2 * c * s * b + s * s * d + cov2[0]
    xz = c * s * (d - a) + (c * c - s * s) * b + cov2[1]
    zz = s * s * a - 2 * c * s * b + c * c * d + cov2[2]
    return xx, xz, zz


def _mahalanobis(Q1, Q2, cov1, cov2, c, s, tx, tz):
    """Squared horizontal Mahalanobis distances of ``Q2 - R Q1 - t`` (broadcast shapes)."""
    rx = Q2[..., 0] - (c * Q1[..., 0] + s * Q1[..., 1]) - tx
    rz = Q2[..., 1] - (-s * Q1[..., 0] + c * Q1[..., 1]) - tz
    xx, xz, zz = _rotated_cov(c, s, cov1, cov2)
    return (zz * rx * rx - 2.0 * xz * rx * rz + xx * rz * rz) / (xx * zz - xz * xz)


def _ransac(Q1, Q2, cov1, cov2, d2_y, config: PlaceConfig, rng) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Planar 2-point RANSAC on horizontal points ``Q1``, ``Q2`` (M, 2) ``(x, z)``: the yaw
    turns the vector between the two points of view a into that of view b, ``t`` is their
    mean offset; MSAC scoring with the vertical term ``d2_y`` (M,) added. Returns
    ``(yaw, t (2,), inliers (M,))`` of the best hypothesis, or None."""
    M = len(Q1)
    if M < 2:
        return None
    H = min(config.ransac_iterations, M * (M - 1) // 2)
    i = rng.integers(0, M, H)
    j = (i + rng.integers(1, M, H)) % M
    v1, v2 = Q1[j] - Q1[i], Q2[j] - Q2[i]
    ok = (np.hypot(v1[:, 0], v1[:, 1]) > 0.05) & (np.hypot(v2[:, 0], v2[:, 1]) > 0.05)
    if not ok.any():
        return None
    i, j, v1, v2 = i[ok], j[ok], v1[ok], v2[ok]
    # with w = z + i x a planar motion is w_b = exp(i yaw) w_a
    yaw = np.arctan2(v2[:, 0], v2[:, 1]) - np.arctan2(v1[:, 0], v1[:, 1])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    mid1, mid2 = 0.5 * (Q1[i] + Q1[j]), 0.5 * (Q2[i] + Q2[j])
    tx = mid2[:, 0:1] - (c[:, 0:1] * mid1[:, 0:1] + s[:, 0:1] * mid1[:, 1:2])
    tz = mid2[:, 1:2] - (-s[:, 0:1] * mid1[:, 0:1] + c[:, 0:1] * mid1[:, 1:2])
    d2 = _mahalanobis(Q1[None], Q2[None], [x[None] for x in cov1], [x[None] for x in cov2], c, s, tx, tz) + d2_y
    score = np.minimum(d2, config.chi2).sum(1)
    k = int(np.argmin(score))
    return float(yaw[k]), np.array([tx[k, 0], tz[k, 0]]), d2[k] < config.chi2


def _normal_equations(Q1, Q2, cov1, cov2, yaw: float, t: np.ndarray):
    """``(A (3, 3), g (3,), chi2)`` of the weighted least squares over ``(yaw, t_x, t_z)``:
    residuals ``r = Q2 - R Q1 - t`` (M, 2), weights ``(cov2 + R cov1 R^T)^-1``."""
    c, s = math.cos(yaw), math.sin(yaw)
    rx_rot = c * Q1[:, 0] + s * Q1[:, 1]
    rz_rot = -s * Q1[:, 0] + c * Q1[:, 1]
    r = np.column_stack([Q2[:, 0] - rx_rot - t[0], Q2[:, 1] - rz_rot - t[1]])
    xx, xz, zz = _rotated_cov(c, s, cov1, cov2)
    det = xx * zz - xz * xz
    W = np.stack([np.stack([zz, -xz], -1), np.stack([-xz, xx], -1)], -2) / det[:, None, None]  # (M, 2, 2)
    J = np.zeros((len(Q1), 2, 3))
    J[:, 0, 0], J[:, 1, 0] = -rz_rot, rx_rot   # dr/dyaw = -dR/dyaw Q1
    J[:, 0, 1] = J[:, 1, 2] = -1.0
    WJ = W @ J
    A = np.einsum("mki,mkj->ij", J, WJ)
    g = np.einsum("mki,mk->i", WJ, r)
    chi2 = float(np.einsum("mk,mkl,ml->", r, W, r))
    return A, g, chi2


def _refine(Q1, Q2, cov1, cov2, d2_y, yaw: float, t: np.ndarray, inl: np.ndarray, config: PlaceConfig,
            fixed_yaw: bool = False):
    """Gauss-Newton over the inliers, inliers re-selected, twice. Returns ``(yaw, t (2,),
    inliers, A (3, 3), chi2)``; with ``fixed_yaw`` only ``t`` moves."""
    for _ in range(3):
        if inl.sum() < 3:
            break
        for _ in range(4):
            A, g, chi2 = _normal_equations(Q1[inl], Q2[inl], [x[inl] for x in cov1], [x[inl] for x in cov2], yaw, t)
            if fixed_yaw:
                step = np.concatenate([[0.0], -np.linalg.solve(A[1:, 1:], g[1:])])
            else:
                step = -np.linalg.solve(A, g)
            yaw, t = yaw + float(step[0]), t + step[1:]
            if np.abs(step).max() < 1e-9:
                break
        c, s = math.cos(yaw), math.sin(yaw)
        new = _mahalanobis(Q1, Q2, cov1, cov2, c, s, t[0], t[1]) + d2_y < config.chi2
        if np.array_equal(new, inl) or new.sum() < 3:
            break
        inl = new
    A, g, chi2 = _normal_equations(Q1[inl], Q2[inl], [x[inl] for x in cov1], [x[inl] for x in cov2], yaw, t)
    return yaw, t, inl, A, chi2


def _fit_covariance(A: np.ndarray, chi2: float, n: int, yaw_var: float | None = None) -> np.ndarray:
    """(3, 3) covariance over ``(yaw, t_x, t_z)``: ``A^-1`` times the reduced chi-square (at
    least 1). With ``yaw_var`` the yaw came from elsewhere at that variance and ``t`` was
    fitted at it: ``t``'s own scatter plus the yaw error carried through ``dt/dyaw``."""
    f = max(chi2 / (2 * n - 3), 1.0) if 2 * n > 3 else 1.0
    if yaw_var is None:
        return np.linalg.inv(A) * f
    Att = np.linalg.inv(A[1:, 1:])
    gvec = -Att @ A[1:, 0]
    cov = np.zeros((3, 3))
    cov[0, 0] = yaw_var
    cov[0, 1:] = cov[1:, 0] = yaw_var * gvec
    cov[1:, 1:] = Att * f + yaw_var * np.outer(gvec, gvec)
    return cov


def _spread(Q: np.ndarray) -> float:
    """Width (m) of horizontal points (M, 2) in their narrowest direction, robustly: the
    smallest, over 12 directions, of the 20-80 % interquantile range of the projections
    over 1.683 (a Gaussian's std). A repeated door's consensus with a few stray points on
    the other wall (skirting-board corners, which match anywhere along a wall) had a std
    of 0.27-0.3 m; this ignores up to a fifth of the points on either side."""
    if len(Q) < 5:
        return 0.0
    ang = np.arange(12) * (math.pi / 12)
    proj = Q @ np.stack([np.cos(ang), np.sin(ang)])                      # (M, 12)
    q20, q80 = np.percentile(proj, [20.0, 80.0], axis=0)
    return float((q80 - q20).min() / 1.683)


def _manhattan_yaw(a: Keyframe, b: Keyframe, yaw_pts: float, var_pts: float, config: PlaceConfig):
    """Relative yaw from the two keyframes' Manhattan observations (eq. 1):
    ``("ok", yaw, sigma)`` for the strongest pair agreeing with the points' yaw,
    ``("mismatch", yaw, sigma)`` when pairs exist and none agrees, None without a pair.

    ``m = theta + yaw_obs (mod 90 deg)`` in each keyframe, so ``theta_b - theta_a =
    yaw_a - yaw_b`` modulo 90 degrees, the branch closest to the points' yaw."""
    obs_a = [o for o in a.manhattan if o.score >= config.manhattan_min_score]
    obs_b = [o for o in b.manhattan if o.score >= config.manhattan_min_score]
    pairs = sorted(((oa, ob) for oa in obs_a for ob in obs_b), key=lambda p: -p[0].score * p[1].score)
    first = None
    for oa, ob in pairs:
        y = yaw_from_manhattan_headings(oa.yaw, ob.yaw, yaw_pts)
        sigma = math.hypot(oa.sigma, ob.sigma)
        gate = max(config.manhattan_gate_sigmas * math.sqrt(sigma * sigma + var_pts),
                   math.radians(config.manhattan_gate_deg))
        if abs(float(geometry.wrap_angle(y - yaw_pts))) <= gate:
            return "ok", y, sigma
        first = first or ("mismatch", y, sigma)
    return first


def _valid(P: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.flatnonzero(np.isfinite(P).all(1) & (P[:, 2] > 0))


def _octaves(kf: Keyframe) -> np.ndarray:
    """``kf.octave``, or level 0 for every keypoint of a keyframe made without it."""
    return kf.octave if len(kf.octave) == len(kf.desc) else np.zeros(len(kf.desc), np.uint8)


def _closure_yaw(yaw_pts: float, var_pts: float, yaw_mf: float, var_mf: float, how: str):
    """The closure's yaw, its variance and source when the Manhattan yaw agrees with the
    points': ``"manhattan"`` takes eq. 1 alone (direction-plus-point), ``"fused"`` the
    inverse-variance mean of the two (independent: walls against matched points)."""
    if how == "manhattan":
        return yaw_mf, var_mf, "manhattan"
    d = float(geometry.wrap_angle(yaw_mf - yaw_pts))
    return yaw_pts + d * var_pts / (var_pts + var_mf), var_pts * var_mf / (var_pts + var_mf), "fused"


def _matched_points(a: Keyframe, b: Keyframe, config: PlaceConfig):
    """Descriptor matches between points with depth whose levelled heights agree (a planar
    motion keeps them, so most wrong matches fail here before any model):
    ``(pairs, P1, P2, cov1, cov2, d2_y)`` of the M matches kept, ``pairs`` (M, 2) their
    keypoint indices in ``a`` and ``b``, ``cov`` the horizontal covariance entries
    (:func:`_point_cov`), ``d2_y`` (M,) their vertical Mahalanobis distances; and the
    number of descriptor matches."""
    fa, fb = _valid(a.P_lev), _valid(b.P_lev)
    m = match_descriptors(a.desc[fa], b.desc[fb], config)
    pairs = np.column_stack([fa[m[:, 0]], fb[m[:, 1]]])
    P1, P2 = a.P_lev[pairs[:, 0]], b.P_lev[pairs[:, 1]]
    c1 = _point_cov(P1, _octaves(a)[pairs[:, 0]], config, a.focal_px)
    c2 = _point_cov(P2, _octaves(b)[pairs[:, 1]], config, b.focal_px)
    d2_y = (P2[:, 1] - P1[:, 1]) ** 2 / (c1[3] + c2[3] + 2 * config.height_sigma_m ** 2)
    keep = d2_y < config.chi2
    return (pairs[keep], P1[keep], P2[keep], tuple(x[keep] for x in c1[:3]), tuple(x[keep] for x in c2[:3]),
            d2_y[keep], len(m))


def prior_distance(pose: np.ndarray, cov: np.ndarray, prior) -> float | None:
    """Squared Mahalanobis distance of the closure ``pose`` (3,) with (3, 3) ``cov`` from
    ``prior`` ``(pose (3,), covariance (3, 3))``, both ``T_base_a_base_b``; the difference
    is ``prior^-1 * pose``, in the tangent space the covariances are stated in (gtsam.Pose2,
    right perturbation). None without a prior."""
    if prior is None:
        return None
    d = geometry.se2_between(np.asarray(prior[0], float), np.asarray(pose, float))
    S = np.asarray(prior[1], float) + cov
    return float(d @ np.linalg.solve(S, d))


#: Slack of :func:`points_in_view` on top of the prior's gate: a point's own depth error
#: (this fraction of its range; Kinect v2 depth errs by ~1 %) and the inlier test's reach.
_VIEW_RANGE_SLACK = 0.1
_VIEW_SLACK_M = 0.1


def points_in_view(a: Keyframe, b: Keyframe, T_base_cam: np.ndarray, prior, config: PlaceConfig) -> int:
    """How many of ``a``'s points with depth could be in ``b``'s view if the motion from
    ``a`` to ``b`` is any that passes the prior gate: moved by ``prior`` (``T_base_a_base_b``
    (3,) and its (3, 3) covariance, as :func:`verify_closure` takes it) into ``b``'s levelled
    camera, within the bearings and the range of ``b``'s own points with depth, widened by
    the gate (``sqrt(prior_gate_chi2)`` sigmas of the prior's heading and position) and a
    slack for the points' own errors.

    A match pairs a point of ``a`` with one of ``b``; an accepted closure moves the first
    onto the second within the inlier test and lies within the gate of the prior, so with
    fewer than ``min_inliers`` such points no closure can be accepted. Verification then
    need not run (descriptor matching and RANSAC: 10-50 ms a pair), which is most of the
    appearance candidates of a run without a revisit: keyframes facing another corridor.
    """
    return _in_view(a, b, _valid(a.P_lev), _valid(b.P_lev), T_base_cam, prior, config)


def _in_view(a: Keyframe, b: Keyframe, fa: np.ndarray, fb: np.ndarray, T_base_cam: np.ndarray, prior,
             config: PlaceConfig) -> int:
    """:func:`points_in_view` over the points ``fa`` of ``a`` and ``fb`` of ``b`` with depth."""
    if len(fa) == 0 or len(fb) == 0:
        return 0
    pose, cov = np.asarray(prior[0], float), np.asarray(prior[1], float)
    k = math.sqrt(config.prior_gate_chi2)
    s_xy = k * geometry.largest_sigma(cov[:2, :2])
    s_th = k * math.sqrt(max(float(cov[2, 2]), 0.0))
    lev = geometry.base_step_to_lev_step(pose, geometry.mount_se2(T_base_cam))
    yaw, t = geometry.pose_to_levelled_motion(lev)
    Q = a.P_lev[fa] @ geometry.rot_y(yaw).T + t  # X_b = R_y(yaw) X_a + t
    Pb = b.P_lev[fb]
    bearing_b = np.arctan2(Pb[:, 0], Pb[:, 2])
    r_q = np.hypot(Q[:, 0], Q[:, 2])
    slack = s_xy + _VIEW_SLACK_M + _VIEW_RANGE_SLACK * r_q
    margin = s_th + np.arctan2(slack, np.maximum(r_q, 1e-9))
    bearing_q = np.arctan2(Q[:, 0], Q[:, 2])
    lo, hi = float(bearing_b.min()), float(bearing_b.max())
    r_max = float(np.hypot(Pb[:, 0], Pb[:, 2]).max())
    seen = (bearing_q >= lo - margin) & (bearing_q <= hi + margin) & (r_q <= r_max + slack)
    return int(seen.sum())


def _out_of_view(a: Keyframe, b: Keyframe, T_base_cam: np.ndarray, prior, config: PlaceConfig) -> bool:
    """Fewer than ``min_inliers`` of ``a``'s points can be in ``b``'s view under ``prior``
    (:func:`points_in_view`). Keyframes with fewer points than that are left to matching,
    which names what they lack (``few_matches``)."""
    fa, fb = _valid(a.P_lev), _valid(b.P_lev)
    enough = min(len(fa), len(fb)) >= config.min_inliers
    return enough and _in_view(a, b, fa, fb, T_base_cam, prior, config) < config.min_inliers


def verify_closure(a: Keyframe, b: Keyframe, T_base_cam: np.ndarray, config: PlaceConfig,
                   seed: int = 0, prior: tuple[np.ndarray, np.ndarray] | None = None) -> ClosureCheck:
    """Geometric verification of a loop-closure candidate: the planar motion from ``a`` to
    ``b`` (module docstring), as ``T_base_a_base_b`` with an information matrix from the fit.

    ``T_base_cam``: (4, 4) the camera mount (its planar part converts the levelled-camera
    motion to base_link, as the odometry's steps). ``seed`` seeds the RANSAC. ``prior``:
    optionally the graph's prediction of ``T_base_a_base_b`` and its (3, 3) covariance (the
    joint marginal of the two poses); a closure beyond ``prior_gate_chi2`` of it is
    rejected (``prior_mismatch``): what geometry cannot tell -- a place that looks the same
    and is elsewhere -- the trajectory can. A pair whose points the prior cannot put in
    view of each other is rejected before matching (``out_of_view``, :func:`points_in_view`).
    """
    if prior is not None and _out_of_view(a, b, T_base_cam, prior, config):
        return ClosureCheck(False, OUT_OF_VIEW, None, None)
    try:
        return _verify(a, b, T_base_cam, config, seed, prior)
    except np.linalg.LinAlgError:  # degenerate inliers (e.g. all at one point): no motion
        return ClosureCheck(False, NO_SOLUTION, None, None)


def _verify(a: Keyframe, b: Keyframe, T_base_cam: np.ndarray, config: PlaceConfig, seed: int, prior) -> ClosureCheck:
    """:func:`verify_closure`'s work (linear algebra errors are its caller's)."""
    pairs, P1, P2, cov1, cov2, d2_y, n_matches = _matched_points(a, b, config)
    if len(P1) < config.min_matches:
        return ClosureCheck(False, FEW_MATCHES, None, None, matches=n_matches)
    Q1, Q2 = P1[:, [0, 2]], P2[:, [0, 2]]
    hyp = _ransac(Q1, Q2, cov1, cov2, d2_y, config, np.random.default_rng(seed))
    if hyp is None or hyp[2].sum() < 3:
        return ClosureCheck(False, NO_SOLUTION, None, None, matches=n_matches)
    yaw, t, inl, A, chi2 = _refine(Q1, Q2, cov1, cov2, d2_y, *hyp, config)
    n_in = int(inl.sum())
    spread = _spread(Q2[inl])
    out = dict(matches=n_matches, inliers=n_in, spread_m=spread, inlier_pairs=pairs[inl])
    if n_in < config.min_inliers or n_in < config.min_inlier_ratio * len(P1):
        return ClosureCheck(False, FEW_INLIERS, None, None, **out)
    narrow = spread < (config.min_spread_many_m if n_in >= config.many_inliers else config.min_spread_m)
    cov = _fit_covariance(A, chi2, n_in)
    source = "2pt"
    mf = _manhattan_yaw(a, b, yaw, float(cov[0, 0]), config)
    if mf is not None and mf[0] == "mismatch":
        return ClosureCheck(False, MANHATTAN_MISMATCH, None, None, yaw_source="manhattan", **out)
    if narrow and (mf is None or prior is None
                   or geometry.largest_sigma(np.asarray(prior[1], float)[:2, :2]) > config.narrow_max_prior_sigma_m):
        # inliers in a narrow band (one wall) fix the translation at a given yaw, not the yaw,
        # and geometry alone cannot tell such a band from a look-alike one elsewhere: only a
        # prior whose gate is narrower than the spacing of repeated doors and posters can
        return ClosureCheck(False, POOR_SPREAD, None, None, **out)
    if mf is not None and (config.yaw_from != "points" or narrow):
        # narrow: the walls give the yaw (eq. 1), the points the translation at it
        # (direction-plus-point), and the prior below must confirm the pose
        how = "manhattan" if narrow else config.yaw_from
        yaw_fix, yaw_var, source = _closure_yaw(yaw, float(cov[0, 0]), mf[1], mf[2] ** 2, how)
        yaw, t, inl, A, chi2 = _refine(Q1, Q2, cov1, cov2, d2_y, yaw_fix, t, inl, config, fixed_yaw=True)
        cov = _fit_covariance(A, chi2, int(inl.sum()), yaw_var=yaw_var)
        out["inliers"], out["inlier_pairs"] = int(inl.sum()), pairs[inl]
    t3 = np.array([t[0], 0.0, t[1]])
    pose, cov_b = lev_motion_to_base_step(float(geometry.wrap_angle(yaw)), t3, cov, geometry.mount_se2(T_base_cam))
    cov_b = 0.5 * (cov_b + cov_b.T) + np.diag([config.min_sigma_xy ** 2, config.min_sigma_xy ** 2,
                                               math.radians(config.min_sigma_theta_deg) ** 2])
    out["prior_d2"] = prior_distance(pose, cov_b, prior)
    if out["prior_d2"] is not None and out["prior_d2"] > config.prior_gate_chi2:
        return ClosureCheck(False, PRIOR_MISMATCH, None, None, yaw_source=source, **out)
    return ClosureCheck(True, ACCEPTED, pose, np.linalg.inv(cov_b), yaw_source=source, covariance=cov_b,
                        lev_motion=(float(geometry.wrap_angle(yaw)), t3), **out)
