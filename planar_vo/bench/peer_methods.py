"""Peer RGB-D odometry: Open3D (legacy and tensor) and OpenCV, chained frame to frame.

These wrap other libraries' dense RGB-D odometry so that ``planar-vo bench peers``
can run them on the same decoded frames as planar-vo. Each method is split into
``prepare(frame)`` (convert one :class:`~planar_vo.core.types.RGBDFrame` into the
library's own image type, once per frame) and ``estimate(prev, curr, init)``, which
returns the relative motion ``T_prev_curr`` (4, 4) float64: the pose of the current
camera optical frame in the previous one, ``X_prev = T_prev_curr @ X_curr``.
:func:`track` chains these steps into ``T_world_cam`` poses.

Methods (``PEER_METHODS``) and the settings used (``PeerOptions`` defaults):

``open3d_legacy``  ``o3d.pipelines.odometry.compute_rgbd_odometry`` with
                   ``RGBDOdometryJacobianFromHybridTerm`` and the default
                   ``OdometryOption`` (3 levels, 20/10/5 iterations, depth_diff_max
                   0.03 m) except ``depth_max`` = the shared truncation (4.5 m).
``open3d_tensor``  ``o3d.t.pipelines.odometry.rgbd_odometry_multi_scale``, method
                   Hybrid, CPU:0, default criteria (10/5/3 iterations) and loss
                   parameters, ``depth_max`` = 4.5 m.
``opencv``         ``cv2.Odometry(OdometryType_RGB_DEPTH, settings, COMMON)``: the
                   RGB + ICP odometry of OpenCV 5 with its default settings (4
                   levels, 7/7/7/10 iterations, max 0.15 m / 15 deg per frame) except
                   the camera matrix and ``maxDepth`` = 4.5 m.

A step is a *failure* when the library reports one, raises, or returns a
non-finite or exactly-identity matrix (what the libraries return on failure); the
chain then continues with the identity step and the failure is counted.

Pure: frames in, poses out; no file I/O.
"""
from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from planar_vo.core.types import CameraIntrinsics, RGBDFrame


@dataclass
class PeerOptions:
    """Settings shared by the peer methods (see the module docstring for the rest)."""

    #: Depth beyond this is ignored by every peer (metres).
    depth_max_m: float = 4.5
    #: Initial guess of each step: ``identity`` (what the libraries' own pipelines do)
    #: or ``constant_velocity`` (the previous successful step; Open3D methods only,
    #: ``cv2.Odometry.compute`` takes no initial guess).
    init: str = "identity"

    def __post_init__(self) -> None:
        if not (self.depth_max_m > 0 and math.isfinite(self.depth_max_m)):
            raise ValueError(f"PeerOptions.depth_max_m must be a positive number, got {self.depth_max_m}")
        if self.init not in ("identity", "constant_velocity"):
            raise ValueError(f"PeerOptions.init must be 'identity' or 'constant_velocity', got {self.init!r}")


@dataclass
class PeerStep:
    """One relative motion: ``T_prev_curr`` (4, 4) float64, ``ok`` False on failure."""

    T_prev_curr: np.ndarray
    ok: bool
    reason: str = ""


def _check_frame(frame: RGBDFrame, intr: CameraIntrinsics) -> None:
    c, d = frame.color, frame.depth
    if c.ndim != 3 or c.shape[2] != 3 or c.dtype != np.uint8:
        raise ValueError(f"frame {frame.index}: color must be (H, W, 3) uint8 BGR, got {c.shape} {c.dtype}")
    if d.shape != c.shape[:2] or d.dtype != np.float32:
        raise ValueError(f"frame {frame.index}: depth must be (H, W) float32 metres matching color "
                         f"{c.shape[:2]}, got {d.shape} {d.dtype}")
    if intr.width and intr.height and (intr.height, intr.width) != c.shape[:2]:
        raise ValueError(f"frame {frame.index}: image is {c.shape[1]}x{c.shape[0]} but the intrinsics "
                         f"say {intr.width}x{intr.height}")


