"""The fitter's laptop as a pseudo-terminal pair: tests and demos drive a real console port.

:class:`PtyTerminal` owns the master side of ``os.openpty()`` and exposes the slave
under a stable symlink (``path``), which is what the console's port opens, like a
``/dev/serial/by-id`` link. :meth:`PtyTerminal.unplug` / :meth:`PtyTerminal.replug`
pull the cable (close the pair and remove the link) and plug a new pair in under the
same path. :func:`console_on_pty` runs a whole console (engine + port thread) against
any :class:`~gateway.console.view.ServiceView`, for the unit tests and for the
end-to-end test against the running service. Linux/POSIX only; no sleeps: reads wait
on ``select`` with a deadline.
"""

from __future__ import annotations

import json
import os
import re
import select
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from gateway.console.engine import Console
from gateway.console.port import ConsolePort
from gateway.console.session import ConsoleLimits
from gateway.console.view import ServiceView

PROMPT_AT_END = re.compile(rb"(railgw[>#] |PIN: )$")


class TerminalTimeoutError(AssertionError):
    """The console did not answer as expected in time (carries what did arrive)."""


class PtyTerminal:
    """The master end of a pty pair whose slave is reachable at ``path`` (a symlink)."""

    def __init__(self, directory: str | Path, name: str = "ttyRAILGW0") -> None:
        self.path = str(Path(directory) / name)
        self._master = -1
        self._slave = -1
        self._pending = bytearray()
        self.plugs = 0
        self._plug()

    def __enter__(self) -> PtyTerminal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # raw from the start: no echo or CR/LF mangling before pyserial
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        os.symlink(os.ttyname(slave), self.path)
        self.plugs += 1

    def unplug(self) -> None:
        """Pull the cable: close both ends of the pair and remove the device link."""
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1
        self._pending.clear()
        if os.path.lexists(self.path):
            os.unlink(self.path)

    def replug(self) -> None:
        """Pull the cable and plug a new pair in under the same ``path``."""
        self.unplug()
        self._plug()

    def close(self) -> None:
        """Unplug for good; idempotent."""
        self.unplug()

    # -- talking ---------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        """Send raw bytes to the console, all of them; while waiting for room, what the
        console sends back is kept for the next read (so neither side can block)."""
        view = memoryview(data)
        while view:
            readable, writable, _ = select.select([self._master], [self._master], [], 1.0)
            if readable:
                self._drain()
            if not writable:
                continue
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                continue
            view = view[n:]

    def _drain(self) -> None:
        try:
            self._pending += os.read(self._master, 65536)
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:  # EIO: nobody has the slave open at the moment
            pass

    def read(self, size: int = 65536, timeout_s: float = 0.05) -> bytes:
        """Up to ``size`` bytes, waiting at most ``timeout_s`` for the first (b"" if none);
        the pyserial-like read used by the host client in tests."""
        if not self._pending:
            ready, _, _ = select.select([self._master], [], [], timeout_s)
            if ready:
                self._drain()
        out, self._pending = bytes(self._pending[:size]), self._pending[size:]
        return out

    def read_until(self, done: Callable[[bytes], bool], timeout_s: float = 5.0) -> bytes:
        """Read until ``done(received)`` is true; TerminalTimeoutError after ``timeout_s``."""
        got = bytearray()
        deadline = time.monotonic() + timeout_s
        while True:
            got += self._pending
            self._pending.clear()
            if done(bytes(got)):
                return bytes(got)
            left = deadline - time.monotonic()
            if left <= 0:
                raise TerminalTimeoutError(f"no complete reply within {timeout_s} s; "
                                           f"got {bytes(got)[-2000:]!r}")
            ready, _, _ = select.select([self._master], [], [], left)
            if ready:
                self._drain()

    def read_prompt(self, timeout_s: float = 5.0) -> str:
        """Everything up to and including the next prompt, as text with CRLF."""
        return self.read_until(lambda b: bool(PROMPT_AT_END.search(b)), timeout_s).decode()

    def command(self, line: str, timeout_s: float = 5.0) -> str:
        """Send one text-mode command; returns the reply without echo and prompt, with
        ``\\n`` line ends. The prompt that ended it is in :attr:`last_prompt`."""
        self.write(line.encode("ascii") + b"\r")
        raw = self.read_prompt(timeout_s)
        m = PROMPT_AT_END.search(raw.encode())
        self.last_prompt = m.group(1).decode() if m else ""
        body = raw[:len(raw) - len(self.last_prompt)]
        echoed = line + "\r\n"
        if body.startswith(echoed):
            body = body[len(echoed):]
        elif body.startswith("\r\n"):  # PIN: not echoed, just the line end
            body = body[2:]
        return body.replace("\r\n", "\n").rstrip("\n")

    def json_command(self, line: str, timeout_s: float = 5.0) -> dict[str, Any]:
        """Send one command in JSON mode; returns the parsed reply object."""
        self.write(line.encode("ascii") + b"\r")
        raw = self.read_until(lambda b: b.endswith(b"\r\n"), timeout_s)
        obj = json.loads(raw.decode())
        if not isinstance(obj, dict):
            raise TerminalTimeoutError(f"expected one JSON object, got {raw!r}")
        return obj

    last_prompt: str = ""


@contextmanager
def console_on_pty(view: ServiceView, directory: str | Path, *, pin_hash: str = "",
                   limits: ConsoleLimits | None = None,
                   clock: Callable[[], float] = time.monotonic,
                   wall: Callable[[], float] = time.time,
                   reopen_min_s: float = 0.02, reopen_max_s: float = 0.2,
                   ) -> Iterator[tuple[PtyTerminal, ConsolePort]]:
    """A console port thread serving ``view`` on a fresh pty; yields ``(terminal, port)``
    once the banner has arrived, and closes both afterwards."""
    term = PtyTerminal(directory)
    console = Console(view, pin_hash=pin_hash, limits=limits, clock=clock, wall=wall,
                      port_name=term.path)
    port = ConsolePort(console, term.path, reopen_min_s=reopen_min_s,
                       reopen_max_s=reopen_max_s)
    try:
        port.start()
        term.read_prompt(timeout_s=10.0)
        yield term, port
    finally:
        port.close()
        term.close()
