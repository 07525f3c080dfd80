"""The ``python -m gateway`` command line: dispatch to one module per subcommand.

Each module in :data:`COMMANDS` has ``register(subparsers)``, which adds its parser
and sets ``func`` to a ``run(args) -> int``. Deliberate failures (GatewayError) become
one line on stderr and the error's exit code; never a traceback. A usage error is one
line too (``prog: error: ...``, exit 2): every option has a checked domain, through the
argparse types defined here once (:func:`real`, :func:`integer`, :data:`SEED`,
:func:`output_path`, :func:`config_value`) and shared by every command.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.metadata
import logging
import math
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn

import can

from gateway import __version__
from gateway.errors import GatewayError, InputError

COMMANDS: tuple[str, ...] = (
    "gateway.commands.model",
    "gateway.commands.estimate",
    "gateway.commands.identify",
    "gateway.commands.console",
    "gateway.commands.run",
    "gateway.commands.replay",
    "gateway.commands.fleet",
)
ENTRY_POINT_GROUP = "railgw.commands"
"""Subcommands from other distributions (``name = "package.module"``), found as python-can
finds interface plugins: ``demo`` and ``bench`` live in firmware_sim, which the gateway
never imports."""


def _plugins() -> dict[str, str]:
    """Entry-point subcommands: command name -> module name."""
    return {ep.name: ep.value for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``prog: error: ...``) and exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message.splitlines()[0] if message else ''}\n")


def _bound(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def real(lo: float, hi: float, *, lo_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite float in [lo, hi] (``(lo, hi]`` with ``lo_open``)."""
    low = "(" if lo_open else "["

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        inside = (value > lo if lo_open else value >= lo) and value <= hi
        if not (math.isfinite(value) and inside):
            raise argparse.ArgumentTypeError(
                f"expected a finite number in {low}{_bound(lo)}, {_bound(hi)}], got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


def integer(lo: int, hi: int) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi]."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], got "
                                             f"{text!r}")
        return value

    parse.__name__ = "integer"
    return parse


SEED = integer(0, 2**32 - 1)
"""Random seeds: numpy's are non-negative; 32 bits, as ``[estimator] seed``."""
SPEED_MPS = real(0.1, 150.0)
"""Vehicle speeds: 150 m/s (540 km/h) is beyond any service train; the model divides by
the speed, and below 0.1 m/s its creep terms are meaningless."""


def config_value(section: str, key: str) -> Callable[[str], Any]:
    """An argparse type for an override of ``[section] key``: the config's own domain."""
    from gateway.config import DOMAINS, Config, check_value

    default = getattr(getattr(Config(), section), key)
    domain = DOMAINS[(section, key)]

    def parse(text: str) -> Any:
        try:
            value = type(default)(text) if not isinstance(default, float) else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {type(default).__name__} for "
                                             f"[{section}] {key}, got {text!r}") from None
        problem = check_value(section, key, value)
        if problem:
            raise argparse.ArgumentTypeError(f"[{section}] {key}: {problem}")
        return value

    parse.__name__ = type(domain).__name__
    return parse


def output_path(text: str) -> str:
    """An argparse type: a file we can create: its directory exists and is writable."""
    if not text or "\0" in text:
        raise argparse.ArgumentTypeError(f"expected an output file path, got {text!r}")
    p = Path(text)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"expected an output file, got directory {text!r}")
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"expected an existing directory for {text!r}, got "
                                         f"no directory {str(parent)!r}")
    if not os.access(parent, os.W_OK):
        raise argparse.ArgumentTypeError(f"expected a writable directory for {text!r}, got "
                                         f"{str(parent)!r} not writable")
    return text


def output_dir(text: str) -> str:
    """An argparse type: a directory that exists or can be made (its parent exists)."""
    if not text or "\0" in text:
        raise argparse.ArgumentTypeError(f"expected a directory path, got {text!r}")
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise argparse.ArgumentTypeError(f"expected a directory, got file {text!r}")
    if not p.exists():
        output_path(text)
    return text


@contextlib.contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """Turn an OSError while writing ``path`` into a one-line InputError."""
    try:
        yield
    except OSError as err:
        raise InputError(f"{path}: expected a writable file, got "
                         f"{err.strerror or err}") from err


def _selected(argv: Sequence[str]) -> tuple[str, ...]:
    """Only the module of the command being run, so that e.g. ``run`` does not import the
    offline-identification stack; every module when the command is unknown or absent."""
    words = [a for a in argv if not a.startswith("-")]
    plugins = _plugins()
    if words:
        module = f"gateway.commands.{words[0]}"
        if module in COMMANDS:
            return (module,)
        if words[0] in plugins:
            return (plugins[words[0]],)
    return COMMANDS + tuple(plugins.values())


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser with every available subcommand (or just the one in argv)."""
    parser = OneLineParser(
        prog="python -m gateway",
        description="Railway suspension condition-monitoring gateway.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in _selected(argv if argv is not None else []):
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
