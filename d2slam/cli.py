"""The ``d2slam`` command line: a thin dispatcher over ``d2slam.commands.*``."""

from __future__ import annotations

import argparse
import importlib
import sys

from d2slam import __version__
from d2slam.errors import D2SlamError

# Subcommand modules, in the order ``d2slam --help`` lists them.
COMMANDS = [
    "bench",
    "synth",
    "demo",
    "segment",
    "vocab",
    "download",
    "assets",
    "run",
    "eval",
    "study",
    "docs",
    "cache",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="d2slam",
        description="D2SLAM reproduction: synthetic dynamic RGB-D benchmark, TUM data, SLAM engine, dynamic "
        "keypoint filtering, evaluation and the study. Run `d2slam COMMAND --help` for each command.",
    )
    parser.add_argument("--version", action="version", version=f"d2slam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"d2slam.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()  # imports every command: a Ctrl-C may come meanwhile
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        code = args.func(args)
    except D2SlamError as exc:
        print(f"d2slam: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("d2slam: interrupted", file=sys.stderr)
        return 130
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