def _valid_step(T: np.ndarray) -> str:
    """Empty string if ``T`` (4, 4) looks like a real estimate, else why not."""
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return "non-finite pose"
    if np.array_equal(T, np.eye(4)):
        return "identity returned"
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
        return "non-orthonormal rotation"
    return ""


class PeerMethod(ABC):
    """A peer odometry: ``prepare`` a frame once, ``estimate`` a step between prepared frames."""

    #: registry key and table label
    name: str = ""
    label: str = ""
    #: whether ``estimate`` uses its ``init`` argument
    accepts_init: bool = True

    def __init__(self, intrinsics: CameraIntrinsics, options: PeerOptions | None = None):
        self.intrinsics = intrinsics
        self.options = options or PeerOptions()

    @abstractmethod
    def prepare(self, frame: RGBDFrame):
        """The library's representation of ``frame`` (built once, used as source and target)."""

    @abstractmethod
    def estimate(self, prev, curr, init: np.ndarray | None = None) -> PeerStep:
        """Motion ``T_prev_curr`` between two prepared frames; ``init`` is a guess of it."""

    def settings(self) -> dict:
        """The settings actually used, for the benchmark's JSON."""
        return {"depth_max_m": self.options.depth_max_m, "init": self.options.init if self.accepts_init else "identity"}


class Open3DLegacyHybrid(PeerMethod):
    """``o3d.pipelines.odometry.compute_rgbd_odometry`` with the hybrid (colour + depth) term."""

    name = "open3d_legacy"
    label = "Open3D legacy hybrid"

    def __init__(self, intrinsics: CameraIntrinsics, options: PeerOptions | None = None):
        super().__init__(intrinsics, options)
        import open3d as o3d

        self._o3d = o3d
        self._odo = o3d.pipelines.odometry
        self._option = self._odo.OdometryOption()
        self._option.depth_max = self.options.depth_max_m
        self._jacobian = self._odo.RGBDOdometryJacobianFromHybridTerm()
        self._pinhole = None

    def prepare(self, frame: RGBDFrame):
        import cv2

        o3d = self._o3d
        _check_frame(frame, self.intrinsics)
        if self._pinhole is None:
            h, w = frame.depth.shape
            i = self.intrinsics
            self._pinhole = o3d.camera.PinholeCameraIntrinsic(w, h, i.fx, i.fy, i.cx, i.cy)
        # The factory turns 1-channel uint8 into float intensity in [0, 1]; doing the
        # BGR -> gray conversion ourselves avoids a BGR/RGB swap.
        gray = cv2.cvtColor(frame.color, cv2.COLOR_BGR2GRAY)
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(gray), o3d.geometry.Image(np.ascontiguousarray(frame.depth)),
            depth_scale=1.0, depth_trunc=self.options.depth_max_m, convert_rgb_to_intensity=True)

    def estimate(self, prev, curr, init: np.ndarray | None = None) -> PeerStep:
        # Open3D returns T_target_source (maps source points into the target frame);
        # with source = curr and target = prev that is T_prev_curr.
        odo_init = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
        ok, T, _ = self._odo.compute_rgbd_odometry(curr, prev, self._pinhole, odo_init,
                                                   self._jacobian, self._option)
        T = np.asarray(T, dtype=np.float64)
        if not ok:
            return PeerStep(np.eye(4), False, "reported failure")
        why = _valid_step(T)
        return PeerStep(T if not why else np.eye(4), not why, why)

    def settings(self) -> dict:
        o = self._option
        return {**super().settings(), "jacobian": "hybrid",
                "iteration_number_per_pyramid_level": list(o.iteration_number_per_pyramid_level),
                "depth_diff_max": o.depth_diff_max, "depth_min": o.depth_min, "depth_max": o.depth_max}


