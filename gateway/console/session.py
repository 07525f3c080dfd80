"""Who may write on the console: PIN check, lockout, idle timeout and the command rate limit.

Everything here takes its time from an injected monotonic clock (``clock() -> s``), so
the tests step time instead of sleeping. Two lifetimes:

- :class:`PinGuard` lives as long as the console: failed attempts and the lockout
  survive a cable pull (re-plugging must not reset a brute-force counter);
- :class:`Session` lives for one connection: login state, mode, idle timer.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import re
from collections.abc import Callable
from dataclasses import dataclass

Clock = Callable[[], float]
"""Monotonic seconds."""

_HEX64 = re.compile(r"^[0-9a-f]{64}$")


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


def pin_hash(pin: str) -> str:
    """SHA-256 hex digest of a PIN, as ``[serial] pin_sha256`` stores it."""
    return hashlib.sha256(pin.encode("utf-8")).hexdigest()


def valid_pin_hash(pin_sha256: str) -> bool:
    """True for 64 lower- or upper-case hex digits."""
    return bool(_HEX64.match(pin_sha256.strip().lower()))


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


class PinGuard:
    """Checks PINs against the configured SHA-256 (constant time) and enforces the lockout."""

    def __init__(self, pin_sha256: str, limits: ConsoleLimits, clock: Clock) -> None:
        digest = pin_sha256.strip().lower()
        self._digest = digest if valid_pin_hash(digest) else ""
        self.configured_but_invalid = bool(pin_sha256.strip()) and not self._digest
        self._limits = limits
        self._clock = clock
        self.failures = 0
        self._locked_until = -math.inf

    @property
    def enabled(self) -> bool:
        """False when no (valid) PIN hash is configured: writes are then impossible."""
        return bool(self._digest)

    def locked_for_s(self) -> float:
        """Seconds of lockout left (0 when not locked)."""
        return max(0.0, self._locked_until - self._clock())

    def check(self, pin: str) -> PinResult:
        """One attempt; the fifth consecutive failure starts the lockout."""
        if not self.enabled:
            return PinResult(False, "login disabled: no PIN configured ([serial] pin_sha256)")
        left = self.locked_for_s()
        if left > 0:
            return PinResult(False, f"console locked after {self._limits.max_failures} "
                                    f"failed PINs; try again in {math.ceil(left)} s", left)
        given = hashlib.sha256(pin.encode("utf-8")).hexdigest()
        if hmac.compare_digest(given, self._digest):
            self.failures = 0
            return PinResult(True, "PIN accepted")
        self.failures += 1
        if self.failures >= self._limits.max_failures:
            self.failures = 0
            self._locked_until = self._clock() + self._limits.lockout_s
            return PinResult(False, f"wrong PIN; console locked for "
                                    f"{math.ceil(self._limits.lockout_s)} s after "
                                    f"{self._limits.max_failures} failed attempts",
                             self._limits.lockout_s)
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
