"""Render a synthetic corridor RGB-D log (MCAP) with exact ground truth.

Writes OUT.mcap (or a ROS 1 bag, a rosbag2 folder: ``--container``) shaped like an iai_kinect2 recording (qhd colour and registered depth,
camera_info, the camera mount on /tf_static, the true camera pose on /ground_truth) and
OUT.gt.tum (TUM: t tx ty tz qx qy qz qw, camera optical frame in the world).
"""
from __future__ import annotations

import argparse
import os
import time

LAYOUT_HELP = ("straight: one corridor; lturn: a 90 deg left turn; loop: a rectangular corridor ring "
               "driven once around (--laps), back to the start; two_frames: a corridor meeting another at 60 deg "
               "(two local Manhattan frames); hall: an open hall, no wall within depth range for long stretches; "
               "building: a ring of corridors round a notched block, a 40 m lap (--lap-m) driven 1.5 times "
               "(--laps), doors and posters of few designs that repeat (loop closure); aliased: two corridors "
               "that look the same at different places, driven one after the other (wrong loop closures)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", help="output log path (.mcap); ground truth goes to <out>.gt.tum")
    parser.add_argument("--layout", default="lturn", help=LAYOUT_HELP + " (default: lturn)")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames at --rate Hz (default: 300; building: enough for --laps laps of "
                             "--lap-m metres)")
    parser.add_argument("--laps", type=float, default=None,
                        help="loop and building: laps driven; the ring is sized so that the frames drive this "
                             "many (default: 1 for loop, 1.5 for building)")
    parser.add_argument("--lap-m", type=float, default=None,
                        help="building without --frames: the lap length in m the frames are chosen for "
                             "(default: 40)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of scene, texture and noise (default: 0)")
    parser.add_argument("--profile", default="ros2", help="ros2 (iai_kinect2-like CDR) or foxglove (protobuf)")
    parser.add_argument("--container", default="mcap",
                        help="mcap (default) | bag (ROS 1 bag, OUT.bag) | rosbag2-sqlite3 | rosbag2-mcap "
                             "(rosbag2 folder OUT/) | mcap-ros1 (MCAP in the ROS 1 profile)")
    parser.add_argument("--texture", default="medium", help="none | low | medium | rich (default: medium)")
    parser.add_argument("--pitch-deg", type=float, default=10.0, help="camera pitch, positive down (default: 10)")
    parser.add_argument("--roll-deg", type=float, default=2.0, help="camera roll (REP 103, default: 2)")
    parser.add_argument("--height", type=float, default=0.8, help="camera height above the floor in m (default: 0.8)")
    parser.add_argument("--speed", type=float, default=0.4, help="cruise speed in m/s (default: 0.4)")
    parser.add_argument("--rate", type=float, default=10.0, help="frame rate in Hz (default: 10)")
    parser.add_argument("--size", default="960x540",
                        help="image size WxH; the Kinect v2 qhd intrinsics are scaled to it (default: 960x540)")
    parser.add_argument("--color-encoding", default="jpeg", help="jpeg | png | bgr8 | rgb8 | mono8 (default: jpeg)")
    parser.add_argument("--depth-encoding", default="png", help="png | compressedDepth | 16UC1 | 32FC1 (default: png)")
    parser.add_argument("--no-depth-noise", action="store_true",
                        help="ideal depth: no noise, quantisation, holes or dropouts")
    parser.add_argument("--sensor", default="ideal",
                        help="ideal | kinect2: kinect2 adds the Kinect v2 colour camera's auto-exposure, motion "
                             "blur, rolling shutter, unsynchronised colour/depth and flicker, and flying depth "
                             "pixels (default: ideal)")
    parser.add_argument("--randomize", action="store_true",
                        help="draw the scene, path wobble, mount, speed, rate, texture, lighting and sensor "
                             "effects from --seed (planar_vo.sim.synth_random.RANGES); --frames is then a "
                             "minimum, and the other scene flags are ignored")
    parser.add_argument("--speed-dips", action="store_true",
                        help="with --randomize: the base also slows down within its cruise (one dip and one more "
                             "per 30 s on average, down to a momentary stop, braking at up to 0.6 m/s^2)")
    w = parser.add_argument_group("wheel odometry (a differential-drive error model driven by the true path)")
    w.add_argument("--wheel-odom", action="store_true",
                   help="add wheel odometry: nav_msgs/Odometry on /odom (Foxglove profile: PoseInFrame)")
    w.add_argument("--wheel-odom-on", default="odom", choices=("odom", "tf"),
                   help="odom: an Odometry topic /odom; tf: the transform odom -> base_link on /tf (default: odom)")
    w.add_argument("--odom-scale", type=float, default=0.02, help="wheel travel scale error (default: 0.02 = +2 %%)")
    w.add_argument("--odom-wheelbase", type=float, default=0.03,
                   help="wheelbase error: turns come out scaled by 1 + this (default: 0.03)")
    w.add_argument("--odom-drift-deg-per-m", type=float, default=0.5,
                   help="heading drift in degrees per metre travelled (default: 0.5)")
    w.add_argument("--odom-noise", type=float, default=0.001,
                   help="wheel travel noise in m per sqrt(m) of travel (default: 0.001)")
    w.add_argument("--odom-rate", type=float, default=50.0,
                   help="odometry samples per second, at least the frame rate (default: 50)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")


