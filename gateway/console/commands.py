"""The console's command table: every command's syntax, help text and reply.

A handler takes the :class:`Context` and the words after the command name and returns
a :class:`~gateway.console.reply.Reply`. It raises :class:`UsageError` (an
InputError) for bad arguments; the service's InputError passes through the same way.
Commands marked ``write`` run only after login and are audited by the engine
(:mod:`gateway.console.engine`), which also handles the PIN line after ``login``.
"""

from __future__ import annotations

import math
import platform
import re
import string
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import serial

from gateway import __version__
from gateway.console import render
from gateway.console.reply import Reply
from gateway.console.session import ConsoleLimits, PinGuard, Session
from gateway.console.view import PARAMS, ServiceView, resolve_parameter
from gateway.errors import InputError
from gateway.jsonform import alert_json
from gateway.records import Severity

HISTORY_JSON_ROWS = 72
"""History rows sent in JSON mode at most (evenly thinned; events always kept)."""
_NAME = re.compile(r"^[A-Za-z0-9._-]{1,32}$")
_PIN_LINE = re.compile(r"^(\s*pin_hash\s*=\s*).*$", re.MULTILINE)
THRESHOLD_MIN_REL = 0.10
"""Lowest threshold a fitter may set: a damper at 10 % of nominal has failed long before
(the default ALARM is at 35 %; below this an alarm could never fire in practice)."""
THRESHOLD_MAX_REL = 5.0
"""Highest threshold: 5 x nominal (conicity 0.75) is past any wheel profile (the default
conicity ALARM is at 2.67 x, 0.40)."""


class UsageError(InputError):
    """A command's arguments do not match its syntax."""


@dataclass
class Context:
    """What a handler may use: the service, this connection's session, the PIN guard.
    A write handler lists the seqs of the alert events it caused in ``emitted`` (the
    console does not announce those again as unsolicited notices)."""

    view: ServiceView
    session: Session
    guard: PinGuard
    limits: ConsoleLimits
    clock: Callable[[], float]
    port_name: str
    emitted: list[int] = field(default_factory=list)


Handler = Callable[[Context, list[str]], Reply]


@dataclass(frozen=True)
class Command:
    """One command: ``usage`` is its syntax, ``summary`` one line, ``detail`` the help."""

    name: str
    usage: str
    summary: str
    detail: str
    handler: Handler
    write: bool = False


def _no_args(cmd: str, args: list[str]) -> None:
    if args:
        raise UsageError(f"expected '{cmd}' without arguments, got {' '.join(args)!r}")


def _resolve(text: str) -> str:
    try:
        return resolve_parameter(text)
    except InputError as err:
        raise UsageError(str(err)) from err


def _label(parameter: str) -> str:
    info = PARAMS.get(parameter)
    return f"{info.label} {info.component}" if info else parameter


# -- read commands -----------------------------------------------------------------------
def _help(ctx: Context, args: list[str]) -> Reply:
    if len(args) > 1:
        raise UsageError(f"expected 'help' or 'help COMMAND', got {' '.join(args)!r}")
    if args:
        cmd = COMMANDS.get(args[0].lower())
        if cmd is None:
            raise UsageError(f"expected a command from {', '.join(COMMANDS)}, got {args[0]!r}")
        lim = ctx.limits
        detail = string.Template(cmd.detail).safe_substitute(
            max_failures=lim.max_failures, lockout_s=f"{lim.lockout_s:g}",
            idle_timeout_s=f"{lim.idle_timeout_s:g}")
        data = {"usage": cmd.usage, "summary": cmd.summary, "detail": detail,
                "write": cmd.write}
        text = f"{cmd.usage}\n  {cmd.summary}" + (" (needs login)" if cmd.write else "")
        return Reply(True, "help", text=text + ("\n" + detail if detail else ""), data=data)
    rows = [f"  {c.usage:<36}{c.summary}" for c in COMMANDS.values()]
    text = ("commands (* needs login; 'help COMMAND' for details):\n"
            + "\n".join(("*" + r[1:]) if c.write else r
                        for r, c in zip(rows, COMMANDS.values(), strict=True)))
    data = {"commands": [{"name": c.name, "usage": c.usage, "summary": c.summary,
                          "write": c.write} for c in COMMANDS.values()]}
    return Reply(True, "help", text=text, data=data)


