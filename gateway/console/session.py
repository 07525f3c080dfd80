"""Who may write on the console: PIN check, lockout, idle timeout and the command rate limit.

Everything here takes its time from an injected monotonic clock (``clock() -> s``), so
the tests step time instead of sleeping. Two lifetimes:

- :class:`PinGuard` lives as long as the console and persists through the service's
  state directory: failed attempts and the lockout survive a cable pull and a restart
  (neither may reset a brute-force counter);
- :class:`Session` lives for one connection: login state, mode, idle timer.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from gateway.errors import InputError
from gateway.pin import PinHash, parse_pin_hash, verify_pin

log = logging.getLogger(__name__)

Clock = Callable[[], float]
"""Monotonic seconds."""


@dataclass(frozen=True)
class ConsoleLimits:
    """The console's limits and timers (seconds, bytes, lines, commands per second).

    ``max_failures`` consecutive wrong PINs lock login (and every write) for
    ``lockout_s``; a logged-in session idle for ``idle_timeout_s`` is logged out; a PIN
    prompt left for ``pin_entry_timeout_s`` is abandoned. Commands are rate-limited by a
    token bucket (``rate_per_s``, ``burst``). A reply is cut at ``reply_max_bytes``.
    """

    max_line_bytes: int = 256
    reply_max_bytes: int = 16384
    rate_per_s: float = 20.0
    burst: int = 20
    max_failures: int = 5
    lockout_s: float = 300.0
    idle_timeout_s: float = 600.0
    pin_entry_timeout_s: float = 60.0
    history_max_hours: float = 31 * 24.0
    log_max_lines: int = 200

    def __post_init__(self) -> None:
        positive = ("max_line_bytes", "rate_per_s", "burst", "max_failures", "lockout_s",
                    "idle_timeout_s", "pin_entry_timeout_s", "history_max_hours",
                    "log_max_lines")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"expected {name} > 0, got {value!r}")
        if self.reply_max_bytes < 512:
            raise ValueError(f"expected reply_max_bytes >= 512, got {self.reply_max_bytes}")


class TokenBucket:
    """Rate limit: ``take()`` is True while tokens last; they refill at ``rate_per_s``."""

    def __init__(self, rate_per_s: float, burst: int, clock: Clock) -> None:
        self._rate = rate_per_s
        self._burst = float(burst)
        self._clock = clock
        self._tokens = float(burst)
        self._t = clock()

    def take(self) -> bool:
        now = self._clock()
        self._tokens = min(self._burst, self._tokens + max(0.0, now - self._t) * self._rate)
        self._t = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False


@dataclass(frozen=True)
class PinResult:
    """Outcome of one PIN attempt: ``ok``, or why not (``locked_s`` > 0 when locked)."""

    ok: bool
    message: str
    locked_s: float = 0.0


@dataclass(frozen=True)
class LockoutState:
    """What survives a restart: consecutive failed PINs and the lockout end (Unix s)."""

    failures: int = 0
    locked_until_unix_s: float = 0.0


class LockoutStore(Protocol):
    """Where the lockout persists (the service's state directory)."""

    def load_lockout(self) -> LockoutState | None: ...

    def save_lockout(self, state: LockoutState) -> bool: ...


class PinGuard:
    """Checks PINs against the configured salted hash and enforces the lockout.

    The failure count and the lockout are saved through ``persist`` at every change and
    loaded at start, so neither a cable pull nor a service restart resets them. The
    lockout end is stored as wall time (``wall``, Unix s) and never extends beyond
    ``lockout_s`` from now when loaded (a clock stepped back cannot lock for ever).
    """

    def __init__(self, pin_hash: str, limits: ConsoleLimits, clock: Clock, *,
                 wall: Clock = time.time, persist: LockoutStore | None = None) -> None:
        self._stored: PinHash | None = None
        self.problem = ""
        if pin_hash.strip():
            try:
                self._stored = parse_pin_hash(pin_hash)
            except InputError as err:
                self.problem = str(err)
        self.configured_but_invalid = bool(self.problem)
        self._limits = limits
        self._clock = clock
        self._wall = wall
        self._persist = persist
        self.failures = 0
        self._locked_until = -math.inf
        saved = persist.load_lockout() if persist is not None else None
        if saved is not None:
            self.failures = max(0, min(int(saved.failures), limits.max_failures - 1))
            left = min(saved.locked_until_unix_s - wall(), limits.lockout_s)
            if left > 0:
                self._locked_until = clock() + left

    @property
    def enabled(self) -> bool:
        """False when no (valid) PIN hash is configured: writes are then impossible."""
        return self._stored is not None

    def locked_for_s(self) -> float:
        """Seconds of lockout left (0 when not locked)."""
        return max(0.0, self._locked_until - self._clock())

    def _save(self) -> None:
        if self._persist is None:
            return
        left = self.locked_for_s()
        state = LockoutState(self.failures, self._wall() + left if left > 0 else 0.0)
        if not self._persist.save_lockout(state):
            log.error("console: the PIN lockout state could not be saved")

    def check(self, pin: str) -> PinResult:
        """One attempt; the ``max_failures``-th consecutive failure starts the lockout."""
        if self._stored is None:
            return PinResult(False, "login disabled: no PIN configured ([serial] pin_hash)")
        left = self.locked_for_s()
        if left > 0:
            return PinResult(False, f"console locked after {self._limits.max_failures} "
                                    f"failed PINs; try again in {math.ceil(left)} s", left)
        if verify_pin(pin, self._stored):
            if self.failures:
                self.failures = 0
                self._save()
            return PinResult(True, "PIN accepted")
        self.failures += 1
        if self.failures >= self._limits.max_failures:
            self.failures = 0
            self._locked_until = self._clock() + self._limits.lockout_s
            self._save()
            return PinResult(False, f"wrong PIN; console locked for "
                                    f"{math.ceil(self._limits.lockout_s)} s after "
                                    f"{self._limits.max_failures} failed attempts",
                             self._limits.lockout_s)
        self._save()
        left_tries = self._limits.max_failures - self.failures
        return PinResult(False, f"wrong PIN ({left_tries} attempt"
                                f"{'s' if left_tries != 1 else ''} left before lockout)")


class Session:
    """One connection's state: mode, login, PIN prompt and idle timer."""

    def __init__(self, number: int, limits: ConsoleLimits, clock: Clock, *,
                 echo: bool) -> None:
        self.number = number
        self._limits = limits
        self._clock = clock
        self.json = False
        self.echo = echo
        self.user: str | None = None
        self.pin_pending_since: float | None = None
        self.pin_shadow = False
        """The next line may be a PIN typed after a refused login: not echoed, not run
        unless it is a command, never repeated."""
        self.pending_user = ""
        self._last_s = clock()

    @property
    def logged_in(self) -> bool:
        return self.user is not None

    def touch(self) -> None:
        """A line arrived: restart the idle timer."""
        self._last_s = self._clock()

    def idle_expired(self) -> bool:
        """True (and logs out) when logged in and idle for longer than the timeout."""
        if self.user is not None and self._clock() - self._last_s > self._limits.idle_timeout_s:
            self.user = None
            return True
        return False

    def idle_left_s(self) -> float:
        return max(0.0, self._limits.idle_timeout_s - (self._clock() - self._last_s))

    def pin_expired(self) -> bool:
        """True (and abandons the PIN prompt) when the prompt waited too long."""
        since = self.pin_pending_since
        if since is not None and self._clock() - since > self._limits.pin_entry_timeout_s:
            self.pin_pending_since = None
            return True
        return False
