"""The detection study's alert columns: one run's estimates judged by the default alert policy.

Three readings of the same estimates (:func:`alert_columns`): the service's policy, which
raises a located change at once on its likelihood interval; the policy judging the
estimates alone (``act_on_located=False``, as before 2026-11-26); and the policy raising
a located change on its redraw range (as before the night of 2026-11-27). No simulation,
no filter.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from gateway.alerts.policy import AlertPolicy, PolicyConfig
from gateway.records import Estimate, Severity

Raised = list[tuple[float, str, str]]
"""Raised alerts: (data time, parameter, severity name)."""


def alerts(est: Sequence[Estimate], act_on_located: bool = True, on_range: bool = False
           ) -> Raised:
    """Raised alerts of the default policy over ``est`` (``act_on_located`` False:
    judging the estimates alone; ``on_range``: a located change raises at once on its
    redraw range instead of its likelihood interval)."""
    policy = AlertPolicy(PolicyConfig(act_on_located=act_on_located))
    if on_range:
        est = [e if e.located is None else replace(e, located=replace(
            e.located, like_lo=e.located.rel_lo, like_hi=e.located.rel_hi)) for e in est]
    return [(a.t_s, a.parameter, a.severity.name) for e in est for a in policy.step(e)
            if a.state.name == "RAISED"]


def _first_after(raised: Raised, name: str, after_s: float) -> tuple[float, str] | None:
    """(data time, severity) of the first alert on ``name`` after ``after_s`` (s)."""
    return next(((t, sev) for t, n, sev in raised if n == name and t > after_s), None)


def _first(raised: Raised, name: str, after_s: float, severity: str | None = None
           ) -> float | None:
    """Data time after ``after_s`` (s, rounded to 0.01) of the first alert on ``name``
    (of ``severity`` only, if given; an ALARM counts from the start of the run)."""
    if severity is None:
        first = _first_after(raised, name, after_s)
        return None if first is None else round(first[0] - after_s, 2)
    times = [t - after_s for t, n, sev in raised if n == name and sev == severity]
    return round(times[0], 2) if times else None


def _highest(raised: Raised, name: str) -> str | None:
    """The highest level raised on parameter ``name`` (None: nothing)."""
    levels = [sev for _, n, sev in raised if n == name]
    return max(levels, key=lambda sev: Severity[sev].value, default=None)


def alert_columns(est: Sequence[Estimate], name: str, fault_at_s: float) -> dict[str, Any]:
    """A fault run's alert columns (the module docstring of
    :mod:`firmware_sim.studies.detection` names them) for a fault on ``name`` at
    ``fault_at_s``."""
    raised = alerts(est)
    ranged = alerts(est, on_range=True)
    return {"alert_s": _first(raised, name, fault_at_s),
            "alarm_s": _first(raised, name, fault_at_s, "ALARM"),
            "alert_estimates_only_s": _first(alerts(est, act_on_located=False), name,
                                             fault_at_s),
            "alert_on_range_s": _first(ranged, name, fault_at_s),
            "alarm_on_range_s": _first(ranged, name, fault_at_s, "ALARM"),
            "alerts_healthy_on_range": sum(n != name for _, n, _ in ranged),
            "severity_max": _highest(raised, name),
            "severity_max_on_range": _highest(ranged, name),
            "alert_severity": (first[1] if (first := _first_after(raised, name, fault_at_s))
                               else None),
            "alerts_healthy": sum(n != name for _, n, _ in raised),
            "alerts_before": sum(t <= fault_at_s for t, _, _ in raised)}