def session_line(ctx: Context) -> str:
    """The console's own state in one line (for ``status``)."""
    locked = ctx.guard.locked_for_s()
    if locked > 0:
        return f"locked for {math.ceil(locked)} s (failed PINs)"
    if ctx.session.logged_in:
        return (f"logged in as {ctx.session.user} (idle logout in "
                f"{math.ceil(ctx.session.idle_left_s())} s)")
    return "not logged in" + ("" if ctx.guard.enabled else " (no PIN configured)")


def _status(ctx: Context, args: list[str]) -> Reply:
    _no_args("status", args)
    d = ctx.view.status()
    data = {**d, "console": {"logged_in": ctx.session.logged_in, "user": ctx.session.user,
                             "locked_s": ctx.guard.locked_for_s(), "port": ctx.port_name}}
    return Reply(True, "status", text=render.status(d, session_line(ctx)), data=data)


def _estimates(ctx: Context, args: list[str]) -> Reply:
    _no_args("estimates", args)
    d = ctx.view.estimates()
    return Reply(True, "estimates", text=render.estimates(d), data=d)


def _alerts(ctx: Context, args: list[str]) -> Reply:
    _no_args("alerts", args)
    active, recent = ctx.view.alerts()
    data = {"active": [alert_json(a) for a in active],
            "recent": [alert_json(a) for a in recent]}
    return Reply(True, "alerts", text=render.alerts(active, recent), data=data)


def parse_hours(text: str, max_hours: float) -> float:
    """``6``, ``6h`` or ``2d`` as hours in (0, max_hours]."""
    m = re.fullmatch(r"(\d+(?:\.\d+)?)\s*([hd]?)", text.strip().lower())
    hours = float(m.group(1)) * (24.0 if m.group(2) == "d" else 1.0) if m else math.nan
    if not 0 < hours <= max_hours:
        raise UsageError(f"expected hours like 6, 6h or 2d, at most {max_hours:g} h, "
                         f"got {text!r}")
    return hours


def _history(ctx: Context, args: list[str]) -> Reply:
    if len(args) > 1:
        raise UsageError(f"expected 'history [hours]', got {' '.join(args)!r}")
    hours = parse_hours(args[0], ctx.limits.history_max_hours) if args else 24.0
    rows = ctx.view.history(hours)
    sent = render.thin(rows, HISTORY_JSON_ROWS)
    return Reply(True, "history", text=render.history(rows, hours),
                 data={"hours": hours, "rows_total": len(rows), "rows": sent})


def _sensors(ctx: Context, args: list[str]) -> Reply:
    _no_args("sensors", args)
    d = ctx.view.sensors()
    return Reply(True, "sensors", text=render.sensors(d), data=d)


def _bus(ctx: Context, args: list[str]) -> Reply:
    _no_args("bus", args)
    d = ctx.view.bus()
    return Reply(True, "bus", text=render.bus(d), data=d)


def _config(ctx: Context, args: list[str]) -> Reply:
    _no_args("config", args)
    text = _PIN_LINE.sub(r'\1"<redacted>"', ctx.view.config_text())
    return Reply(True, "config", text=text.rstrip("\n") or "(empty)", data={"text": text})


def _version(ctx: Context, args: list[str]) -> Reply:
    _no_args("version", args)
    service = ctx.view.status().get("version") or __version__
    data = {"gateway": service, "console": __version__, "python": platform.python_version(),
            "pyserial": getattr(serial, "__version__", "?")}
    text = (f"railgw {service} (console {__version__}, Python {data['python']}, "
            f"pyserial {data['pyserial']})")
    return Reply(True, "version", text=text, data=data)


def _log(ctx: Context, args: list[str]) -> Reply:
    cap = ctx.limits.log_max_lines
    if len(args) > 1 or (args and not (args[0].isdigit() and 0 < int(args[0]) <= cap)):
        raise UsageError(f"expected 'log [n]' with 1 <= n <= {cap}, got {' '.join(args)!r}")
    n = int(args[0]) if args else 20
    lines = [str(x) for x in ctx.view.log_lines(n)][-n:]
    return Reply(True, "log", text="\n".join(lines) or "(no log lines)", data={"lines": lines})


# -- session commands --------------------------------------------------------------------
def _login(ctx: Context, args: list[str]) -> Reply:
    if len(args) > 1 or (args and not _NAME.match(args[0])):
        raise UsageError(f"expected 'login [name]' (name: up to 32 of A-Z a-z 0-9 . _ -), "
                         f"got {' '.join(args)!r}")
    if not ctx.guard.enabled:
        return Reply.fail("login", "login disabled: no PIN configured ([serial] pin_hash)")
    left = ctx.guard.locked_for_s()
    if left > 0:
        return Reply.fail("login", f"console locked after failed PINs; try again in "
                                   f"{math.ceil(left)} s", locked_s=math.ceil(left))
    ctx.session.pin_pending_since = ctx.clock()
    ctx.session.pending_user = args[0] if args else "fitter"
    return Reply(True, "login", text="", data={"pin_required": True})


