"""Convert any readable RGB-D log (TUM folder, MCAP, ROS 1 bag, rosbag2 folder) to an MCAP log
(or another container with ``--container``), ground truth included.

Colour and depth become image topics named like the TUM ROS bags (``/camera/rgb/...``,
``/camera/depth/...``), the calibration a CameraInfo (or CameraCalibration), and the
ground truth ``/ground_truth`` poses. The default encodings are lossless (PNG colour,
32FC1 depth), so frames read back bit-exactly; ``--depth-encoding png`` is about 4x
smaller but rounds depth to whole millimetres.
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from planar_vo.io.cliargs import add_log_arguments
    from planar_vo.io.codecs import COLOR_ENCODINGS, DEPTH_ENCODINGS
    from planar_vo.io.rosbags_writer import CONTAINERS
    add_log_arguments(parser)
    parser.add_argument("output", help="MCAP file to write (a .bag file or a folder for --container)")
    parser.add_argument("--profile", choices=("ros2", "foxglove"), default="ros2",
                        help="message schemas: ROS 2 (CDR) or Foxglove (protobuf); default ros2")
    parser.add_argument("--container", choices=CONTAINERS, default="mcap",
                        help="mcap (default; --profile applies) | bag (ROS 1) | rosbag2-sqlite3 | rosbag2-mcap "
                             "(rosbag2 folder) | mcap-ros1 (MCAP in the ROS 1 profile)")
    parser.add_argument("--color-encoding", choices=COLOR_ENCODINGS, default="png",
                        help="default png (lossless)")
    parser.add_argument("--depth-encoding", choices=DEPTH_ENCODINGS, default="32FC1",
                        help="default 32FC1 (exact); png/16UC1/compressedDepth store millimetres")
    parser.add_argument("--jpeg-quality", type=int, default=90)
    parser.add_argument("--start", type=int, default=0, help="first frame index")
    parser.add_argument("--stop", type=int, default=None, help="stop before this frame index")
    parser.add_argument("--stride", type=int, default=1, help="keep every n-th frame")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")


def main(args: argparse.Namespace) -> int:
    import os
    import time
    from pathlib import Path

    from planar_vo.core.errors import InputError, PartialResult
    from planar_vo.io.cliargs import open_log_from_args
    from planar_vo.io.mcap_writer import LogTopics
    from planar_vo.io.rosbags_writer import open_log_writer

    out = Path(args.output)
    if out.exists() and not args.overwrite:
        raise InputError(f"{out} exists; pass --overwrite to replace it")
    if out.resolve() == Path(args.log).resolve():
        raise InputError(f"{out}: output would overwrite the input")
    if args.stride < 1 or args.start < 0:
        raise InputError("--start must be >= 0 and --stride >= 1")
    cc = "/compressed" if args.color_encoding in ("jpeg", "png") else ""
    dc = "/compressed" if args.depth_encoding in ("png", "compressedDepth") else ""
    topics = LogTopics(color=f"/camera/rgb/image_color{cc}", depth=f"/camera/depth/image{dc}",
                       info="/camera/rgb/camera_info")
    t0 = time.perf_counter()
    partial = None
    with open_log_from_args(args) as log:
        intrinsics = log.intrinsics
        gt = log.ground_truth
        mount = log.mount
        camera_frame = gt.child_frame_id if gt is not None and gt.child_frame_id else "camera_optical_frame"
        if getattr(log, "camera_frame", None):
            camera_frame = log.camera_frame
        if args.container != "mcap" and args.profile != "ros2":
            raise InputError(f"--profile {args.profile} applies to --container mcap only")
        with open_log_writer(out, intrinsics, container=args.container, profile=args.profile, mount=mount,
                             color_encoding=args.color_encoding, depth_encoding=args.depth_encoding,
                             topics=topics, jpeg_quality=args.jpeg_quality,
                             camera_frame=camera_frame) as writer:
            if gt is not None:
                for stamp, T in zip(gt.stamps, gt.poses):
                    writer.write_ground_truth(stamp, T)
            try:
                for frame in log.frames(args.start, args.stop, args.stride):
                    writer.write(frame)
            except PartialResult as exc:
                partial = exc  # keep what was readable, then report it
        stats = log.stats
    size = sum(f.stat().st_size for f in out.iterdir()) if out.is_dir() else os.path.getsize(out)
    print(f"wrote {out}: {writer.frames_written} frames, {writer.poses_written} ground-truth poses, "
          f"{size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s ({args.container}, {args.profile}, colour "
          f"{args.color_encoding}, depth {args.depth_encoding}); skipped {len(stats['corrupt'])} corrupt, "
          f"{stats['unpaired_color']} colour and {stats['unpaired_depth']} depth unpaired")
    if partial is not None:
        raise partial
    return 0
