"""The seam between the console and the service: the ServiceView protocol and its shapes.

The console never imports the service; the service implements :class:`ServiceView`.
The read side returns plain dicts (JSON-compatible, shapes below) so that the console
can print them for a fitter and pass them through unchanged in JSON mode; the console
renders them defensively (missing keys show as "-"). The write side returns typed
frozen results (:class:`AckResult`, :class:`BaselineResult`, :class:`ThresholdResult`),
each with its JSON form (alerts: :func:`gateway.jsonform.alert_json`). The helpers here
(:func:`estimates_view`, :func:`history_row`, :func:`resolve_parameter`) build the read
shapes from the shared records, for the service and for the test doubles alike: alerts
and estimates in the one JSON form of :mod:`gateway.jsonform`, relative values and the
confidence gate from the one judge, :mod:`gateway.alerts.judge`.

Every method is called from the console's port thread: the service must make them
thread-safe. Write methods are called only after login and a successful audit of the
attempt, with canonical arguments (parameter names from :data:`gateway.model.vehicle.PARAM_NAMES`,
a :class:`Severity`), and raise :class:`gateway.errors.InputError` ("expected ..., got
...") to refuse.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from gateway.alerts import judge
from gateway.alerts.policy import Levels
from gateway.console.session import LockoutState
from gateway.errors import InputError
from gateway.jsonform import alert_json, estimate_json, finite, params_json
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL
from gateway.records import Alert, Estimate, Severity


@dataclass(frozen=True)
class AckResult:
    """``ack``: the ACKNOWLEDGED event the service emitted."""

    alert: Alert

    def to_json(self) -> dict[str, Any]:
        return {"alert": alert_json(self.alert)}


@dataclass(frozen=True)
class BaselineResult:
    """``baseline reset``: the parameter, the data time ``t_s`` (s, NaN before the first
    estimate), the CLEARED events it caused and what the estimator does now."""

    parameter: str
    t_s: float
    cleared: tuple[Alert, ...]
    estimator: str = "re-learning this parameter from the prior"

    def to_json(self) -> dict[str, Any]:
        return {"parameter": self.parameter, "t_s": finite(self.t_s),
                "events": [alert_json(a) for a in self.cleared], "estimator": self.estimator}


@dataclass(frozen=True)
class ThresholdResult:
    """``threshold set``: the changed level and the parameter's thresholds afterwards."""

    parameter: str
    side: str
    severity: Severity
    value_rel: float
    low_rel: Levels
    high_rel: Levels

    def to_json(self) -> dict[str, Any]:
        return {"parameter": self.parameter, "side": self.side,
                "severity": self.severity.name, "value_rel": finite(self.value_rel),
                "thresholds": {"low": [finite(v) for v in self.low_rel],
                               "high": [finite(v) for v in self.high_rel]}}


class ServiceView(Protocol):
    """What the console asks of the running service.

    Dict shapes of the read side (every key optional for the console; units in names):

    - ``status()``: ``{"state": "Running", "uptime_s", "version", "data_time_s",
      "worker": {"alive", "restarts", "pid", "rtf"}, "bus": {"state", "open"},
      "active_alerts"}``.
    - ``estimates()``: as built by :func:`estimates_view`.
    - ``alerts()``: ``(active, recent)``; recent oldest first.
    - ``history(hours)``: rows as built by :func:`history_row`, oldest first, from the
      persisted estimate history (including baseline-reset events).
    - ``sensors()``: ``{message: {"rate_hz", "expected_hz", "accepted",
      "rejected": {reason: n}, "lost_frames", "timeouts", "timed_out",
      "last_values": {signal: value}}}`` (see ``gateway.frontend.validate.MessageStats``).
    - ``bus()``: ``{"interface", "channel", "state", "open", "load_pct",
      "error_frames", "frames_rx", "frames_tx", "reopens", "dropped", "last_error"}``.
    - ``config_text()``: the running configuration as TOML (``gateway.config.as_toml``).
    - ``log_lines(n)``: the last ``n`` log lines, oldest first.
    - ``audit(entry)``: persist one audit entry (a JSON-compatible dict: ``time``,
      ``t_unix_s``, ``who``, ``port``, ``session``, ``command``, ``args``, ``result``
      ("attempt", "ok", "refused", "rejected", "error" or, for login,
      "failed"/"locked"), ``detail``); False when it could not be written (the console
      then refuses the write command: fail closed).
    - ``load_lockout()`` / ``save_lockout(state)``: the PIN lockout, kept where a
      restart does not lose it.
    """

    def status(self) -> dict[str, Any]: ...

    def estimates(self) -> dict[str, Any]: ...

    def alerts(self) -> tuple[Sequence[Alert], Sequence[Alert]]: ...

    def history(self, hours: float) -> list[dict[str, Any]]: ...

    def sensors(self) -> dict[str, Any]: ...

    def bus(self) -> dict[str, Any]: ...

    def config_text(self) -> str: ...

    def log_lines(self, n: int) -> list[str]: ...

    def acknowledge(self, alert_key: int | str) -> AckResult: ...

    def baseline_reset(self, component: str) -> BaselineResult: ...

    def set_threshold(self, parameter: str, severity: Severity,
                      value_rel: float) -> ThresholdResult: ...

    def audit(self, entry: dict[str, Any]) -> bool: ...

    def load_lockout(self) -> LockoutState | None: ...

    def save_lockout(self, state: LockoutState) -> bool: ...