def _logout(ctx: Context, args: list[str]) -> Reply:
    _no_args("logout", args)
    was = ctx.session.user
    ctx.session.user = None
    return Reply(True, "logout", text="logged out" if was else "was not logged in",
                 data={"was_logged_in": was is not None})


def _mode(ctx: Context, args: list[str]) -> Reply:
    if len(args) > 1 or (args and args[0].lower() not in ("json", "text")):
        raise UsageError(f"expected 'mode json' or 'mode text', got {' '.join(args)!r}")
    if args:
        ctx.session.json = args[0].lower() == "json"
    mode = "json" if ctx.session.json else "text"
    return Reply(True, "mode", text=f"{mode} mode", data={"mode": mode})


def _echo(ctx: Context, args: list[str]) -> Reply:
    if len(args) > 1 or (args and args[0].lower() not in ("on", "off")):
        raise UsageError(f"expected 'echo on' or 'echo off', got {' '.join(args)!r}")
    if args:
        ctx.session.echo = args[0].lower() == "on"
    state = "on" if ctx.session.echo else "off"
    return Reply(True, "echo", text=f"echo is {state}", data={"echo": state})


# -- write commands ----------------------------------------------------------------------
def parse_alert_key(text: str) -> int | str:
    """``12`` or ``#12`` -> 12; a component or parameter alias -> its parameter name."""
    key = text.lstrip("#")
    if key.isdigit():
        return int(key)
    return _resolve(text)


def _ack(ctx: Context, args: list[str]) -> Reply:
    if len(args) != 1:
        raise UsageError(f"expected 'ack <#seq|component>', got {' '.join(args)!r}")
    result = ctx.view.acknowledge(parse_alert_key(args[0]))
    alert = result.alert
    ctx.emitted.append(alert.seq)
    text = f"acknowledged: #{alert.seq} {_label(alert.parameter)} {alert.severity.name}"
    return Reply(True, "ack", text=text, data=result.to_json())


def _baseline(ctx: Context, args: list[str]) -> Reply:
    if len(args) != 2 or args[0].lower() != "reset":
        raise UsageError(f"expected 'baseline reset <component>', got {' '.join(args)!r}")
    parameter = _resolve(args[1])
    result = ctx.view.baseline_reset(parameter)
    cleared = [a.seq for a in result.cleared]
    ctx.emitted.extend(cleared)
    text = (f"baseline reset: {_label(parameter)} re-learns from its prior"
            + (f"; cleared alert {', '.join(f'#{s}' for s in cleared)}" if cleared else ""))
    return Reply(True, "baseline", text=text, data=result.to_json())


_SEVERITIES = {"advisory": Severity.ADVISORY, "adv": Severity.ADVISORY,
               "warning": Severity.WARNING, "warn": Severity.WARNING,
               "alarm": Severity.ALARM}


def parse_threshold(text: str) -> float:
    """``0.5`` or ``50%`` -> 0.5 (relative to nominal, within
    [:data:`THRESHOLD_MIN_REL`, :data:`THRESHOLD_MAX_REL`])."""
    t = text.strip()
    try:
        value = float(t[:-1]) / 100.0 if t.endswith("%") else float(t)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and THRESHOLD_MIN_REL <= value <= THRESHOLD_MAX_REL):
        raise UsageError(f"expected a threshold from {THRESHOLD_MIN_REL * 100:g} % to "
                         f"{THRESHOLD_MAX_REL * 100:g} % of nominal ({THRESHOLD_MIN_REL:g} "
                         f"to {THRESHOLD_MAX_REL:g}), got {text[:16]!r}")
    return value


def _threshold(ctx: Context, args: list[str]) -> Reply:
    if len(args) != 4 or args[0].lower() != "set":
        raise UsageError("expected 'threshold set <component> <advisory|warning|alarm> "
                         f"<value>', got {' '.join(args)!r}")
    parameter = _resolve(args[1])
    severity = _SEVERITIES.get(args[2].lower())
    if severity is None:
        raise UsageError(f"expected a severity from advisory, warning, alarm, got {args[2]!r}")
    value = parse_threshold(args[3])
    result = ctx.view.set_threshold(parameter, severity, value)
    text = (f"threshold set: {_label(parameter)} {result.side}-side {severity.name} at "
            f"{value * 100:g} % of nominal")
    return Reply(True, "threshold", text=text, data=result.to_json())


