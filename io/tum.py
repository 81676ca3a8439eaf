"""TUM RGB-D benchmark folders (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``) as an RGB-D log.

Layout (Sturm et al., IROS 2012): list files of ``timestamp filename`` lines, 8-bit colour
PNGs, 16-bit depth PNGs with 5000 units per metre (0 = no reading). Colour and depth are
paired by nearest stamp like the benchmark's ``associate.py``.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from planar_vo.core.errors import InputError
from planar_vo.io.log import (DEPTH_SAMPLES, INTRINSICS_FLAGS, LogSummary, RGBDLog, _empty_stats,
                              check_range, depth_valid_fraction)
from planar_vo.io.pairing import COLOR, DEPTH, StampPairer, Unpaired
from planar_vo.io.trajectory import read_tum_trajectory
from planar_vo.core.types import CameraIntrinsics, RGBDFrame, Trajectory

#: Depth PNG units per metre.
TUM_DEPTH_SCALE = 5000.0

#: Published calibration of the three TUM Kinects (colour camera, 640x480).
TUM_INTRINSICS = {
    "freiburg1": CameraIntrinsics(640, 480, 517.3, 516.5, 318.6, 255.3,
                                  (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": CameraIntrinsics(640, 480, 520.9, 521.0, 325.1, 249.7,
                                  (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": CameraIntrinsics(640, 480, 535.4, 539.2, 320.1, 247.6),
}
_SENSOR = re.compile(r"(?:freiburg|fr)([123])(?![0-9])", re.IGNORECASE)


def tum_sensor(folder) -> str | None:
    """``"freiburg1"`` .. ``"freiburg3"`` from a folder name such as ``rgbd_dataset_freiburg1_xyz``."""
    match = _SENSOR.search(Path(folder).resolve().name)
    return f"freiburg{match.group(1)}" if match else None


def read_tum_list(path: Path) -> list[tuple[float, str]]:
    """``[(stamp, relative filename)]`` from ``rgb.txt`` / ``depth.txt``."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path.parent}: {path.name} is missing; a TUM RGB-D folder needs rgb.txt, "
                         "depth.txt and the rgb/ and depth/ images") from None
    out = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            stamp = float(parts[0])
            if len(parts) != 2 or not math.isfinite(stamp):
                raise ValueError
        except ValueError:
            raise InputError(f"{path}:{lineno}: expected 'timestamp filename', got {line[:80]!r}") from None
        out.append((stamp, parts[1]))
    return out


