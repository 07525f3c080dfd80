"""The alert policy: turns a stream of estimates into alert events (raise, escalate, clear, ack).

Over 400 lines: thresholds, hold times, hysteresis, baselines and lifecycle act on one
policy state. The threshold judge shared with the console is :mod:`gateway.alerts.judge`;
alerts in the snapshot take their JSON form from :mod:`gateway.jsonform`.

Core module: no I/O, no clock. Time is the estimates' data time ``t_s``; the only state
is :class:`AlertPolicy`'s, and :meth:`AlertPolicy.snapshot` / :meth:`AlertPolicy.restore`
checkpoint it as a JSON-compatible dict. ``docs/alerts.md`` explains the defaults.

Per parameter, ``rel = mean / nominal`` is judged against thresholds on a low side
(``rel <= threshold``, a weak damper) and/or a high side (``rel >= threshold``, worn
wheels), one per severity. A confidence gate (``std / max(|mean|, nominal)``), hold
times in data time and hysteresis keep estimator noise from raising or flapping alerts.
A change the estimator's fault bank located (:class:`gateway.records.Located`) whose
whole likelihood interval lies past a threshold raises at once: the bank has already
made the statistical decision the hold times stand in for, and every value on the far
side of the threshold is 4 sigma or more from the located one (the sure standard).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from gateway import jsonform
from gateway.alerts import judge
from gateway.errors import ConfigError, InputError, StateError
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL
from gateway.records import Alert, AlertState, Estimate, Located, Severity

SIDES: tuple[str, str] = ("low", "high")
CODE_BASE: dict[str, int] = {"low": 0x10, "high": 0x20}
CODE_TWO_SENDERS = 0x30
"""Not a parameter alert: two senders on one sensor id (``FrontEndStats.two_senders``,
"two senders on BGN"); the stream is excluded from the estimator meanwhile. Always
ADVISORY, parameter :func:`sender_parameter` (``node:BGN``), ``value_rel`` NaN (on the
bus: GW_Alert_Param and GW_Alert_ValueRel NotAvailable), side :data:`SENDERS_SIDE`."""
SENDERS_SIDE = "senders"
"""The ``side`` :func:`decode_code` gives :data:`CODE_TWO_SENDERS`."""
NODE_PREFIX = "node:"
SNAPSHOT_VERSION = 2
"""2: alerts in the snapshot in :func:`gateway.jsonform.alert_json` form (severity and
state by name, NaN as null); 1 (still read): severity and state as integers."""
SNAPSHOT_VERSIONS_READ = (1, 2)
SEQ_BLOCK = 16
"""Seqs reserved durably at a time (``reserve``): a restart skips at most this many."""
Levels = tuple[float | None, float | None, float | None]
"""Thresholds relative to nominal for (ADVISORY, WARNING, ALARM); None = not judged."""


def alert_code(parameter: str, severity: Severity, side: str) -> int:
    """The alert code: ``CODE_BASE[side] + 3 * PARAM_NAMES.index(parameter) + severity``."""
    return CODE_BASE[side] + 3 * PARAM_NAMES.index(parameter) + int(severity)


def sender_parameter(message: str) -> str:
    """The alert parameter of two senders on ``message``: ``node:BGN`` for ``BGN_Lat``."""
    return NODE_PREFIX + message.split("_", 1)[0]


def decode_code(code: int) -> tuple[str, Severity, str]:
    """``(parameter, severity, side)`` of an alert code; InputError for an unknown code.
    :data:`CODE_TWO_SENDERS` gives ``("node", ADVISORY, SENDERS_SIDE)`` (the node is in
    the alert's ``parameter``)."""
    if code == CODE_TWO_SENDERS:
        return NODE_PREFIX[:-1], Severity.ADVISORY, SENDERS_SIDE
    for side, base in CODE_BASE.items():
        k = code - base - 1
        if 0 <= k < 3 * len(PARAM_NAMES):
            return PARAM_NAMES[k // 3], Severity(k % 3 + 1), side
    raise InputError(f"expected an alert code in 0x11..0x19, 0x21..0x29 or 0x30, "
                     f"got {code:#x}")


def _side_problem(side: str, levels: Levels, hysteresis_rel: float) -> str | None:
    """Why ``levels`` are invalid on ``side`` ("expected ..., got ..."), or None."""
    low = side == "low"
    bound = 1.0 - hysteresis_rel if low else 1.0 + hysteresis_rel
    values = [v for v in levels if v is not None]
    for k, v in enumerate(levels):
        if v is not None and not (math.isfinite(v) and v > 0 and (v < bound if low else
                                                                 v > bound)):
            return (f"expected the {side}-side {Severity(k + 1).name} threshold "
                    f"{'below 1 - ' if low else 'above 1 + '}hysteresis = {bound:g} "
                    f"and > 0, got {v!r}")
    if not all((a > b) if low else (a < b) for a, b in zip(values, values[1:], strict=False)):
        way = "decreasing" if low else "increasing"
        return f"expected {side}-side thresholds strictly {way} with severity, got {levels}"
    return None


@dataclass(frozen=True)
class ParamPolicy:
    """How one parameter is judged; every ``*_rel`` is a fraction of ``nominal``.

    ``nominal`` in the parameter's unit (N s/m or -). ``low_rel``/``high_rel``: thresholds
    for (ADVISORY, WARNING, ALARM). ``hysteresis_rel``: a raised severity is released
    only once ``rel`` is back past its threshold by this much. ``max_std_rel``: the
    confidence gate, judge only when ``std / max(|mean|, nominal) <= max_std_rel``.
    """

    nominal: float
    low_rel: Levels = (None, None, None)
    high_rel: Levels = (None, None, None)
    hysteresis_rel: float = 0.05
    max_std_rel: float = 0.05

    def __post_init__(self) -> None:
        if not (math.isfinite(self.nominal) and self.nominal > 0):
            raise ConfigError(f"expected a finite nominal > 0, got {self.nominal!r}")
        if not (0 <= self.hysteresis_rel < 0.5 and 0 < self.max_std_rel <= 1):
            raise ConfigError(f"expected 0 <= hysteresis_rel < 0.5 and 0 < max_std_rel <= 1, "
                              f"got {self.hysteresis_rel!r}, {self.max_std_rel!r}")
        for side in SIDES:
            levels = self.levels(side)
            problem = (_side_problem(side, levels, self.hysteresis_rel) if len(levels) == 3
                       else f"expected 3 {side}-side thresholds, got {levels!r}")
            if problem:
                raise ConfigError(problem)

    def levels(self, side: str) -> Levels:
        """The (ADVISORY, WARNING, ALARM) thresholds of ``side`` ("low" or "high")."""
        return self.low_rel if side == "low" else self.high_rel


def default_params() -> dict[str, ParamPolicy]:
    """Defaults for the paper's vehicle (reasons in ``docs/alerts.md``)."""
    return {
        "csy_ns_per_m": ParamPolicy(THETA_NOMINAL.csy_ns_per_m, low_rel=(0.75, 0.55, 0.35)),
        "csay_ns_per_m": ParamPolicy(THETA_NOMINAL.csay_ns_per_m, low_rel=(0.75, 0.55, 0.35)),
        "conicity": ParamPolicy(THETA_NOMINAL.conicity, high_rel=(1.6, 2.0, 2.67),
                                hysteresis_rel=0.1, max_std_rel=0.08),
    }


@dataclass(frozen=True)
class PolicyConfig:
    """The whole policy: per-parameter thresholds plus hold times in data seconds.

    A condition must hold continuously for ``raise_hold_s`` before it raises and its
    release for ``clear_hold_s`` before it clears; estimates more than ``max_gap_s``
    apart (or going back in time) break the continuity. A condition that is *sure*, the
    value past its threshold by at least ``sure_sigmas`` times the estimate's std (both
    relative to nominal) on every estimate, raises after ``sure_hold_s`` instead: a
    damper the estimator has found failed need not wait the noise hold. With
    ``act_on_located`` a change the fault bank located, its whole likelihood interval past
    a threshold, raises with the estimate that reports it (docs/alerts.md, "Located changes").
    """

    params: Mapping[str, ParamPolicy] = field(default_factory=default_params)
    raise_hold_s: float = 3.0
    clear_hold_s: float = 5.0
    max_gap_s: float = 2.0
    sure_hold_s: float = 0.5
    sure_sigmas: float = 4.0
    act_on_located: bool = True

    def __post_init__(self) -> None:
        unknown = sorted(set(self.params) - set(PARAM_NAMES))
        if unknown:
            raise ConfigError(f"expected parameters from {PARAM_NAMES}, got {unknown}")
        for name in ("raise_hold_s", "clear_hold_s", "max_gap_s", "sure_hold_s",
                     "sure_sigmas"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"expected {name} finite and >= 0, got {value!r}")


@dataclass
class _Track:
    """Mutable per-parameter state; ``since`` = data time a raw condition began, per side."""

    severity: int = 0
    side: str = ""
    acknowledged: bool = False
    raised_seq: int = 0
    last: Alert | None = None
    value_rel: float = math.nan
    last_t_s: float | None = None
    release_since: float | None = None
    baseline_t_s: float | None = None
    located_t_s: float | None = None        # the fault-bank change last acted on
    since: dict[str, list[float | None]] = field(
        default_factory=lambda: {s: [None, None, None] for s in SIDES})
    sure_since: dict[str, list[float | None]] = field(
        default_factory=lambda: {s: [None, None, None] for s in SIDES})

    def reset_timers(self) -> None:
        self.since = {s: [None, None, None] for s in SIDES}
        self.sure_since = {s: [None, None, None] for s in SIDES}
        self.release_since = None


def _alert_from_json(d: Any, version: int) -> Alert:
    """An alert of a snapshot; version 1 wrote severity and state as integers."""
    try:
        if version == 1:
            d = {**d, "severity": Severity(d["severity"]).name,
                 "state": AlertState(d["state"]).name}
        return jsonform.alert_from_json(d)
    except (KeyError, TypeError, ValueError) as err:
        raise StateError(f"expected an alert object, got {d!r} ({err})") from err


class AlertPolicy:
    """Alert events from estimates: ``events = policy.step(estimate)``.

    One active alert per parameter at its current severity. Events are :class:`Alert`
    records with ``seq`` strictly increasing over the gateway's life (persist the
    snapshot and the history and :meth:`restore` from both).

    ``reserve(upto) -> bool``, if given, is called before a seq at or past the reserved
    bound is used, to record durably that seqs below ``upto`` (``SEQ_BLOCK`` more) may be
    used; :meth:`restore` from that bound then never repeats a seq, even if the events
    themselves were never persisted. A failed reservation does not hold an alert back
    (it still goes out); it is counted in :attr:`seq_unreserved`.
    """

    def __init__(self, config: PolicyConfig | None = None, *, next_seq: int = 1,
                 reserve: Callable[[int], bool] | None = None) -> None:
        self._config = config or PolicyConfig()
        self._next_seq = next_seq
        self._reserve = reserve
        self._reserved_upto = next_seq
        self.seq_unreserved = 0
        """Events emitted with a seq whose reservation could not be persisted."""
        self._tracks = {name: _Track() for name in self._config.params}
        self._senders: dict[str, tuple[int, Alert]] = {}
        """Active two-sender alerts: parameter -> (seq of the RAISED event, latest event)."""
        self._overrides: list[tuple[str, int, str, float | None]] = []
        self.restore_problems: list[str] = []  # persisted overrides that no longer validate

    @property
    def config(self) -> PolicyConfig:
        """The effective configuration, including run-time threshold changes."""
        return self._config

    @property
    def next_seq(self) -> int:
        return self._next_seq

    @property
    def active(self) -> tuple[Alert, ...]:
        """The latest event (RAISED or ACKNOWLEDGED) of each active alert, by parameter
        (suspension parameters first, then two-sender alerts)."""
        return tuple(tr.last for tr in self._tracks.values() if tr.severity and tr.last) + \
            tuple(last for _, last in self._senders.values())

    # -- two senders ---------------------------------------------------------------
    def two_senders_active(self, message: str) -> bool:
        """Is a two-sender alert active for ``message`` (e.g. ``BGN_Lat``)?"""
        return sender_parameter(message) in self._senders

    def two_senders(self, message: str, flagged: bool, t_s: float) -> list[Alert]:
        """The front end's two-sender flag of ``message`` at data time ``t_s``: RAISED
        (ADVISORY, :data:`CODE_TWO_SENDERS`) when it is set and no such alert is active,
        CLEARED when it is clear and one is; else no event. One alert per episode."""
        if not (isinstance(t_s, int | float) and math.isfinite(t_s)):
            raise InputError(f"expected a finite data time t_s, got {t_s!r}")
        param = sender_parameter(message)
        node = param[len(NODE_PREFIX):]
        if flagged and param not in self._senders:
            alert = self._sender_event(param, AlertState.RAISED, t_s,
                                       f"two senders on {node} ({message}): its frames are "
                                       f"excluded from the estimator")
            self._senders[param] = (alert.seq, alert)
            return [alert]
        if not flagged and param in self._senders:
            del self._senders[param]
            return [self._sender_event(param, AlertState.CLEARED, t_s,
                                       f"single sender on {node} ({message}) again")]
        return []

    def _sender_event(self, param: str, state: AlertState, t_s: float,
                      message: str) -> Alert:
        return Alert(self._take_seq(), t_s, param, Severity.ADVISORY, state,
                     CODE_TWO_SENDERS, math.nan, message)

    def baseline_times(self) -> dict[str, float | None]:
        """Data time of the last baseline reset per parameter (None: never)."""
        return {name: tr.baseline_t_s for name, tr in self._tracks.items()}

    # -- judging -------------------------------------------------------------------
    def step(self, estimate: Estimate) -> list[Alert]:
        """Judge one estimate; returns the events it causes (usually none). A provisional
        estimate (the estimator still tests its model) is not judged: timers restart; nor
        is a parameter the estimate calls unresolved (``Estimate.unresolved``: the
        sensors in use cannot resolve it), as behind a closed gate, though the fault
        bank's located change of it still acts."""
        events: list[Alert] = []
        if estimate.provisional:
            for tr in self._tracks.values():
                tr.reset_timers()
            return events
        for name, pp in self._config.params.items():
            try:
                i = estimate.names.index(name)
            except ValueError as err:
                raise InputError(f"expected estimate names to include {name!r}, "
                                 f"got {estimate.names}") from err
            loc = estimate.located
            if loc is not None and loc.parameter == name and self._config.act_on_located:
                events += self._located(name, pp, self._tracks[name], estimate.t_s, loc)
            if name in estimate.unresolved:
                # the sensors in use cannot resolve it: its mean is what the filters knew
                # before, so it is not judged (a closed gate); a located change is data
                self._tracks[name].reset_timers()
                continue
            events += self._judge(name, pp, self._tracks[name], estimate.t_s,
                                  float(estimate.mean[i]), float(estimate.std[i]))
        return events

    def _located(self, name: str, pp: ParamPolicy, tr: _Track, t_s: float, loc: Located
                 ) -> list[Alert]:
        """Raise (or escalate) at once to the highest level whose threshold the whole
        likelihood interval ``like_lo``..``like_hi`` is past; nothing if no level is. Each
        change is acted on once (estimates carry it for 2 s; after a restart, acting again
        raises nothing that is already raised)."""
        if loc.t_s == tr.located_t_s:
            return []
        tr.located_t_s = loc.t_s
        sev, side = 0, ""
        for s in SIDES:
            edge = loc.like_hi if s == "low" else loc.like_lo
            for k, threshold in enumerate(pp.levels(s)):
                if threshold is not None and judge.beyond(s, edge, threshold) and k + 1 > sev:
                    sev, side = k + 1, s
        if not sev or (tr.severity and side == tr.side and sev <= tr.severity):
            return []
        tr.value_rel = loc.rel
        return self._raise_over(name, pp, tr, sev, side, t_s,
                                f"{name} located by the fault bank at {loc.rel:.3f} of "
                                f"nominal (likely {loc.like_lo:.3f}-{loc.like_hi:.3f})")

    def _judge(self, name: str, pp: ParamPolicy, tr: _Track, t_s: float, mean: float,
               std: float) -> list[Alert]:
        cfg = self._config
        if not math.isfinite(t_s):
            tr.reset_timers()
            return []
        if tr.last_t_s is None or not t_s >= tr.last_t_s or t_s - tr.last_t_s > cfg.max_gap_s:
            tr.reset_timers()                       # first estimate, gap or time went back
        tr.last_t_s = t_s
        rel = judge.value_rel(mean, pp.nominal)
        std_rel = judge.sigma_rel(mean, std, pp.nominal)
        if rel is None or not judge.judgeable(rel, std_rel, pp.max_std_rel):
            tr.reset_timers()                       # gate closed: no judgement at all
            return []
        tr.value_rel = rel
        margin = cfg.sure_sigmas * std / pp.nominal     # "sure": this far past, in rel
        sev, side = 0, ""                           # highest level held long enough
        for s in SIDES:
            for k, threshold in enumerate(pp.levels(s)):
                if threshold is None or not judge.beyond(s, rel, threshold):
                    tr.since[s][k] = tr.sure_since[s][k] = None
                    continue
                start = tr.since[s][k]
                if start is None:
                    start = tr.since[s][k] = t_s
                sure = tr.sure_since[s][k]
                if not judge.beyond(s, rel, threshold - margin if s == "low"
                                    else threshold + margin):
                    sure = tr.sure_since[s][k] = None
                elif sure is None:
                    sure = tr.sure_since[s][k] = t_s
                held = t_s - start >= cfg.raise_hold_s or (
                    sure is not None and t_s - sure >= cfg.sure_hold_s)
                if held and k + 1 > sev:
                    sev, side = k + 1, s
        if sev and (tr.severity == 0 or side != tr.side or sev > tr.severity):
            return self._raise_over(name, pp, tr, sev, side, t_s,
                                    f"{name} at {rel:.3f} of nominal")
        return self._release(name, pp, tr, t_s, rel) if tr.severity else []

    def _raise_over(self, name: str, pp: ParamPolicy, tr: _Track, sev: int, side: str,
                    t_s: float, what: str) -> list[Alert]:
        """Raise ``sev`` on ``side``, clearing first an alert on the other side; the
        message is ``what`` and the threshold passed."""
        events = [self._clear(name, tr, t_s, f"superseded on the {side} side")
                  ] if tr.severity and side != tr.side else []
        return events + [self._raise(name, tr, sev, side, t_s,
                                     f"{what}, {side}-side {Severity(sev).name} threshold "
                                     f"{pp.levels(side)[sev - 1]:g}")]

    def _release(self, name: str, pp: ParamPolicy, tr: _Track, t_s: float,
                 rel: float) -> list[Alert]:
        """Clear or de-escalate once ``rel`` has been past threshold + hysteresis for
        ``clear_hold_s``; the new level is the highest one still held with hysteresis."""
        margin = pp.hysteresis_rel if tr.side == "low" else -pp.hysteresis_rel
        hold = max((k + 1 for k, threshold in enumerate(pp.levels(tr.side))
                    if threshold is not None and judge.beyond(tr.side, rel, threshold + margin)),
                   default=0)
        if hold >= tr.severity:
            tr.release_since = None
            return []
        tr.release_since = t_s if tr.release_since is None else tr.release_since
        if t_s - tr.release_since < self._config.clear_hold_s:
            return []
        side = tr.side
        events = [self._clear(name, tr, t_s, f"{name} back to {rel:.3f} of nominal "
                                             f"(hysteresis {pp.hysteresis_rel:g})")]
        if hold:
            events.append(self._raise(name, tr, hold, side, t_s,
                                      f"{name} de-escalated to {Severity(hold).name} at "
                                      f"{rel:.3f} of nominal"))
        return events

    def _take_seq(self) -> int:
        """The next seq, reserved durably first when the reserved block is used up."""
        if self._reserve is not None and self._next_seq >= self._reserved_upto:
            upto = self._next_seq + SEQ_BLOCK
            if self._reserve(upto):
                self._reserved_upto = upto
            else:
                self.seq_unreserved += 1
        seq = self._next_seq
        self._next_seq += 1
        return seq

    def _event(self, name: str, tr: _Track, sev: int, side: str, state: AlertState,
               t_s: float, message: str) -> Alert:
        return Alert(self._take_seq(), t_s, name, Severity(sev), state,
                     alert_code(name, Severity(sev), side), tr.value_rel, message)

    def _raise(self, name: str, tr: _Track, sev: int, side: str, t_s: float,
               message: str) -> Alert:
        alert = self._event(name, tr, sev, side, AlertState.RAISED, t_s, message)
        tr.severity, tr.side, tr.acknowledged = sev, side, False
        tr.raised_seq, tr.last, tr.release_since = alert.seq, alert, None
        return alert

    def _clear(self, name: str, tr: _Track, t_s: float, message: str) -> Alert:
        alert = self._event(name, tr, tr.severity, tr.side, AlertState.CLEARED, t_s, message)
        tr.severity, tr.side, tr.acknowledged = 0, "", False
        tr.raised_seq, tr.last, tr.release_since = 0, None, None
        return alert

    # -- fitter commands ------------------------------------------------------------
    def _track(self, parameter: str, t_s: float = 0.0) -> _Track:
        if not (isinstance(t_s, int | float) and math.isfinite(t_s)):
            raise InputError(f"expected a finite data time t_s, got {t_s!r}")
        if parameter not in self._tracks:
            raise InputError(f"expected a parameter from {tuple(self._tracks)}, "
                             f"got {parameter!r}")
        return self._tracks[parameter]

    def acknowledge(self, key: int | str, t_s: float) -> Alert:
        """Acknowledge an active alert by parameter name or by the seq of its RAISED (or
        latest) event; returns the ACKNOWLEDGED event. InputError if none matches."""
        if not (isinstance(t_s, int | float) and math.isfinite(t_s)):
            raise InputError(f"expected a finite data time t_s, got {t_s!r}")
        sender = [p for p, (raised, last) in self._senders.items()
                  if key == p or (not isinstance(key, bool | str) and key in (raised, last.seq))]
        if sender:
            raised, last = self._senders[sender[0]]
            if last.state == AlertState.ACKNOWLEDGED:
                raise InputError(f"expected a RAISED alert, got alert {raised} "
                                 f"({sender[0]}) already ACKNOWLEDGED")
            alert = self._sender_event(sender[0], AlertState.ACKNOWLEDGED, t_s,
                                       f"two senders on {sender[0][len(NODE_PREFIX):]} "
                                       f"acknowledged")
            self._senders[sender[0]] = (raised, alert)
            return alert
        if isinstance(key, str):
            name, tr = key, self._track(key)
            if not tr.severity:
                raise InputError(f"expected an active alert for {key}, got none")
        else:
            found = [(n, t) for n, t in self._tracks.items() if t.severity and t.last
                     and key in (t.raised_seq, t.last.seq)]
            if isinstance(key, bool) or not found:
                seqs = [t.raised_seq for t in self._tracks.values() if t.severity] + [
                    raised for raised, _ in self._senders.values()]
                raise InputError(f"expected the seq of an active alert {seqs}, got {key!r}")
            name, tr = found[0]
        if tr.acknowledged:
            raise InputError(f"expected a RAISED alert, got alert {tr.raised_seq} "
                             f"({name}) already ACKNOWLEDGED")
        alert = self._event(name, tr, tr.severity, tr.side, AlertState.ACKNOWLEDGED, t_s,
                            f"{name} {Severity(tr.severity).name} acknowledged")
        tr.acknowledged, tr.last = True, alert
        return alert

    def reset_baseline(self, parameter: str, t_s: float) -> list[Alert]:
        """Record a baseline reset (component replaced) at data time ``t_s``: clears the
        parameter's active alert (CLEARED event) and restarts its hold timers."""
        tr = self._track(parameter, t_s)
        events = []
        if tr.severity:
            events.append(self._clear(parameter, tr, t_s, f"{parameter} baseline reset"))
        tr.reset_timers()
        tr.baseline_t_s = t_s
        return events

    def set_threshold(self, parameter: str, severity: Severity | int | str,
                      value_rel: float | None, side: str | None = None) -> None:
        """Change one threshold at run time (console). ``side`` defaults to "low" when
        ``value_rel < 1`` and "high" when ``> 1``; ``value_rel=None`` disables the level
        (needs ``side``). InputError ("expected ..., got ...") if invalid."""
        self._track(parameter)
        try:
            sev = Severity[severity.upper()] if isinstance(severity, str) else Severity(severity)
        except (KeyError, ValueError) as err:
            raise InputError(f"expected a severity from {[s.name for s in Severity]}, "
                             f"got {severity!r}") from err
        if value_rel is not None and not (isinstance(value_rel, int | float)
                                          and math.isfinite(value_rel)):
            raise InputError(f"expected a finite threshold relative to nominal, "
                             f"got {value_rel!r}")
        inferred = None if value_rel is None or value_rel == 1 else (
            "low" if value_rel < 1 else "high")
        side = side or inferred
        if side not in SIDES or (inferred and side != inferred):
            raise InputError(f"expected side 'low' (threshold < 1) or 'high' (> 1), got "
                             f"side {side!r} with threshold {value_rel!r}")
        pp = self._config.params[parameter]
        levels = list(pp.levels(side))
        levels[sev - 1] = None if value_rel is None else float(value_rel)
        new_levels: Levels = (levels[0], levels[1], levels[2])
        problem = _side_problem(side, new_levels, pp.hysteresis_rel)
        if problem:
            raise InputError(f"{parameter}: {problem}")
        params = dict(self._config.params)
        params[parameter] = (dataclasses.replace(pp, low_rel=new_levels) if side == "low"
                             else dataclasses.replace(pp, high_rel=new_levels))
        self._config = dataclasses.replace(self._config, params=params)
        self._overrides.append((parameter, int(sev), side, levels[sev - 1]))
        self._tracks[parameter].reset_timers()

    # -- checkpoint ------------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """The full policy state as a JSON-compatible dict (alerts in their
        :func:`gateway.jsonform.alert_json` form; NaN as None)."""
        params = {name: {**dataclasses.asdict(tr), "value_rel": jsonform.finite(tr.value_rel),
                         "last": None if tr.last is None else jsonform.alert_json(tr.last)}
                  for name, tr in self._tracks.items()}
        senders = {p: [raised, jsonform.alert_json(last)]
                   for p, (raised, last) in self._senders.items()}
        return {"version": SNAPSHOT_VERSION, "next_seq": self._next_seq,
                "overrides": [list(o) for o in self._overrides], "params": params,
                "senders": senders}

    @classmethod
    def restore(cls, snapshot: Mapping[str, Any] | None, config: PolicyConfig | None = None,
                history: Iterable[Alert] = (), *, reserved_upto: int | None = 0,
                reserve: Callable[[int], bool] | None = None,
                strict: bool = True) -> AlertPolicy:
        """A policy from ``snapshot`` (or fresh if None) on top of ``config``, then brought up
        to date with the alert ``history`` events newer than the snapshot (a crash between
        the history append and the snapshot write loses nothing). StateError if the
        snapshot is malformed, or (``strict``) a history event is; with ``strict=False``
        such an event is skipped and noted in :attr:`restore_problems`.

        ``reserved_upto``: the persisted seq reservation; the next seq is at least that
        (0: none kept yet; None: it was lost, so one more ``SEQ_BLOCK`` is skipped).
        ``reserve``: see the class."""
        policy = cls(config)
        if snapshot is not None:
            try:
                policy._load(snapshot)
            except (KeyError, TypeError, ValueError, AttributeError, RecursionError) as err:
                raise StateError(f"expected an alert-policy snapshot version "
                                 f"{SNAPSHOT_VERSIONS_READ}, got a malformed one "
                                 f"({err!r})") from err
        for alert in sorted(history, key=lambda a: a.seq):
            if alert.seq >= policy._next_seq:
                try:
                    policy._apply(alert)
                except InputError as err:
                    if strict:
                        raise StateError(f"alert history seq {alert.seq}: {err}") from err
                    policy.restore_problems.append(f"alert history seq {alert.seq} "
                                                   f"skipped: {err}")
        floor = policy._next_seq + SEQ_BLOCK if reserved_upto is None else reserved_upto
        if not (isinstance(floor, int) and floor >= 0):
            raise StateError(f"expected a seq reservation >= 0, got {reserved_upto!r}")
        policy._next_seq = policy._reserved_upto = max(policy._next_seq, floor)
        policy._reserve = reserve
        return policy

    def _load(self, snap: Mapping[str, Any]) -> None:
        version = snap["version"]
        if isinstance(version, bool) or version not in SNAPSHOT_VERSIONS_READ:
            raise ValueError(f"version {version!r}")
        for parameter, sev, side, value in snap["overrides"]:
            try:
                self.set_threshold(parameter, sev, value, side)
            except InputError as err:
                self.restore_problems.append(f"threshold override not restored: {err}")
        next_seq = snap["next_seq"]
        if isinstance(next_seq, bool) or not (isinstance(next_seq, int) and next_seq >= 1):
            raise ValueError(f"expected next_seq an integer >= 1, got {next_seq!r}")
        self._next_seq = next_seq
        for name, d in snap["params"].items():
            if name in self._tracks:
                last = (_alert_from_json(d["last"], version) if d["last"] is not None
                        else None)
                since = {side: [None if x is None else float(x) for x in d["since"][side]]
                         for side in SIDES}
                value_rel = math.nan if d["value_rel"] is None else float(d["value_rel"])
                self._tracks[name] = _Track(**{**d, "last": last, "since": since,
                                               "value_rel": value_rel})
        for param, (raised, d) in snap.get("senders", {}).items():
            last = _alert_from_json({**d, "value_rel": None}, version)
            if not (isinstance(raised, int) and last.code == CODE_TWO_SENDERS
                    and param.startswith(NODE_PREFIX)):
                raise ValueError(f"expected a two-sender alert, got {param!r}: {d!r}")
            self._senders[param] = (raised, last)

    def _apply(self, alert: Alert) -> None:
        """Replay one persisted event onto the active set (restore)."""
        self._next_seq = max(self._next_seq, alert.seq + 1)
        if alert.code == CODE_TWO_SENDERS:
            if alert.state == AlertState.RAISED:
                self._senders[alert.parameter] = (alert.seq, alert)
            elif alert.parameter in self._senders:
                if alert.state == AlertState.CLEARED:
                    del self._senders[alert.parameter]
                else:
                    self._senders[alert.parameter] = (self._senders[alert.parameter][0], alert)
            return
        tr = self._tracks.get(alert.parameter)
        if tr is None:
            return
        _, _, side = decode_code(alert.code)
        if alert.state == AlertState.RAISED:
            tr.severity, tr.side, tr.acknowledged = int(alert.severity), side, False
            tr.raised_seq, tr.last, tr.value_rel = alert.seq, alert, alert.value_rel
        elif tr.severity == int(alert.severity) and tr.side == side:
            if alert.state == AlertState.ACKNOWLEDGED:
                tr.acknowledged, tr.last = True, alert
            else:
                tr.severity, tr.side, tr.acknowledged, tr.raised_seq, tr.last = (
                    0, "", False, 0, None)