#: SynthConfig field -> command-line flag, to name the flag in error messages.
_FLAGS = {"layout": "--layout", "n_frames": "--frames", "laps": "--laps", "texture": "--texture", "pitch_deg": "--pitch-deg",
          "roll_deg": "--roll-deg", "cam_height": "--height", "speed": "--speed", "rate_hz": "--rate",
          "width": "--size", "height": "--size", "fx": "--size", "fy": "--size"}


def _parse_size(text: str) -> tuple[int, int]:
    from planar_vo.core.errors import InputError
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 960x540") from None
    if w < 8 or h < 8 or w > 8192 or h > 8192:
        raise InputError(f"--size {text!r}: width and height must be between 8 and 8192 pixels")
    return w, h


def _frames(args: argparse.Namespace) -> int:
    """``--frames``, or its default: 300, or for ``building`` the frames of ``--laps`` laps of ``--lap-m``."""
    from planar_vo.core.errors import InputError
    from planar_vo.sim.synth import frames_for_laps
    from planar_vo.sim.synth_scene import BUILDING_LAP_M

    if args.lap_m is not None and (args.layout != "building" or args.frames is not None or not args.lap_m > 0):
        raise InputError(f"--lap-m {args.lap_m}: sizes the building layout when --frames is not given; "
                         "give a positive length with --layout building and no --frames")
    if args.frames is not None:
        return args.frames
    if args.layout != "building" or not (args.speed > 0 and args.rate > 0):
        return 300  # (SynthConfig names a bad --speed or --rate)
    laps = args.laps if args.laps is not None and args.laps > 0 else 1.5  # SynthConfig rejects a bad --laps
    return frames_for_laps(laps, args.lap_m or BUILDING_LAP_M, args.speed, args.rate)


def _wheel_odom_model(args: argparse.Namespace, seed: int):
    """The :class:`WheelOdomModel` of the flags (seeded with the log's seed), or None."""
    from planar_vo.core.errors import InputError
    from planar_vo.io.wheel_odom import WheelOdomModel

    if not getattr(args, "wheel_odom", False):
        return None
    try:
        return WheelOdomModel(scale=args.odom_scale, wheelbase=args.odom_wheelbase,
                              drift_deg_per_m=args.odom_drift_deg_per_m, noise=args.odom_noise,
                              rate_hz=args.odom_rate, seed=seed)
    except ValueError as exc:
        raise InputError(f"--wheel-odom: {exc} (see --odom-scale/--odom-wheelbase/--odom-drift-deg-per-m/"
                         "--odom-noise/--odom-rate)") from None