@dataclass(frozen=True)
class ParamInfo:
    """How a parameter is shown to a fitter: ``value * scale`` in ``unit``."""

    name: str
    label: str
    component: str
    unit: str
    scale: float
    aliases: tuple[str, ...]


PARAMS: dict[str, ParamInfo] = {
    "csy_ns_per_m": ParamInfo("csy_ns_per_m", "Csy", "lateral damper", "kNs/m", 1e-3,
                              ("csy", "lateral-damper", "lateral", "csy_ns_per_m")),
    "csay_ns_per_m": ParamInfo("csay_ns_per_m", "Csay", "anti-yaw damper", "kNs/m", 1e-3,
                               ("csay", "anti-yaw-damper", "yaw-damper", "anti-yaw",
                                "csay_ns_per_m")),
    "conicity": ParamInfo("conicity", "lambda", "wheelset", "", 1.0,
                          ("conicity", "wheelset", "lambda", "wheels")),
}
"""Display names and the aliases a fitter may type, per :data:`PARAM_NAMES` entry."""

NOMINAL: dict[str, float] = {name: float(getattr(THETA_NOMINAL, name)) for name in PARAM_NAMES}


def _norm(text: str) -> str:
    return text.strip().lower().replace("_", "-")


def resolve_parameter(text: str) -> str:
    """The :data:`PARAM_NAMES` entry a fitter means (``csy``, ``lateral-damper``,
    ``wheelset``, ...); InputError listing the choices otherwise."""
    key = _norm(text)
    for info in PARAMS.values():
        if key in {_norm(a) for a in info.aliases}:
            return info.name
    choices = ", ".join("/".join(info.aliases[:2]) for info in PARAMS.values())
    raise InputError(f"expected a component or parameter ({choices}), got {text!r}")




def estimates_view(est: Estimate | None, *,
                   thresholds: Mapping[str, Mapping[str, Sequence[float | None]]],
                   active: Sequence[Alert] = (), particles: int | None = None,
                   max_std_rel: Mapping[str, float] | None = None,
                   nominal: Mapping[str, float] = NOMINAL) -> dict[str, Any]:
    """The ``estimates()`` dict from the latest estimate.

    ``{"t_s", "ess", "particles", "updated", "left_out", "unresolved", "parameters": {name:
    {"mean", "std", "nominal", "value_rel", "sigma_rel", "thresholds": {"low": [A, W, Al],
    "high": [...]},
    "status": "OK"|"ADVISORY"|"WARNING"|"ALARM", "alert_state", "alert_seq",
    "confident"}}}``. ``status`` is the active alert's severity (the policy's judgement
    with hold times), else "OK"; ``confident`` is False while ``sigma_rel`` is above the
    policy's confidence gate ``max_std_rel``; ``left_out`` the sensors the estimate did
    without (a dead node), ``[]`` when none; ``unresolved`` the parameters the sensors
    in use cannot resolve (:mod:`gateway.estimator.observability`), ``[]`` when none.
    ``est`` None gives no parameters.

    Built from the one estimate form (:func:`gateway.jsonform.estimate_json`: ``t_s``,
    ``ess``, ``updated``, ``left_out``, ``unresolved``, each parameter's ``mean`` and
    ``std``) plus, per parameter, what the judge (:mod:`gateway.alerts.judge`) makes of
    it; it differs from that form because it is the console's documented reply
    (docs/console.md), made for a fitter.
    """
    out: dict[str, Any] = {"t_s": None, "ess": None, "particles": particles,
                           "updated": None, "left_out": [], "unresolved": [],
                           "parameters": {}}
    if est is None:
        return out
    form = estimate_json(est)                  # the one estimate form, then the judge's view
    out.update(t_s=form["t_s"], ess=form["ess"], updated=form["updated"],
               left_out=form["left_out"], unresolved=form["unresolved"])
    by_param = {a.parameter: a for a in active}
    for name, mean, std in zip(est.names, est.mean, est.std, strict=True):
        nom = nominal.get(name)
        rel = judge.value_rel(mean, nom)
        sigma_rel = judge.sigma_rel(mean, std, nom)
        levels = thresholds.get(name, {})
        alert = by_param.get(name)
        gate = (max_std_rel or {}).get(name)
        out["parameters"][name] = {
            **form["params"][name], "nominal": nom,
            "value_rel": finite(rel), "sigma_rel": finite(sigma_rel),
            "thresholds": {side: [finite(t) for t in lv] for side, lv in levels.items()},
            "status": alert.severity.name if alert else "OK",
            "alert_state": alert.state.name if alert else None,
            "alert_seq": alert.seq if alert else None,
            "confident": (None if gate is None or sigma_rel is None
                          else judge.confident(sigma_rel, gate)),
        }
    return out


def history_row(t_s: float, est: Estimate | None = None, *, event: str | None = None,
                time: str | None = None) -> dict[str, Any]:
    """One ``history()`` row: ``{"t_s", "time" (ISO wall time or None), "estimates":
    {name: {"mean", "std"}}, "event" (e.g. "baseline reset csy_ns_per_m") or None}``."""
    ests = {} if est is None else params_json(est)
    return {"t_s": finite(t_s), "time": time, "estimates": ests, "event": event}