class TumRGBDLog(RGBDLog):
    """A TUM RGB-D folder; see :func:`planar_vo.io.open_log`."""

    def __init__(self, path, *, intrinsics: CameraIntrinsics | None = None, sync_tolerance: float = 0.02):
        super().__init__(path)
        self.sync_tolerance = float(sync_tolerance)
        self.color_list = read_tum_list(self.path / "rgb.txt")
        self.depth_list = read_tum_list(self.path / "depth.txt")
        for name, lst in (("rgb.txt", self.color_list), ("depth.txt", self.depth_list)):
            if not lst:
                raise InputError(f"{self.path / name}: lists no images")
            first = self.path / lst[0][1]
            if not first.is_file():
                raise InputError(f"{self.path / name}: its first image {lst[0][1]} is missing")
        self._intrinsics_override = intrinsics
        self._size = None
        self._gt = None

    @property
    def image_size(self) -> tuple[int, int]:
        if self._size is None:
            img = cv2.imread(str(self.path / self.color_list[0][1]), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise InputError(f"{self.path / self.color_list[0][1]}: not a readable image")
            self._size = (img.shape[1], img.shape[0])
        return self._size

    def _intrinsics_and_source(self) -> tuple[CameraIntrinsics, str]:
        w, h = self.image_size
        if self._intrinsics_override is not None:
            k, source = self._intrinsics_override, "given"
        else:
            sensor = tum_sensor(self.path)
            if sensor is None:
                raise InputError(f"{self.path}: cannot tell the TUM sensor from the folder name (no "
                                 f"freiburg1/2/3 in it); give the intrinsics with {INTRINSICS_FLAGS}")
            k, source = TUM_INTRINSICS[sensor], f"TUM {sensor} default"
        if (k.width, k.height) != (w, h):
            raise InputError(f"{self.path}: intrinsics are for {k.width}x{k.height} but the images are "
                             f"{w}x{h}; give the intrinsics with {INTRINSICS_FLAGS}")
        return k, source

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics_and_source()[0]

    @property
    def ground_truth(self) -> Trajectory | None:
        gt_file = self.path / "groundtruth.txt"
        if self._gt is None and gt_file.is_file():
            self._gt = read_tum_trajectory(gt_file)
        return self._gt

    def _pair_events(self):
        pairer = StampPairer(self.sync_tolerance)
        merged = sorted([(s, COLOR, f) for s, f in self.color_list] +
                        [(s, DEPTH, f) for s, f in self.depth_list], key=lambda e: (e[0], e[1]))
        for stamp, side, name in merged:
            yield from pairer.push(side, stamp, name)
        yield from pairer.finish()

    def _read_color(self, name: str) -> np.ndarray | None:
        flag = cv2.IMREAD_GRAYSCALE if self.color_mode == "gray" else cv2.IMREAD_COLOR
        return cv2.imread(str(self.path / name), flag)

    def _read_depth(self, name: str) -> np.ndarray | None:
        raw = cv2.imread(str(self.path / name), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
            return None
        return raw.astype(np.float32) / np.float32(TUM_DEPTH_SCALE)

    def frames(self, start: int = 0, stop: int | None = None, stride: int = 1) -> Iterator[RGBDFrame]:
        check_range(start, stop, stride)
        stats = self.stats = _empty_stats()
        index = 0
        checked = False
        for ev in self._pair_events():
            if isinstance(ev, Unpaired):
                stats["unpaired_color" if ev.side == COLOR else "unpaired_depth"] += 1
                continue
            i = index
            index += 1
            if stop is not None and i >= stop:
                return
            stats["paired"] += 1
            if i < start or (i - start) % stride:
                continue
            color, depth = self._read_color(ev.color), self._read_depth(ev.depth)
            if color is None or depth is None:
                bad = ev.color if color is None else ev.depth
                stats["corrupt"].append((ev.color_stamp, f"{bad}: missing or not a valid "
                                         f"{'colour' if color is None else '16-bit depth'} PNG"))
                continue
            if color.shape[:2] != depth.shape:
                msg = (f"colour {ev.color} is {color.shape[1]}x{color.shape[0]} but depth {ev.depth} is "
                       f"{depth.shape[1]}x{depth.shape[0]}")
                if not checked:
                    raise InputError(f"{self.path}: {msg}; depth must be registered to colour")
                stats["corrupt"].append((ev.color_stamp, msg))
                continue
            checked = True
            yield RGBDFrame(i, ev.color_stamp, color, depth, depth_stamp=ev.depth_stamp,
                            meta={"color_file": ev.color, "depth_file": ev.depth})

    def summary(self) -> LogSummary:
        stats = self.stats = _empty_stats()
        pairs = []
        for ev in self._pair_events():
            if isinstance(ev, Unpaired):
                stats["unpaired_color" if ev.side == COLOR else "unpaired_depth"] += 1
            else:
                pairs.append(ev)
        stats["paired"] = len(pairs)
        fractions = []
        for ev in pairs[:: max(1, len(pairs) // DEPTH_SAMPLES)]:
            depth = self._read_depth(ev.depth)
            if depth is None:
                stats["corrupt"].append((ev.color_stamp, f"{ev.depth}: missing or not a 16-bit PNG"))
            else:
                fractions.append(depth_valid_fraction(depth))
        w, h = self.image_size
        gt = self.ground_truth
        s = LogSummary(
            path=str(self.path), format="TUM RGB-D folder", color_topic="rgb.txt",
            depth_topic="depth.txt", info_topic=None, color_encoding="png (8-bit)",
            depth_encoding=f"png (16-bit, {TUM_DEPTH_SCALE:g} per m)", width=w, height=h,
            frames=len(pairs), color_messages=len(self.color_list), depth_messages=len(self.depth_list),
            unpaired_color=stats["unpaired_color"], unpaired_depth=stats["unpaired_depth"],
            corrupt=len(stats["corrupt"]),
            first_stamp=pairs[0].color_stamp if pairs else None,
            last_stamp=pairs[-1].color_stamp if pairs else None,
            ground_truth_poses=len(gt) if gt is not None else 0,
            depth_valid_fraction=float(np.mean(fractions)) if fractions else None,
            depth_frames_sampled=len(fractions))
        try:
            s.intrinsics, s.intrinsics_source = self._intrinsics_and_source()
        except InputError as exc:
            s.notes.append(str(exc))
        if s.depth_all_invalid:
            s.notes.append("depth is invalid (0) in every sampled frame")
        return s
