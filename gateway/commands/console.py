"""``gateway console PORT``: the host-side client for a gateway's serial maintenance console.

Runs on the fitter's laptop. Lines are edited locally (readline: arrow keys, history
of this run), sent whole, and each reply is printed once the console's prompt (or, in
JSON mode, a complete JSON line) has arrived. The PIN is read without echo. The
console's own echo of the sent line is removed. ``exit``/``quit`` or Ctrl-D leave;
Ctrl-C cancels the line being typed. ``python -m serial.tools.miniterm PORT
115200`` works too (docs/console.md).

``gateway console hash-pin`` makes the ``[serial] pin_hash`` line for the gateway's config
instead: it reads the PIN without echo (twice, from a terminal; one line from a pipe)
and prints the salted scrypt hash (``gateway.pin``).
"""

from __future__ import annotations

import argparse
import contextlib
import getpass
import json
import re
import sys
import time
from typing import Protocol

import serial

from gateway.errors import InputError
from gateway.pin import hash_pin, pin_problem

PROMPT_AT_END = re.compile(rb"(railgw[>#] |PIN: )$")
LOCAL_EXIT = ("exit", "quit")


class Transport(Protocol):
    """A pyserial-like port: ``read`` returns what arrived within its timeout."""

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...


def _json_line_done(buf: bytes) -> bool:
    if not buf.endswith(b"\n"):
        return False
    last = buf.rstrip().rsplit(b"\n", 1)[-1].strip()
    if not last.startswith(b"{"):
        return False
    try:
        return isinstance(json.loads(last), dict)
    except ValueError:
        return False


class ConsoleClient:
    """One conversation with the console over ``port``; :meth:`exchange` per line."""

    def __init__(self, port: Transport, *, timeout_s: float = 5.0) -> None:
        self._port = port
        self._timeout_s = timeout_s
        self.prompt = "railgw> "

    def _read_reply(self) -> bytes:
        buf = bytearray()
        deadline = time.monotonic() + self._timeout_s
        while time.monotonic() < deadline:
            chunk = self._port.read(4096)
            if chunk:
                buf += chunk
                if PROMPT_AT_END.search(buf) or _json_line_done(bytes(buf)):
                    break
        return bytes(buf)

    def hello(self) -> str:
        """Wake the console with an empty line; returns whatever preceded the prompt."""
        return self.exchange("")

    def exchange(self, line: str) -> str:
        """Send ``line``; returns the reply text (no echo, no prompt, ``\\n`` line ends)
        and remembers the prompt that ended it in :attr:`prompt` ('' in JSON mode)."""
        sent = line.encode("ascii", errors="replace")
        self._port.write(sent + b"\r")
        raw = self._read_reply()
        m = PROMPT_AT_END.search(raw)
        self.prompt = m.group(1).decode() if m else ""
        body = raw[:m.start()] if m else raw
        if body.startswith(sent + b"\r\n"):
            body = body[len(sent) + 2:]
        elif body.startswith(b"\r\n"):
            body = body[2:]
        return body.decode("ascii", errors="replace").replace("\r\n", "\n").rstrip("\n")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("console", help="talk to a gateway's serial maintenance console",
                       description="Interactive client for the gateway's maintenance port "
                                   "(line editing and history on this side). "
                                   "'console hash-pin' prints a [serial] pin_hash for a PIN "
                                   "read without echo.")
    p.add_argument("port", metavar="PORT",
                   help="serial device, e.g. /dev/ttyUSB0 or COM3; or 'hash-pin'")
    p.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--timeout", type=float, default=5.0,
                   help="seconds to wait for a reply (default 5)")
    p.set_defaults(func=run)


def read_pin(stdin_is_tty: bool | None = None) -> str:
    """The PIN: typed twice without echo on a terminal, else the first line of stdin."""
    tty = sys.stdin.isatty() if stdin_is_tty is None else stdin_is_tty
    if not tty:
        line = sys.stdin.readline()
        return line.rstrip("\r\n")
    pin = getpass.getpass("new console PIN: ")
    problem = pin_problem(pin)
    if problem:
        raise InputError(problem)
    if getpass.getpass("the same PIN again: ") != pin:
        raise InputError("expected the same PIN twice, got two different ones")
    return pin


def hash_pin_command() -> int:
    """``console hash-pin``: print the PIN's hash (``scrypt$...``) for ``[serial] pin_hash``."""
    print(hash_pin(read_pin()))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.port == "hash-pin":
        return hash_pin_command()
    with contextlib.suppress(ImportError):  # Windows without pyreadline: plain input()
        import readline  # noqa: F401  (line editing and history for input())
    try:
        port = serial.Serial(args.port, args.baud, timeout=0.05, write_timeout=2.0)
    except (serial.SerialException, OSError, ValueError) as err:
        raise InputError(f"expected a serial port to open, got {args.port!r}: {err}") from err
    with port:
        client = ConsoleClient(port, timeout_s=args.timeout)
        banner = client.hello()
        if banner:
            print(banner)
        print("(local: 'exit' or Ctrl-D leaves this client)")
        return _loop(client)


def _loop(client: ConsoleClient) -> int:
    while True:
        prompt = client.prompt or "json> "
        try:
            line = getpass.getpass(prompt) if prompt == "PIN: " else input(prompt)
        except EOFError:
            print()
            return 0
        except KeyboardInterrupt:  # cancel the line being typed; nothing is sent
            print()
            continue
        if line.strip().lower() in LOCAL_EXIT and client.prompt != "PIN: ":
            return 0
        try:
            reply = client.exchange(line)
        except (serial.SerialException, OSError) as err:
            print(f"port error: {err}")
            return 1
        if reply:
            print(reply)
