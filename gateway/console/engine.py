"""The console engine: serial bytes in, reply bytes out (line discipline, session, commands).

One :class:`Console` serves one port for the life of the service; each connection
(port opened) gets a fresh :class:`~gateway.console.session.Session`, while failed
PIN attempts and the lockout persist. No I/O and no clock of its own: the port thread
calls :meth:`Console.feed` with what it read and writes what comes back, and calls
:meth:`Console.poll` when idle (timers). Time comes from the injected ``clock``
(monotonic s) and ``wall`` (Unix s, for audit entries).

Nothing a fitter or line noise sends can raise out of :meth:`feed`: each line is
handled inside a catch-all that logs and replies "internal error".
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from gateway import __version__
from gateway.console import render
from gateway.console.commands import COMMANDS, Context, UsageError, help_usage, result_detail
from gateway.console.lines import Cancelled, Event, LineDiscipline, TooLong
from gateway.console.reply import Reply, encode_json, encode_text, jsonable, to_wire
from gateway.console.session import ConsoleLimits, PinGuard, Session, TokenBucket
from gateway.console.view import ServiceView
from gateway.errors import GatewayError, InputError
from gateway.records import Alert

log = logging.getLogger(__name__)

PROMPT = b"railgw> "
PROMPT_LOGGED_IN = b"railgw# "
PROMPT_PIN = b"PIN: "
AUDIT_REFUSAL = ("refused: the audit log cannot be written (state directory: see 'log'); "
                 "write commands are off until it works")


class Console:
    """The maintenance console for one port; feed it bytes, write back what it returns."""

    def __init__(self, view: ServiceView, *, pin_hash: str = "",
                 limits: ConsoleLimits | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time, port_name: str = "",
                 echo: bool = True) -> None:
        self.view = view
        self.limits = limits or ConsoleLimits()
        self._clock = clock
        self._wall = wall
        self.port_name = port_name
        self._echo_default = echo
        self.guard = PinGuard(pin_hash, self.limits, clock, wall=wall, persist=view)
        if self.guard.configured_but_invalid:
            log.warning("console: [serial] pin_hash unusable (%s); login disabled",
                        self.guard.problem)
        self._bucket = TokenBucket(self.limits.rate_per_s, self.limits.burst, clock)
        self._lines = LineDiscipline(self.limits.max_line_bytes, echo=echo)
        self._sessions = 0
        self.session = Session(0, self.limits, clock, echo=echo)
        """The current connection's session (number 0 until the first :meth:`connect`)."""
        self._limited = False
        self._own_events: collections.deque[int] = collections.deque(maxlen=64)
        self.lines_dropped = 0
        self.internal_errors = 0

    def _new_session(self) -> Session:
        self._sessions += 1
        return Session(self._sessions, self.limits, self._clock, echo=self._echo_default)

    # -- connection lifecycle ------------------------------------------------------------
    def connect(self) -> bytes:
        """A new connection (the port was opened): fresh session; returns the banner."""
        self.session = self._new_session()
        self._lines.reset()
        self._sync()
        log.info("console: session %d on %s", self.session.number, self.port_name or "-")
        return (to_wire(f"\r\nrailgw {__version__} maintenance console"
                        f"{' on ' + self.port_name if self.port_name else ''}; "
                        f"type 'help' for commands\n") + self.prompt())

    def disconnect(self, reason: str = "") -> None:
        """The connection ended (cable pulled, port closed): drop the login."""
        if self.session.logged_in:
            log.info("console: session %d of %s ended while logged in (%s)",
                     self.session.number, self.session.user, reason or "disconnect")
        self.session.user = None
        self.session.pin_pending_since = None
        self.session.pin_shadow = False
        self._lines.reset()

    def prompt(self) -> bytes:
        """The prompt for the current state (none in JSON mode)."""
        s = self.session
        if s.pin_pending_since is not None:
            return b"" if s.json else PROMPT_PIN
        if s.json:
            return b""
        return PROMPT_LOGGED_IN if s.logged_in else PROMPT

    def _sync(self) -> None:
        s = self.session
        self._lines.echo = s.echo and not s.json
        self._lines.secret = s.pin_pending_since is not None or s.pin_shadow

    # -- input -----------------------------------------------------------------------------
    def feed(self, data: bytes) -> bytes:
        """Bytes from the port in; echo, replies and prompts out. Never raises."""
        try:
            return self._lines.feed(data, self._on_event)
        except Exception:  # a bug in the line discipline must not stop the port thread
            self.internal_errors += 1
            log.exception("console: internal error in the line discipline")
            self._lines.reset()
            return b""

    def poll(self) -> bytes:
        """Timers: logs out an idle session, abandons a stale PIN prompt (text notice)."""
        s = self.session
        note = ""
        if s.pin_expired():
            s.pin_shadow = True
            note = "PIN entry timed out; type 'login' again"
        elif s.idle_expired():
            note = f"session idle for {self.limits.idle_timeout_s:g} s: logged out"
            log.info("console: session %d idle timeout", s.number)
        if not note:
            return b""
        self._sync()
        return b"" if s.json else to_wire(f"\n{note}\n") + self.prompt()

    def notify_alert(self, alert: Alert) -> bytes:
        """An unsolicited alert notice for the terminal (text mode only; JSON mode stays
        strictly one reply per command), then the prompt and the partial line again."""
        if self.session.json or alert.seq in self._own_events:
            return b""  # JSON mode, or the event this console's own command just caused
        return (to_wire(f"\n** alert: {render.alert_line(alert)}\n") + self.prompt()
                + self._lines.partial)

    def _on_event(self, event: Event) -> bytes:
        try:
            out = self._event(event)
        except Exception:
            self.internal_errors += 1
            log.exception("console: internal error handling a line")
            out = self._encode(Reply.fail("?", "internal error (logged)")) + self.prompt()
        self._sync()
        return out

    def _event(self, event: Event) -> bytes:
        s = self.session
        if not self._bucket.take():
            self.lines_dropped += 1
            if self._limited:
                return b""
            self._limited = True
            s.pin_shadow = s.pin_shadow or s.pin_pending_since is not None
            s.pin_pending_since = None
            return self._encode(Reply.fail(
                "?", f"rate limit: expected at most {self.limits.rate_per_s:g} commands "
                     f"per second, got more; input dropped")) + self.prompt()
        self._limited = False
        if isinstance(event, Cancelled):
            s.pin_pending_since = None
            return self.prompt()
        notice = b""
        if s.idle_expired():
            log.info("console: session %d idle timeout", s.number)
            if not s.json:
                notice = to_wire(f"(session idle for {self.limits.idle_timeout_s:g} s: "
                                 f"logged out)\n")
        if isinstance(event, TooLong):
            s.pin_shadow = s.pin_shadow or s.pin_pending_since is not None
            s.pin_pending_since = None
            return notice + self._encode(Reply.fail(
                "?", f"line too long: expected at most {self.limits.max_line_bytes} "
                     f"bytes, got {event.length}; line discarded")) + self.prompt()
        if s.pin_pending_since is not None:
            return notice + self._pin(event.text) + self.prompt()
        shadow, s.pin_shadow = s.pin_shadow, False
        s.touch()
        words = event.text.split()
        if not words:
            return b"" if s.json else self.prompt()
        if shadow and words[0].lower() not in COMMANDS and words[0] != "?":
            # The line after a refused login may well be the PIN: neither echoed (the
            # line discipline was secret) nor repeated, and not run.
            return notice + self._encode(Reply.fail(
                "?", "line discarded: login was refused, and this may have been the PIN "
                     "(not shown); type 'login' again")) + self.prompt()
        return notice + self._encode(self._command(words)) + self.prompt()

    def _encode(self, reply: Reply) -> bytes:
        cap = self.limits.reply_max_bytes
        if self.session.json:
            return encode_json(reply, cap)
        return encode_text(reply, cap)

    # -- commands ----------------------------------------------------------------------------
    def _context(self) -> Context:
        return Context(self.view, self.session, self.guard, self.limits, self._clock,
                       self.port_name)

    def _command(self, words: list[str]) -> Reply:
        name, args = words[0].lower(), words[1:]
        if name == "?":
            name = "help"
        cmd = COMMANDS.get(name)
        if cmd is None:
            # Never repeat an unknown word: it may be a PIN typed at the wrong moment.
            return Reply.fail("?", "unknown command (not repeated, it may have been a PIN); "
                                   "type 'help'")
        if cmd.write:
            refusal = self._refusal()
            if refusal:
                self._audit(name, args, "refused", refusal)
                return Reply.fail(name, refusal)
            if not self._audit(name, args, "attempt", ""):
                return Reply.fail(name, AUDIT_REFUSAL)
        ctx = self._context()
        try:
            reply = cmd.handler(ctx, args)
        except InputError as err:
            if cmd.write:
                self._audit(name, args, "rejected", str(err))
            usage = f" (usage: {help_usage(name)})" if isinstance(err, UsageError) else ""
            return Reply.fail(name, f"{err}{usage}")
        except GatewayError as err:
            if cmd.write:
                self._audit(name, args, "error", str(err))
            return Reply.fail(name, str(err))
        except Exception as err:
            self.internal_errors += 1
            log.exception("console: command %r failed", name)
            if cmd.write:
                self._audit(name, args, "error", f"internal error: {type(err).__name__}")
            return Reply.fail(name, f"internal error ({type(err).__name__}; logged)")
        self._own_events.extend(ctx.emitted)
        if cmd.write:
            self._audit(name, args, "ok" if reply.ok else "rejected", result_detail(reply))
        elif name == "login" and not reply.ok:
            self.session.pin_shadow = True
            self._audit("login", args, "locked" if "locked" in reply.error else "refused",
                        reply.error, who=args[0] if args else None)
        return reply

    def _refusal(self) -> str:
        """Why a write command may not run now ('' when it may)."""
        left = self.guard.locked_for_s()
        if left > 0:
            return f"refused: console locked after failed PINs ({left:.0f} s left)"
        if not self.guard.enabled:
            return "refused: write commands are disabled (no PIN configured)"
        if not self.session.logged_in:
            return "refused: write commands need 'login' first"
        return ""

    def _pin(self, pin: str) -> bytes:
        s = self.session
        user = s.pending_user or "fitter"
        if s.pin_expired():
            return self._encode(Reply.fail("login", "PIN entry timed out; type 'login' again"))
        s.pin_pending_since = None
        if not pin:
            return self._encode(Reply.fail("login", "login cancelled (empty PIN)"))
        result = self.guard.check(pin)
        if result.ok and not self._audit("login", [user], "ok", "logged in", who=user):
            s.pin_shadow = True
            log.error("console: login as %s refused: the audit log cannot be written", user)
            return self._encode(Reply.fail("login", AUDIT_REFUSAL))
        if result.ok:
            s.user = user
            s.touch()
            log.info("console: %s logged in (session %d)", user, s.number)
            return self._encode(Reply(True, "login", text=f"logged in as {user}; "
                                      f"write commands enabled ('logout' to end)",
                                      data={"user": user}))
        outcome = "locked" if result.locked_s > 0 else "failed"
        s.pin_shadow = True
        self._audit("login", [user], outcome, result.message, who=user)
        log.warning("console: login as %s %s: %s", user, outcome, result.message)
        extra: dict[str, Any] = {"locked_s": result.locked_s} if result.locked_s else {}
        return self._encode(Reply.fail("login", result.message, **extra))

    def _audit(self, command: str, args: list[str], result: str, detail: Any,
               who: str | None = None) -> bool:
        """Hand one entry to the service's audit log; False (logged) if it was not
        written: the caller then refuses (fail closed)."""
        now = self._wall()
        entry = {"time": datetime.fromtimestamp(now, UTC).isoformat(timespec="seconds"),
                 "t_unix_s": now, "who": who or self.session.user or "-",
                 "port": self.port_name, "session": self.session.number, "command": command,
                 "args": list(args), "result": result, "detail": jsonable(detail)}
        try:
            written = bool(self.view.audit(entry))
        except Exception:
            log.exception("console: audit of %s (%s) failed", command, result)
            return False
        if not written:
            log.error("console: audit of %s (%s) could not be written", command, result)
        return written