def main(args: argparse.Namespace) -> int:
    from planar_vo.core.errors import ConfigError, InputError
    from planar_vo.io.codecs import COLOR_ENCODINGS, DEPTH_ENCODINGS
    from planar_vo.io.mcap_writer import PROFILES
    from planar_vo.sim.synth import SENSOR_PRESETS, SynthConfig, with_sensor, write_synth_log
    from planar_vo.sim.synth_scene import CLOSED_LAYOUTS

    if args.profile not in PROFILES:
        raise InputError(f"--profile {args.profile!r}: use one of {', '.join(PROFILES)}")
    if args.color_encoding not in COLOR_ENCODINGS:
        raise InputError(f"--color-encoding {args.color_encoding!r}: use one of {', '.join(COLOR_ENCODINGS)}")
    if args.depth_encoding not in DEPTH_ENCODINGS:
        raise InputError(f"--depth-encoding {args.depth_encoding!r}: use one of {', '.join(DEPTH_ENCODINGS)}")
    if args.sensor not in SENSOR_PRESETS:
        raise InputError(f"--sensor {args.sensor!r}: use one of {', '.join(SENSOR_PRESETS)}")
    if args.speed_dips and not args.randomize:
        raise InputError("--speed-dips draws the dips from --seed: use it with --randomize")
    width, height = _parse_size(args.size)
    try:
        if args.randomize:
            from planar_vo.sim.synth_random import describe, randomized_config

            cfg = randomized_config(args.seed, args.layout, n_frames=args.frames or 300, speed_dips=args.speed_dips)
            print("randomized: " + ", ".join(f"{k}={v}" for k, v in describe(cfg).items()))
        else:
            cfg = SynthConfig(layout=args.layout, seed=args.seed, n_frames=_frames(args), rate_hz=args.rate,
                              speed=args.speed, texture=args.texture, pitch_deg=args.pitch_deg,
                              roll_deg=args.roll_deg, cam_height=args.height, depth_noise=not args.no_depth_noise,
                              laps=args.laps)
            cfg = with_sensor(cfg, args.sensor)
        if (width, height) != (cfg.width, cfg.height):
            cfg = cfg.at_resolution(width, height)
    except ConfigError as exc:
        msg = str(exc)
        for field, flag in _FLAGS.items():
            msg = msg.replace(f"SynthConfig.{field}:", f"{flag}:")
        raise InputError(msg) from None
    _check_container(args)
    odom = _wheel_odom_model(args, cfg.seed)
    t0 = time.perf_counter()
    paths = write_synth_log(cfg, args.out, profile=args.profile, color_encoding=args.color_encoding,
                            depth_encoding=args.depth_encoding, progress=not args.quiet,
                            container=args.container, wheel_odom=odom,
                            wheel_odom_on=getattr(args, "wheel_odom_on", "odom"))
    dt = time.perf_counter() - t0
    size_mb = _size(paths["log"]) / 1e6
    print(f"log: {paths['log']}  ({cfg.n_frames} frames {cfg.width}x{cfg.height}, {size_mb:.1f} MB, "
          f"{cfg.path_length:.1f} m, {cfg.n_frames / dt:.1f} frames/s)")
    print(f"ground truth: {paths['ground_truth']}")
    if cfg.layout in CLOSED_LAYOUTS:
        print(f"{cfg.layout}: a lap of {cfg.path_length / cfg.laps_used:.1f} m, driven {cfg.laps_used:g} times")
    if odom is not None:
        where = "/tf (odom -> base_link)" if args.wheel_odom_on == "tf" else "/odom"
        print(f"wheel odometry: {where}, scale {odom.scale:+g}, wheelbase {odom.wheelbase:+g}, "
              f"drift {odom.drift_deg_per_m:g} deg/m, noise {odom.noise:g} m/sqrt(m)")
    return 0


def _check_container(args: argparse.Namespace) -> None:
    """The output name fits the container: ``.mcap`` file, ``.bag`` file, or a new folder."""
    from planar_vo.core.errors import InputError
    from planar_vo.io.rosbags_writer import CONTAINERS
    out = str(args.out).rstrip("/")
    if args.container not in CONTAINERS:
        raise InputError(f"--container {args.container!r}: use one of {', '.join(CONTAINERS)}")
    if args.container != "mcap" and args.profile != "ros2":
        raise InputError(f"--profile {args.profile} applies to --container mcap only (ROS containers hold "
                         "ROS messages)")
    suffix = {"mcap": ".mcap", "mcap-ros1": ".mcap", "bag": ".bag"}.get(args.container)
    if suffix is not None and not out.endswith(suffix):
        raise InputError(f"output {args.out!r}: the log name must end in {suffix} for --container {args.container}")
    if suffix is None and (out.endswith((".mcap", ".bag", ".db3")) or os.path.isfile(out)):
        raise InputError(f"output {args.out!r}: --container {args.container} writes a folder; "
                         "give a folder name without a file suffix")


def _size(path: str) -> int:
    if os.path.isdir(path):
        return sum(os.path.getsize(os.path.join(path, f)) for f in os.listdir(path))
    return os.path.getsize(path)
