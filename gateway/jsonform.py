"""The one JSON form of the shared records: an :class:`Estimate` and an :class:`Alert`.

Every place that writes these records as JSON builds on the forms here: the console's
replies (``gateway.console.view``), the state directory (``gateway.sinks.store.codec``),
the alert policy's snapshot (``gateway.alerts.policy``) and the replay's JSON Lines
(``gateway.offline.replay``). Where a place needs a different shape (the store adds
``wall_time_s``; replay lines are rounded), it derives it from these forms and says why
in one comment there.

Strict JSON: a non-finite float (NaN, inf) is written as ``null`` (:func:`finite`) and
read back as NaN (:func:`number`). Enums are written by name (``"ALARM"``, ``"RAISED"``).

- alert: ``{"seq", "t_s", "parameter", "severity", "state", "code", "value_rel",
  "message"}``;
- estimate: ``{"t_s", "ess", "updated", "provisional", "v_sy_mps", "v_say_mps", "params": {name:
  {"mean", "std"}}, "located", "left_out", "unresolved"}`` (:func:`params_json` is the
  ``params`` part alone; ``located`` null, or the fault bank's change ``{"t_s",
  "parameter", "rel", "rel_lo", "rel_hi", "like_lo", "like_hi"}``, :func:`located_json`;
  ``left_out`` the names of the sensors the estimate did without, ``[]`` when it used
  them all; ``unresolved`` the parameters the sensors in use cannot resolve at that
  speed, ``[]`` when none).
"""

from __future__ import annotations

import math
from typing import Any

from gateway.records import Alert, AlertState, Estimate, Located, Severity


def finite(x: float | None) -> float | None:
    """``x`` as a float, or None when it is None or not finite (JSON has no NaN)."""
    return float(x) if x is not None and math.isfinite(x) else None


def number(x: Any) -> float:
    """A JSON number back as a float; ``null`` is NaN. TypeError for anything else."""
    if x is None:
        return math.nan
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise TypeError(f"expected a number or null, got {x!r}")
    return float(x)


def alert_json(alert: Alert) -> dict[str, Any]:
    """The JSON form of an alert event (severity and state by name)."""
    return {"seq": alert.seq, "t_s": finite(alert.t_s), "parameter": alert.parameter,
            "severity": alert.severity.name, "state": alert.state.name,
            "code": alert.code, "value_rel": finite(alert.value_rel),
            "message": alert.message}


def alert_from_json(d: Any) -> Alert:
    """Inverse of :func:`alert_json`; ``message`` may be missing. ValueError, KeyError or
    TypeError ("expected ..., got ...") on a malformed object."""
    seq, code = d["seq"], d["code"]
    if isinstance(seq, bool) or isinstance(code, bool) or not (
            isinstance(seq, int) and isinstance(code, int)):
        raise TypeError(f"expected integer seq and code, got {seq!r}, {code!r}")
    severity, state = d["severity"], d["state"]
    if severity not in Severity.__members__ or state not in AlertState.__members__:
        raise ValueError(f"expected severity from {list(Severity.__members__)} and state "
                         f"from {list(AlertState.__members__)}, got {severity!r}, {state!r}")
    return Alert(seq, number(d["t_s"]), str(d["parameter"]), Severity[severity],
                 AlertState[state], code, number(d["value_rel"]), str(d.get("message", "")))


def params_json(est: Estimate) -> dict[str, dict[str, float | None]]:
    """``{name: {"mean", "std"}}`` of an estimate, in its ``names`` order."""
    return {n: {"mean": finite(m), "std": finite(s)}
            for n, m, s in zip(est.names, est.mean, est.std, strict=True)}


def estimate_json(est: Estimate) -> dict[str, Any]:
    """The JSON form of an estimate."""
    return {"t_s": finite(est.t_s), "ess": finite(est.ess), "updated": bool(est.updated),
            "provisional": bool(est.provisional), "v_sy_mps": finite(est.v_sy_mps),
            "v_say_mps": finite(est.v_say_mps),
            "params": params_json(est),
            "located": None if est.located is None else located_json(est.located),
            "left_out": list(est.left_out), "unresolved": list(est.unresolved)}


def located_json(loc: Located) -> dict[str, Any]:
    """The JSON form of a fault-bank change (values relative to nominal)."""
    return {"t_s": finite(loc.t_s), "parameter": loc.parameter, "rel": finite(loc.rel),
            "rel_lo": finite(loc.rel_lo), "rel_hi": finite(loc.rel_hi),
            "like_lo": finite(loc.like_lo), "like_hi": finite(loc.like_hi)}

