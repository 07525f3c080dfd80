"""systemd's notify protocol: one datagram to ``$NOTIFY_SOCKET``; silent without it.

Written here rather than taken from a library: the protocol is one ``sendto`` of
``KEY=VALUE`` lines to a unix datagram socket (an abstract one when the path starts
with ``@``). READY, STATUS, WATCHDOG, EXTEND_TIMEOUT_USEC, STOPPING and RELOADING are
what the service uses.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


class Notifier:
    """Sends notifications; every method is a no-op when not run under systemd."""

    def __init__(self, address: str | None = None) -> None:
        addr = address if address is not None else os.environ.get("NOTIFY_SOCKET", "")
        self._address: str | bytes | None = None
        self._sock: socket.socket | None = None
        if addr:
            self._address = ("\0" + addr[1:]) if addr.startswith("@") else addr
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            # Never block the main loop: a unix datagram queue holds only
            # net.unix.max_dgram_qlen (default 10) messages, and a reader that falls behind
            # would otherwise stall the whole service inside sendto().
            self._sock.setblocking(False)
        self.dropped = 0
        """Notifications not sent because the receiver's queue was full."""
        usec = os.environ.get("WATCHDOG_USEC", "")
        pid = os.environ.get("WATCHDOG_PID", "")
        self.watchdog_s: float | None = None
        if usec.isdigit() and (not pid or pid == str(os.getpid())):
            self.watchdog_s = int(usec) / 1e6

    @property
    def enabled(self) -> bool:
        """Whether a notify socket is configured."""
        return self._sock is not None

    def notify(self, **fields: str | int) -> bool:
        """Send ``KEY=VALUE`` lines (keys upper-cased); False if not sent."""
        if self._sock is None or self._address is None:
            return False
        payload = "\n".join(f"{k.upper()}={v}" for k, v in fields.items()).encode()
        try:
            self._sock.sendto(payload, self._address)
            return True
        except BlockingIOError:
            self.dropped += 1
            log.debug("sd_notify to %s: receiver's queue full, %d dropped", self._address,
                      self.dropped)
            return False
        except OSError as err:
            log.warning("sd_notify to %s failed: %s", self._address, err)
            return False

    def ready(self, status: str = "") -> bool:
        """READY=1 (with an optional STATUS)."""
        return self.notify(READY=1, STATUS=status) if status else self.notify(READY=1)

    def status(self, text: str) -> bool:
        """STATUS=text (one line)."""
        return self.notify(STATUS=text.replace("\n", " "))

    def watchdog(self) -> bool:
        """WATCHDOG=1: only call while the pipeline makes progress."""
        return self.notify(WATCHDOG=1)

    def extend_timeout(self, seconds: float, status: str = "") -> bool:
        """EXTEND_TIMEOUT_USEC: the current state's time-out now ends ``seconds`` from now
        at the earliest (systemd >= 236; older ones ignore it), with an optional STATUS."""
        usec = max(0, int(seconds * 1e6))
        if status:
            return self.notify(EXTEND_TIMEOUT_USEC=usec, STATUS=status)
        return self.notify(EXTEND_TIMEOUT_USEC=usec)

    def stopping(self) -> bool:
        return self.notify(STOPPING=1)

    def reloading(self) -> bool:
        return self.notify(RELOADING=1)

    def close(self) -> None:
        """Idempotent."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