def _cmd(name: str, usage: str, summary: str, detail: str, handler: Handler,
         write: bool = False) -> tuple[str, Command]:
    return name, Command(name, usage, summary, detail.strip(), handler, write)


COMMANDS: dict[str, Command] = dict([
    _cmd("help", "help [command]", "list commands, or explain one",
         "Without an argument lists every command; 'help estimates' explains one.", _help),
    _cmd("status", "status", "overall health, uptime, worker, bus",
         "State is Running, Degraded (a reason follows) or Fault. Also shows this "
         "console's login state.", _status),
    _cmd("estimates", "estimates", "dampers and conicity vs nominal",
         "Per parameter: value, +-sigma, % of nominal, the ADVISORY/WARNING/ALARM\n"
         "thresholds in % of nominal and the alert status. 'unsure' means sigma is\n"
         "still above the confidence gate, so no alert is raised on it yet.", _estimates),
    _cmd("alerts", "alerts", "active alerts and recent events",
         "Each alert has a sequence number #seq for 'ack'.", _alerts),
    _cmd("history", "history [hours|Nd]", "estimates over hours or days",
         "From the persisted history; default 24 h; e.g. 'history 6', 'history 7d'.\n"
         "Baseline resets are listed as events (**).", _history),
    _cmd("sensors", "sensors", "sensor rates, errors, timeouts, values",
         "rate/expected in Hz; rejected = frames dropped by validation (crc, counter,\n"
         "range, ...); lost = frames missing from the alive counter; t/o = timeouts.",
         _sensors),
    _cmd("bus", "bus", "CAN bus state, load, error counters",
         "State ERROR_ACTIVE is normal; ERROR_PASSIVE or BUS_OFF point at wiring or a "
         "node.", _bus),
    _cmd("config", "config", "the running configuration (TOML)",
         "The PIN hash is never shown.", _config),
    _cmd("version", "version", "software versions", "Gateway, Python and pyserial.",
         _version),
    _cmd("log", "log [n]", "the last n log lines (default 20)", "At most 200 lines.", _log),
    _cmd("login", "login [name]", "log in for write commands (asks PIN)",
         "The PIN is not echoed. $max_failures wrong PINs in a row lock login for\n"
         "$lockout_s s. The session ends after $idle_timeout_s s without a command, on\n"
         "'logout', or when the cable is pulled. 'name' goes into the audit log.", _login),
    _cmd("logout", "logout", "end the logged-in session", "", _logout),
    _cmd("ack", "ack <#seq|component>", "acknowledge an active alert",
         "e.g. 'ack 12' or 'ack lateral-damper'. Recorded in the audit log.", _ack, True),
    _cmd("baseline", "baseline reset <component>", "after replacing a damper/wheelset",
         "Components: csy (lateral-damper), csay (anti-yaw-damper), conicity (wheelset).\n"
         "The estimator re-learns that parameter from its prior; its alert is cleared;\n"
         "history records the event. Recorded in the audit log.", _baseline, True),
    _cmd("threshold", "threshold set <comp> <sev> <value>", "change an alert threshold",
         "Severity: advisory, warning or alarm. Value relative to nominal, 0.5 or 50%:\n"
         "below 1 judges the low side (weak damper), above 1 the high side (worn\n"
         "wheels); from 10% to 500%. e.g. 'threshold set csy warning 50%'.\n"
         "Recorded in the audit log.",
         _threshold, True),
    _cmd("mode", "mode json|text", "JSON replies for scripts, or text",
         "In json mode every reply is one JSON object on one line, no prompt, no echo:\n"
         '{"ok": true, "cmd": ..., "data": ...} or {"ok": false, "cmd": ..., "error": ...}',
         _mode),
    _cmd("echo", "echo on|off", "echo typed characters (text mode)",
         "Off for terminals with local echo.", _echo),
])
"""Every command, in the order 'help' lists them."""


def help_usage(name: str) -> str:
    """The usage line of ``name`` (for error replies)."""
    cmd = COMMANDS.get(name)
    return cmd.usage if cmd else name


def result_detail(reply: Reply) -> Any:
    """What the audit log stores of a reply: the data when ok, else the error text."""
    return reply.data if reply.ok else reply.error
