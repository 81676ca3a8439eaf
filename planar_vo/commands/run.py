"""Estimate raw (frame-to-frame) and smoothed (pose-graph) trajectories from an RGB-D log."""
from __future__ import annotations

import argparse


def add_input_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("input")
    g.add_argument("--color-topic", help="colour image topic (default: found automatically)")
    g.add_argument("--depth-topic", help="depth image topic (default: found automatically)")
    g.add_argument("--info-topic", help="CameraInfo / CameraCalibration topic")
    g.add_argument("--odom-topic", help="wheel odometry topic: nav_msgs/Odometry, /tf (odom -> base_link) or "
                                        "a pose topic (default: found automatically)")
    g.add_argument("--no-wheel-odom", action="store_true", help="ignore the log's wheel odometry")
    for k in ("fx", "fy", "cx", "cy"):
        g.add_argument(f"--{k}", type=float, help="intrinsics override in pixels (give all four)")
    g.add_argument("--pitch-deg", type=float, help="mount pitch, positive looking down (REP 103)")
    g.add_argument("--roll-deg", type=float, help="mount roll (REP 103)")
    g.add_argument("--height", type=float, dest="height_m", help="camera height above the floor [m]")
    g.add_argument("--start", type=int, help="first frame index")
    g.add_argument("--stop", type=int, help="stop before this frame index")
    g.add_argument("--stride", type=int, help="use every N-th frame")


def overrides_from_args(args: argparse.Namespace) -> dict:
    """Nested config overrides from the flags that were given."""
    ov: dict = {"input": {}, "output": {}}
    levelling: dict = {}
    for k in ("color_topic", "depth_topic", "info_topic", "odom_topic", "fx", "fy", "cx", "cy", "start", "stop", "stride"):
        v = getattr(args, k, None)
        if v is not None:
            ov["input"][k] = v
    for k in ("pitch_deg", "roll_deg", "height_m"):
        v = getattr(args, k, None)
        if v is not None:
            levelling[k] = v
    if levelling:
        ov["frontend"] = {"levelling": levelling}
    if getattr(args, "no_wheel_odom", False):
        ov["backend"] = {"wheel_odom": False}
    if getattr(args, "online", False):
        ov["solver"] = "online"
    if getattr(args, "no_loops", False):
        ov["loops"] = {"enabled": False}
    if getattr(args, "no_plot", False):
        ov["output"]["plot"] = False
    if getattr(args, "poses_format", None) is not None:
        ov["output"]["poses_format"] = args.poses_format
    return {k: v for k, v in ov.items() if v != {}}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="MCAP log (ROS 2, ROS 1 or Foxglove), ROS 1 .bag, rosbag2 folder or TUM RGB-D folder")
    p.add_argument("--out", required=True, help="run folder to write (created if missing)")
    p.add_argument("--config", help="YAML configuration file (see config.yaml of any run)")
    p.add_argument("--online", action="store_true", help="iSAM2 per frame instead of batch LM")
    p.add_argument("--no-loops", action="store_true", help="no loop closure (keyframes, place recognition)")
    p.add_argument("--gt", help="ground truth (TUM) to draw in trajectory.png")
    p.add_argument("--no-plot", action="store_true", help="skip trajectory.png")
    p.add_argument("--poses-format", choices=("auto", "ros2", "foxglove"),
                   help="poses.mcap schemas: ROS 2 messages (evo_traj bag2, ROS tools, Foxglove) or Foxglove "
                        "protobuf; default auto: the log's family (Foxglove for Foxglove MCAP and TUM folders)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_input_arguments(p)


def main(args: argparse.Namespace) -> int:
    from planar_vo.config import load_config
    from planar_vo.pipeline import run

    config = load_config(args.config, overrides_from_args(args))
    result = run(args.log, args.out, config, progress=not args.quiet, gt_path=args.gt)
    print_summary(result)
    return exit_code(result)


#: Exit code of a run that finished but could not estimate the motion (report.json "motion").
EXIT_NOT_ESTIMATED = 4


def exit_code(result) -> int:
    """3 for a partial run, 4 when the motion was not estimated, else 0."""
    if result.partial:
        return 3
    if result.report.get("motion", {}).get("verdict") == "not_estimated":
        return EXIT_NOT_ESTIMATED
    return 0


def print_summary(result) -> None:
    r = result.report
    f = r["frames"]
    print(f"frames with a pose: {f['with_pose']} (direction-plus-point {f['estimated_dpp']}, "
          f"2-point {f['estimated_2pt']}, partial {f.get('partial', 0)}, bridged {f['bridged']}, "
          f"failed {f['failed']})")
    print(f"speed: {r['fps']} frames/s end to end")
    lc = r.get("loop_closure") or {}
    if lc.get("keyframes") is not None:
        unseen = (lc.get("not_accepted_by_reason") or {}).get("out_of_view", 0)
        print(f"loop closure: {lc['keyframes']} keyframes, {lc['candidates']} candidates, {lc['accepted']} closures "
              f"kept ({unseen} out of view, {lc['rejected'] - unseen} rejected by verification, "
              f"{lc['removed_by_graph']} removed by the graph)")
    walls = (r.get("backend") or {}).get("walls") or {}
    if walls.get("factors"):
        print(f"walls: {walls['landmarks']} wall landmarks, {walls['factors']} offset factors "
              f"({walls['associated']} of {walls['observations']} wall sightings associated)")
    wo = r.get("wheel_odometry") or {}
    if wo.get("used"):
        print(f"wheel odometry: {wo['topic']} ({wo['source']}), a factor on {wo['steps_with_factor']} steps, "
              f"{wo['bridged_replaced']} bridged steps carried by it")
    for key, bad in (("motion", ("not_estimated", "degraded")), ("planarity", ("not_planar", "unverified"))):
        sec = r.get(key, {})
        if sec.get("verdict") in bad:
            print(f"warning: {sec['message']}")
    if result.partial:
        print(f"partial run: {result.stop_reason}; results so far written")
    print(f"wrote {result.out_dir}/: " + ", ".join(sorted(p.split('/')[-1] for p in result.files.values())))
