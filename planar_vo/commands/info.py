"""Show what a run would read from a log: topics, frames, rate, calibration, mount, ground truth.

Exit status: 0; 2 if the log cannot be used (no calibration, depth invalid everywhere,
unreadable); 3 if the log is cut short (what was readable is still described).
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from planar_vo.io.cliargs import add_log_arguments
    add_log_arguments(parser)


def main(args: argparse.Namespace) -> int:
    from planar_vo.core.errors import InputError, PartialResult
    from planar_vo.io.cliargs import open_log_from_args

    with open_log_from_args(args) as log:
        summary = log.summary()
    print(summary)
    if summary.truncated:
        raise PartialResult(f"{args.log}: log is cut short ({summary.truncated}); "
                            f"{summary.frames} frames are readable")
    if summary.intrinsics is None:
        raise InputError(summary.notes[0] if summary.notes else
                         f"{args.log}: no intrinsics; give --fx/--fy/--cx/--cy")
    if summary.depth_all_invalid:
        raise InputError(f"{args.log}: depth on {summary.depth_topic} is invalid (0, NaN or inf) in all "
                         f"{summary.depth_frames_sampled} sampled frames; check the depth topic "
                         "(--depth-topic) and its encoding")
    return 0
