"""Command-line entry point ``planar-vo``.

Each sub-command lives in its own module exposing ``add_arguments(parser)`` and
``main(args) -> int``; heavy imports (open3d, gtsam) happen inside ``main`` so that
``--help`` stays fast. Errors the user can fix arrive as :class:`PlanarVOError` and
are printed as one line; unexpected ones too (with ``--debug`` for the traceback).
"""
from __future__ import annotations

import argparse
import importlib
import sys

from planar_vo import __version__
from planar_vo.core.errors import PlanarVOError

#: name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("planar_vo.commands.demo", "run the whole job on the shipped sample and evaluate it"),
    "run": ("planar_vo.commands.run", "estimate raw and smoothed trajectories from an RGB-D log"),
    "batch": ("planar_vo.commands.batch", "run many logs as one Ray task each, resumable, with one summary"),
    "evaluate": ("planar_vo.commands.evaluate", "compare a run's trajectories with ground truth"),
    "info": ("planar_vo.commands.info", "show what a run would read from a log"),
    "convert": ("planar_vo.commands.convert", "convert a TUM RGB-D folder to MCAP"),
    "synth": ("planar_vo.commands.synth", "render a synthetic corridor log with ground truth"),
    "bench": ("planar_vo.commands.bench", "benchmarks: solvers, frontend, backend, io, peers, run, sweep, compare, batch, wheel, places, loops"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="planar-vo",
        description="Planar RGB-D visual odometry with a GTSAM pose-graph back-end.",
    )
    parser.add_argument("--version", action="version", version=f"planar-vo {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=help_text, description=(mod.__doc__ or help_text).strip().splitlines()[0])
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show tracebacks of unexpected errors")
        mod.add_arguments(p)
        p.set_defaults(_main=mod.main)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args._main(args) or 0)
    except PlanarVOError as exc:
        print(f"planar-vo {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"planar-vo {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the CLI never shows a bare traceback
        if getattr(args, "debug", False):
            raise
        print(f"planar-vo {args.command}: internal error: {type(exc).__name__}: {exc} "
              f"(rerun with --debug for the traceback and report it)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