class Open3DTensorHybrid(PeerMethod):
    """``o3d.t.pipelines.odometry.rgbd_odometry_multi_scale``, hybrid method, on the CPU."""

    name = "open3d_tensor"
    label = "Open3D tensor multi-scale"

    def __init__(self, intrinsics: CameraIntrinsics, options: PeerOptions | None = None):
        super().__init__(intrinsics, options)
        import open3d as o3d

        self._o3d = o3d
        self._odo = o3d.t.pipelines.odometry
        self._device = o3d.core.Device("CPU:0")
        self._K = o3d.core.Tensor(intrinsics.K, dtype=o3d.core.Dtype.Float64)
        self._criteria = [self._odo.OdometryConvergenceCriteria(n) for n in (10, 5, 3)]
        self._params = self._odo.OdometryLossParams()

    def prepare(self, frame: RGBDFrame):
        import cv2

        o3d = self._o3d
        _check_frame(frame, self.intrinsics)
        rgb = cv2.cvtColor(frame.color, cv2.COLOR_BGR2RGB)
        color = o3d.t.geometry.Image(o3d.core.Tensor(rgb, device=self._device))
        depth = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(frame.depth), device=self._device))
        return o3d.t.geometry.RGBDImage(color, depth)

    def estimate(self, prev, curr, init: np.ndarray | None = None) -> PeerStep:
        o3d = self._o3d
        T0 = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
        try:
            # source = curr, target = prev: the result maps curr points into prev.
            res = self._odo.rgbd_odometry_multi_scale(
                curr, prev, self._K, o3d.core.Tensor(T0), 1.0, self.options.depth_max_m,
                self._criteria, self._odo.Method.Hybrid, self._params)
        except RuntimeError as exc:  # e.g. too few correspondences at some level
            return PeerStep(np.eye(4), False, f"raised: {exc}".splitlines()[0][:120])
        T = res.transformation.numpy().astype(np.float64)
        why = _valid_step(T)
        if not why and res.fitness <= 0.0:
            why = "no inliers"
        return PeerStep(T if not why else np.eye(4), not why, why)

    def settings(self) -> dict:
        p = self._params
        return {**super().settings(), "method": "Hybrid", "device": str(self._device),
                "iterations_per_level": [10, 5, 3], "depth_outlier_trunc": p.depth_outlier_trunc,
                "depth_huber_delta": p.depth_huber_delta, "intensity_huber_delta": p.intensity_huber_delta}


class OpenCVRGBDOdometry(PeerMethod):
    """``cv2.Odometry`` of type ``OdometryType_RGB_DEPTH`` (photometric + ICP, OpenCV 5)."""

    name = "opencv"
    label = "OpenCV RGB-D"
    accepts_init = False

    def __init__(self, intrinsics: CameraIntrinsics, options: PeerOptions | None = None):
        super().__init__(intrinsics, options)
        import cv2

        self._cv2 = cv2
        s = cv2.OdometrySettings()
        s.setCameraMatrix(intrinsics.K.astype(np.float32))  # OpenCV asserts CV_32F
        s.setMaxDepth(self.options.depth_max_m)
        self._settings = s
        self._odo = cv2.Odometry(cv2.OdometryType_RGB_DEPTH, s, cv2.OdometryAlgoType_COMMON)

    def prepare(self, frame: RGBDFrame):
        cv2 = self._cv2
        _check_frame(frame, self.intrinsics)
        depth = np.ascontiguousarray(frame.depth)
        f = cv2.OdometryFrame(image=frame.color, depth=depth)
        self._odo.prepareFrame(f)  # pyramids etc., once per frame; usable as src and dst
        return f

    def estimate(self, prev, curr, init: np.ndarray | None = None) -> PeerStep:
        # OpenCV returns Rt with ``Rt * src = dst``; src = curr, dst = prev gives T_prev_curr.
        try:
            ok, T = self._odo.compute(curr, prev)
        except self._cv2.error as exc:
            return PeerStep(np.eye(4), False, f"raised: {exc}".splitlines()[0][:120])
        if not ok or T is None:
            return PeerStep(np.eye(4), False, "reported failure")
        T = np.asarray(T, dtype=np.float64)
        why = _valid_step(T)
        return PeerStep(T if not why else np.eye(4), not why, why)

    def settings(self) -> dict:
        s = self._settings
        return {**super().settings(), "type": "RGB_DEPTH", "algo": "COMMON",
                "iter_counts": s.getIterCounts().ravel().astype(int).tolist(),
                "min_gradient_magnitudes": s.getMinGradientMagnitudes().ravel().tolist(),
                "max_depth_diff": s.getMaxDepthDiff(), "max_points_part": s.getMaxPointsPart(),
                "max_translation": s.getMaxTranslation(), "max_rotation_deg": s.getMaxRotation(),
                "min_depth": s.getMinDepth(), "max_depth": s.getMaxDepth()}


