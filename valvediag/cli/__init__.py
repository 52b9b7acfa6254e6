"""The ``valvediag`` command line.

Each command lives in its own module with a ``register(subparsers)`` function
that adds its parser and sets ``func`` (called with the parsed arguments,
returning an exit code).
"""
from __future__ import annotations

import argparse
import importlib
import sys

from .. import __version__

#: Command modules, in the order ``--help`` lists them.
COMMANDS = ("bi", "reproduce", "synth", "scan", "model")


class CommandError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="valvediag",
        description="Find sticky (stiction) and loose (backlash) control valves in integrating "
                    "loops from historian data, with the Backlash Index of Farenzena & "
                    "Trierweiler (2012).",
        epilog="Run 'valvediag COMMAND --help' for the options of a command.")
    parser.add_argument("--version", action="version", version=f"valvediag {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:   # a command still being written
            if exc.name == f"{__name__}.{name}":
                continue
            raise
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except CommandError as exc:
        print(f"valvediag {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":   # python -m valvediag.cli
    sys.exit(main())
