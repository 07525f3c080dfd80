"""The ``python -m gateway`` command line: dispatch to one module per subcommand.

Each module in :data:`COMMANDS` has ``register(subparsers)``, which adds its parser
and sets ``func`` to a ``run(args) -> int``. Deliberate failures (GatewayError) become
one line on stderr and the error's exit code; never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

import can

from gateway import __version__
from gateway.errors import GatewayError

COMMANDS: tuple[str, ...] = (
    "gateway.commands.model",
    "gateway.commands.estimate",
    "gateway.commands.bench",
    "gateway.commands.identify",
    "gateway.commands.console",
    "gateway.commands.run",
    "gateway.commands.replay",
    "gateway.commands.demo",
)


def _selected(argv: Sequence[str]) -> tuple[str, ...]:
    """Only the module of the command being run, so that e.g. ``run`` does not import the
    offline-identification stack; every module when the command is unknown or absent."""
    words = [a for a in argv if not a.startswith("-")]
    if words:
        module = f"gateway.commands.{words[0]}"
        if module in COMMANDS:
            return (module,)
    return COMMANDS


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser with every available subcommand (or just the one in argv)."""
    parser = argparse.ArgumentParser(
        prog="python -m gateway",
        description="Railway suspension condition-monitoring gateway.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in _selected(argv) if argv is not None else COMMANDS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as err:
            if err.name != name:
                raise
            continue
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    return dispatch(args)


def dispatch(args: argparse.Namespace) -> int:
    """Run ``args.func``; deliberate failures become one line on stderr and exit codes."""
    try:
        return int(args.func(args))
    except GatewayError as err:
        print(f"error: {err}", file=sys.stderr)
        return err.exit_code
    except can.CanError as err:
        print(f"error: CAN bus: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:                    # e.g. piped into head: not an error
        sys.stdout = open(os.devnull, "w")     # noqa: SIM115 - silences the exit flush
        return 0