#: name -> class, in table order
PEER_METHODS: dict[str, type[PeerMethod]] = {
    cls.name: cls for cls in (Open3DLegacyHybrid, Open3DTensorHybrid, OpenCVRGBDOdometry)
}


def make_method(name: str, intrinsics: CameraIntrinsics, options: PeerOptions | None = None) -> PeerMethod:
    """Instantiate the peer called ``name`` (a key of :data:`PEER_METHODS`)."""
    if name not in PEER_METHODS:
        raise ValueError(f"unknown peer method {name!r}; choose from {', '.join(PEER_METHODS)}")
    return PEER_METHODS[name](intrinsics, options)


@dataclass
class PeerRun:
    """A chained peer trajectory.

    ``stamps`` (N,) float64 seconds; ``poses`` (N, 4, 4) float64 ``T_world_cam``;
    ``failures``: indices of the frames whose incoming step failed (identity chained);
    ``reasons``: failure reason per failed frame; ``time_s``: wall time spent in
    ``prepare`` + ``estimate`` (the method's own processing, decoding excluded).
    """

    name: str
    label: str
    stamps: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    failures: list = field(default_factory=list)
    reasons: dict = field(default_factory=dict)
    time_s: float = 0.0

    @property
    def frames(self) -> int:
        return len(self.stamps)

    @property
    def ms_per_frame(self) -> float:
        return 1000.0 * self.time_s / self.frames if self.frames else float("nan")

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(stamps (N,), poses (N, 4, 4))`` as float64 arrays."""
        return (np.asarray(self.stamps, dtype=np.float64).reshape(-1),
                np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4))


class PeerTracker:
    """Chains one peer method over a frame stream: ``add(frame)`` per frame, in order."""

    def __init__(self, method: PeerMethod, T_world_cam0: np.ndarray | None = None):
        self.method = method
        self.run = PeerRun(method.name, method.label)
        self._T0 = np.eye(4) if T_world_cam0 is None else np.asarray(T_world_cam0, dtype=np.float64)
        if self._T0.shape != (4, 4):
            raise ValueError(f"PeerTracker: T_world_cam0 must be (4, 4), got {self._T0.shape}")
        self._prev = None
        self._pose = self._T0.copy()
        self._velocity: np.ndarray | None = None

    def add(self, frame: RGBDFrame) -> np.ndarray:
        """Process ``frame``; returns its pose ``T_world_cam`` (4, 4)."""
        m = self.method
        t0 = time.perf_counter()
        cur = m.prepare(frame)
        if self._prev is not None:
            init = None
            if m.accepts_init and m.options.init == "constant_velocity" and self._velocity is not None:
                init = self._velocity
            step = m.estimate(self._prev, cur, init)
        self.run.time_s += time.perf_counter() - t0
        if self._prev is not None:
            if step.ok:
                self._pose = self._pose @ step.T_prev_curr
                self._velocity = step.T_prev_curr
            else:
                self.run.failures.append(frame.index)
                self.run.reasons[frame.index] = step.reason
                self._velocity = None
        self._prev = cur
        self.run.stamps.append(float(frame.stamp))
        self.run.poses.append(self._pose.copy())
        return self._pose.copy()


def track(frames: Iterable[RGBDFrame], intrinsics: CameraIntrinsics, methods: Iterable[str],
          options: PeerOptions | None = None, T_world_cam0: np.ndarray | None = None) -> dict[str, PeerRun]:
    """Run every method in ``methods`` over one pass of ``frames``; ``{name: PeerRun}``.

    Each frame is decoded once and handed to every method in turn, so long logs need no
    frame cache. The first pose of every trajectory is ``T_world_cam0`` (default identity).
    """
    trackers = [PeerTracker(make_method(n, intrinsics, options), T_world_cam0) for n in methods]
    for frame in frames:
        for t in trackers:
            t.add(frame)
    return {t.method.name: t.run for t in trackers}
