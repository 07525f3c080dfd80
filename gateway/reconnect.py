"""Reopen-with-backoff: the one delay rule of every thread that reopens a lost device.

The CAN receive thread (``gateway.can.source``) and the console's serial thread
(``gateway.console.port``) both loop "open, serve, lose it, wait, reopen". The wait
starts at ``min_s``, doubles after every pause up to ``max_s``, and drops back to
``min_s`` when the caller says the device worked (``reset()``). The waiting itself is
injected (``wait(delay_s)``, e.g. a stop event's ``wait`` so that closing the thread
cuts the pause short), so a test drives it without sleeping.

It lives at the package root, below every stage, because both ``can/`` and
``console/`` use it; it imports nothing from ``gateway``.
"""

from __future__ import annotations

from collections.abc import Callable


class Backoff:
    """Exponential reopen delays in seconds: ``min_s``, doubled per pause, capped at ``max_s``.

    Usage in a reopen loop::

        backoff = Backoff(0.2, 10.0, wait=stop.wait)
        while not stop.is_set():
            try:
                dev = open_device()
            except OSError:
                backoff.pause()          # waits delay_s, then doubles it
                continue
            serve(dev)
            backoff.reset()              # it worked: the next loss waits min_s again
    """

    def __init__(self, min_s: float, max_s: float, *,
                 wait: Callable[[float], object]) -> None:
        if not 0 < min_s <= max_s:
            raise ValueError(f"expected 0 < reopen_min_s <= reopen_max_s, got "
                             f"{min_s}, {max_s}")
        self.min_s = min_s
        self.max_s = max_s
        self._wait = wait
        self.delay_s = min_s
        """The pause the next :meth:`pause` waits (s); log it before pausing."""

    def pause(self) -> None:
        """Wait ``delay_s`` (through the injected ``wait``), then double it, up to ``max_s``."""
        self._wait(self.delay_s)
        self.delay_s = min(self.delay_s * 2, self.max_s)

    def reset(self) -> None:
        """The device worked: the next pause is ``min_s`` again."""
        self.delay_s = self.min_s
