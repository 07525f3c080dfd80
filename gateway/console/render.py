"""Text for a fitter: the service's dicts as short aligned tables, at most 80 columns.

Every renderer takes what a :class:`~gateway.console.view.ServiceView` method returned
and copes with missing or odd values (shown as "-"); :func:`generic` is the fallback
for anything else. Pure functions, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from gateway.console.view import PARAMS
from gateway.records import Alert

DASH = "-"


def num(x: Any, fmt: str = ".3g", scale: float = 1.0) -> str:
    """``x * scale`` formatted, or "-" when it is not a finite number."""
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        return DASH
    return format(x * scale, fmt)


def duration(s: Any) -> str:
    """Seconds as ``2d 03:05:12`` (or "-")."""
    if not isinstance(s, int | float) or not math.isfinite(s) or s < 0:
        return DASH
    days, rest = divmod(int(s), 86400)
    h, rest = divmod(rest, 3600)
    m, sec = divmod(rest, 60)
    return (f"{days}d " if days else "") + f"{h:02d}:{m:02d}:{sec:02d}"


def _get(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, Mapping):
            return None
        d = d.get(k)
    return d


def _word(x: Any) -> str:
    if x is None:
        return DASH
    if isinstance(x, bool):
        return "yes" if x else "no"
    return str(x)


def generic(data: Any, indent: int = 0) -> str:
    """Any JSON-like value as indented ``key: value`` lines."""
    pad = "  " * indent
    if isinstance(data, Mapping):
        lines = []
        for k, v in data.items():
            if isinstance(v, Mapping | list | tuple) and v:
                lines.append(f"{pad}{k}:")
                lines.append(generic(v, indent + 1))
            else:
                lines.append(f"{pad}{k}: {_word(v) if not isinstance(v, float) else num(v)}")
        return "\n".join(lines)
    if isinstance(data, list | tuple):
        return "\n".join(generic(v, indent) if isinstance(v, Mapping | list | tuple)
                         else f"{pad}- {_word(v)}" for v in data)
    return f"{pad}{_word(data)}"


def status(d: Mapping[str, Any], session_line: str) -> str:
    worker = _get(d, "worker") or {}
    lines = [f"state      {_word(d.get('state'))}"
             + (f" ({d['reason']})" if d.get("reason") else ""),
             f"uptime     {duration(d.get('uptime_s'))}",
             f"version    {_word(d.get('version'))}",
             f"data time  {num(d.get('data_time_s'), '.1f')} s",
             f"worker     {'alive' if worker.get('alive') else 'NOT RUNNING'}, "
             f"{_word(worker.get('restarts'))} restarts, pid {_word(worker.get('pid'))}, "
             f"real-time factor {num(worker.get('rtf'), '.2f')}",
             f"CAN bus    {_word(_get(d, 'bus', 'state'))}"
             f"{'' if _get(d, 'bus', 'open') is not False else ' (closed)'}",
             f"alerts     {_word(d.get('active_alerts'))} active"]
    fe = d.get("front_end")
    if isinstance(fe, Mapping):
        lines.append(f"front end  {front_end(fe)}")
    sd = d.get("state_dir")
    if isinstance(sd, Mapping) and (sd.get("write_failures") or sd.get("set_aside")):
        aside = ", ".join(map(_word, sd.get("set_aside") or [])) or "none"
        lines.append(f"state dir  {_word(sd.get('write_failures'))} WRITE FAILURES since "
                     f"start; set aside at start: {aside}")
    lines.append(f"console    {session_line}")
    return "\n".join(lines)


def _by_reason(counts: Any) -> str:
    """``12 (deadline 10, clock 2)``: the total and its non-zero reasons."""
    if not isinstance(counts, Mapping):
        return DASH
    nz = [(k, v) for k, v in counts.items() if isinstance(v, int) and v]
    total = sum(v for _, v in nz)
    return f"{total} ({', '.join(f'{k} {v}' for k, v in nz)})" if nz else "0"


def front_end(fe: Mapping[str, Any]) -> str:
    """Two lines: late frames and gap points by reason; resyncs, clock steps, receive
    times beyond a horizon (if any) and two senders (now, or past episodes); then one
    line per node (:func:`node_timing`)."""
    senders = fe.get("two_senders") or []
    rest = f"resyncs {_word(fe.get('resyncs'))}, clock steps {_word(fe.get('clock_steps'))}"
    horizon = _by_reason(fe.get("horizon"))
    if horizon not in ("0", DASH):
        rest += f", beyond horizon {horizon}"
    episodes = _word(fe.get("two_sender_events", 0))
    rest += (f", TWO SENDERS on {', '.join(map(_word, senders))}" if senders
             else f", two senders: none now ({episodes} episodes)")
    return (f"late {_by_reason(fe.get('late'))}, gaps {_by_reason(fe.get('gaps'))}\n"
            f"           {rest}{node_timing(fe.get('nodes'))}")


def node_timing(nodes: Any) -> str:
    """One line per node (message): fitted drift in ppm and grid phase in us, then its
    late, missing and reordered samples; "" when there are none."""
    if not isinstance(nodes, Mapping):
        return ""
    return "".join(
        f"\n           {_word(m):<9} drift {num(_get(t, 'drift_ppm'), '+.1f')} ppm, "
        f"phase {num(_get(t, 'grid_phase_us'), '.0f')} us, "
        f"late {_word(_get(t, 'late_samples'))}, missing {_word(_get(t, 'missing_samples'))}, "
        f"reordered {_word(_get(t, 'reordered_samples'))}"
        for m, t in nodes.items())


def _limits(th: Any, scale_pct: bool = True) -> str:
    if not isinstance(th, Mapping):
        return DASH
    parts = []
    for side, sign in (("low", "<="), ("high", ">=")):
        levels = th.get(side) or []
        vals = [num(v, ".0f", 100.0) for v in levels]
        if any(v != DASH for v in vals):
            parts.append(sign + "/".join(vals))
    return " ".join(parts) + " %" if parts else DASH


def estimates(d: Mapping[str, Any]) -> str:
    params = d.get("parameters") or {}
    if not params:
        return "no estimate yet (the estimator has not produced one)"
    head = (f"estimates at data time {num(d.get('t_s'), '.1f')} s, ESS "
            f"{num(d.get('ess'), '.0f')} of {_word(d.get('particles'))} particles"
            + ("" if d.get("updated") is not False else " (predict only: gated)"))
    if d.get("left_out"):
        head += ("\nwithout sensors " + ", ".join(map(str, d["left_out"])) + " (no data: "
                 "left out); what only they show is not in these values")
    if d.get("unresolved"):
        head += ("\nunresolved by the sensors in use: " + ", ".join(map(str, d["unresolved"]))
                 + " (its value is mostly what was known before)")
    rows = [head, f"{'parameter':<21}{'value':>8} {'+-sigma':>7} {'unit':<6}"
                  f"{'% nom':>6}  {'limits A/W/Al':<16}status"]
    for name, p in params.items():
        info = PARAMS.get(name)
        label = f"{info.label} {info.component}" if info else name
        scale, unit = (info.scale, info.unit) if info else (1.0, "")
        mean, std = p.get("mean"), p.get("std")
        fmt = ".4f" if info is not None and info.scale == 1.0 else ".1f"
        word = _word(p.get("status"))
        if p.get("alert_state") == "ACKNOWLEDGED":
            word += " ack"
        if p.get("confident") is False:
            word += " unsure"
        rows.append(f"{label[:20]:<21}{num(mean, fmt, scale):>8} {num(std, fmt, scale):>7} "
                    f"{unit:<6}{num(p.get('value_rel'), '.1f', 100.0):>6}  "
                    f"{_limits(p.get('thresholds')):<16}{word}")
    rows.append("limits: ADVISORY/WARNING/ALARM thresholds in % of nominal; ack = alert\n"
                "acknowledged; unsure = sigma above the confidence gate (not judged yet)")
    return "\n".join(rows)


def alert_line(a: Alert) -> str:
    info = PARAMS.get(a.parameter)
    label = f"{info.label} {info.component}" if info else a.parameter
    return (f"#{a.seq:<5} {a.severity.name:<8} {a.state.name:<12} {label[:22]:<22} "
            f"{num(a.value_rel, '.0f', 100.0):>4} %  t={num(a.t_s, '.0f')} s")


def alerts(active: Sequence[Alert], recent: Sequence[Alert], max_recent: int = 20) -> str:
    lines = [f"active alerts: {len(active)}"]
    lines += ["  " + alert_line(a) + (f"\n         {a.message}" if a.message else "")
              for a in active]
    shown = list(recent)[-max_recent:]
    lines.append(f"recent events: {len(recent)}"
                 + (f" (last {len(shown)} shown)" if len(shown) < len(recent) else ""))
    lines += ["  " + alert_line(a) for a in shown]
    if any(a.state.name == "RAISED" for a in active):
        lines.append("acknowledge with: ack <#seq> or ack <component>  (login first)")
    return "\n".join(lines)


def thin(rows: Sequence[Mapping[str, Any]], max_rows: int) -> list[Mapping[str, Any]]:
    """At most ``max_rows`` estimate rows, evenly spread, always the last one; every event
    row (baseline reset, threshold change) is kept. Order is preserved."""
    plain = [i for i, r in enumerate(rows) if not r.get("event")]
    if len(plain) <= max_rows:
        return list(rows)
    step = len(plain) / max_rows
    keep = {plain[int(k * step)] for k in range(max_rows - 1)} | {plain[-1]}
    return [r for i, r in enumerate(rows) if r.get("event") or i in keep]


def history(rows: Sequence[Mapping[str, Any]], hours: float, max_rows: int = 48) -> str:
    if not rows:
        return f"no history in the last {hours:g} h"
    shown = thin(rows, max_rows)
    n_plain = sum(1 for r in rows if not r.get("event"))
    n_shown = sum(1 for r in shown if not r.get("event"))
    out = [f"history, last {hours:g} h ({n_plain} rows"
           + (f", {n_shown} shown" if n_shown < n_plain else "") + ")",
           f"{'t [h]':>8} {'time':<20}"
           + "".join(f"{(info.label + ' ' + info.unit).strip():>16}" for info in PARAMS.values())]
    for r in shown:
        t_h = num(r.get("t_s"), ".2f", 1 / 3600)
        when = str(r.get("time") or "")[:19]
        if r.get("event"):
            out.append(f"{t_h:>8} {when:<20}  ** {r['event']}")
            continue
        cells = []
        for name, info in PARAMS.items():
            e = _get(r, "estimates", name) or {}
            fmt = ".4f" if info.scale == 1.0 else ".1f"
            cells.append(f"{num(e.get('mean'), fmt, info.scale)}+-"
                         f"{num(e.get('std'), fmt, info.scale)}")
        out.append(f"{t_h:>8} {when:<20}" + "".join(f"{c:>16}" for c in cells))
    return "\n".join(out)


def _values(vals: Any) -> str:
    if not isinstance(vals, Mapping):
        return DASH
    return " ".join(f"{k}={num(v, '.4g')}" for k, v in vals.items()) or DASH


def sensors(d: Mapping[str, Any]) -> str:
    msgs = d.get("messages", d)
    if not isinstance(msgs, Mapping) or not msgs:
        return "no sensor statistics yet"
    out = [f"{'message':<11}{'rate/expected Hz':>18}{'accepted':>12}{'rejected':>9}"
           f"{'lost':>7}{'t/o':>5}  state"]
    for name, m in msgs.items():
        if not isinstance(m, Mapping):
            continue
        rej = m.get("rejected") or {}
        rej_total = sum(v for v in rej.values() if isinstance(v, int)) \
            if isinstance(rej, Mapping) else rej
        rate, exp = m.get("rate_hz"), m.get("expected_hz")
        state = "TIMED OUT" if m.get("timed_out") else "ok"
        if (state == "ok" and isinstance(rate, int | float) and isinstance(exp, int | float)
                and exp > 0 and abs(rate - exp) > 0.05 * exp):
            state = "RATE OFF"
        out.append(f"{str(name)[:10]:<11}{num(rate, '.1f'):>9}/{num(exp, '.1f'):<8}"
                   f"{_word(m.get('accepted')):>12}{_word(rej_total):>9}"
                   f"{_word(m.get('lost_frames')):>7}{_word(m.get('timeouts')):>5}  {state}")
        if isinstance(rej, Mapping) and rej:
            out.append(" " * 13 + "rejected: "
                       + ", ".join(f"{k} {v}" for k, v in rej.items()))
        out.append(" " * 13 + "last: " + _values(m.get("last_values")))
    return "\n".join(out)


def bus(d: Mapping[str, Any]) -> str:
    if not d:
        return "no bus statistics yet"
    lines = [f"interface   {_word(d.get('interface'))} {_word(d.get('channel'))}"
             f" ({'open' if d.get('open') else 'CLOSED'})",
             f"state       {_word(d.get('state'))}",
             f"load        {num(d.get('load_pct'), '.1f')} %",
             f"frames      rx {_word(d.get('frames_rx'))}, tx {_word(d.get('frames_tx'))}, "
             f"dropped {_word(d.get('dropped'))}",
             f"errors      {_word(d.get('error_frames'))} error frames, "
             f"{_word(d.get('reopens'))} reopens"]
    if d.get("last_error"):
        lines.append(f"last error  {d['last_error']}")
    known = {"interface", "channel", "open", "state", "load_pct", "frames_rx", "frames_tx",
             "dropped", "error_frames", "reopens", "last_error"}
    rest = {k: v for k, v in d.items() if k not in known}
    if rest:
        lines.append(generic(rest))
    return "\n".join(lines)
