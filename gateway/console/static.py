"""An in-memory ServiceView built from real records: for tests, demos and the docs transcript.

:meth:`StaticView.example` is a bogie whose lateral damper has faded to a third of
nominal (ALARM) and whose wheelset conicity is high (ADVISORY, acknowledged), with two
days of hourly history. The write side acts on this state the way the service does
(acknowledge, baseline reset, threshold change) and keeps every audit entry in
:attr:`StaticView.audit_log`.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Sequence
from typing import Any

from gateway import __version__
from gateway.config import Config, SerialConfig, as_toml
from gateway.console.view import (
    NOMINAL,
    alert_view,
    estimates_view,
    history_row,
    resolve_parameter,
)
from gateway.errors import InputError
from gateway.records import Alert, AlertState, Estimate, Severity

DEFAULT_THRESHOLDS: dict[str, dict[str, list[float | None]]] = {
    "csy_ns_per_m": {"low": [0.75, 0.55, 0.35], "high": [None, None, None]},
    "csay_ns_per_m": {"low": [0.75, 0.55, 0.35], "high": [None, None, None]},
    "conicity": {"low": [None, None, None], "high": [1.6, 2.0, 2.67]},
}
"""The alert policy's defaults (``docs/alerts.md``), relative to nominal."""


class StaticView:
    """A :class:`~gateway.console.view.ServiceView` over fixed data; thread-safe."""

    def __init__(self, *, estimate: Estimate | None, active: Sequence[Alert] = (),
                 recent: Sequence[Alert] = (),
                 thresholds: dict[str, dict[str, list[float | None]]] | None = None,
                 history: Sequence[dict[str, Any]] = (), sensors: dict[str, Any] | None = None,
                 bus: dict[str, Any] | None = None, config_text: str = "",
                 log: Sequence[str] = (), status: dict[str, Any] | None = None,
                 particles: int = 1000) -> None:
        self._lock = threading.Lock()
        self._estimate = estimate
        self._active = {a.parameter: a for a in active}
        self._raised = {a.parameter: a.seq for a in recent
                        if a.state == AlertState.RAISED and a.parameter in self._active}
        self._recent = list(recent)
        self._thresholds = {k: {s: list(v) for s, v in d.items()}
                            for k, d in (thresholds or DEFAULT_THRESHOLDS).items()}
        self._history = list(history)
        self._sensors = sensors or {}
        self._bus = bus or {}
        self._config_text = config_text
        self._log = list(log)
        self._status = status or {"state": "Running", "version": __version__}
        self._particles = particles
        self._next_seq = 1 + max((a.seq for a in [*active, *recent]), default=0)
        self.audit_log: list[dict[str, Any]] = []

    # -- read side ---------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        with self._lock:
            return {**self._status, "active_alerts": len(self._active)}

    def estimates(self) -> dict[str, Any]:
        with self._lock:
            return estimates_view(self._estimate, thresholds=self._thresholds,
                                  active=list(self._active.values()),
                                  particles=self._particles,
                                  max_std_rel={"csy_ns_per_m": 0.05, "csay_ns_per_m": 0.05,
                                               "conicity": 0.08})

    def alerts(self) -> tuple[list[Alert], list[Alert]]:
        with self._lock:
            return list(self._active.values()), list(self._recent)

    def history(self, hours: float) -> list[dict[str, Any]]:
        with self._lock:
            if not self._history:
                return []
            t_end = max(r["t_s"] or 0.0 for r in self._history)
            return [r for r in self._history if (r["t_s"] or 0.0) >= t_end - hours * 3600.0]

    def sensors(self) -> dict[str, Any]:
        return dict(self._sensors)

    def bus(self) -> dict[str, Any]:
        return dict(self._bus)

    def config_text(self) -> str:
        return self._config_text

    def log_lines(self, n: int) -> list[str]:
        with self._lock:
            return self._log[-n:] if n > 0 else []

    # -- write side --------------------------------------------------------------------
    def _now_s(self) -> float:
        return self._estimate.t_s if self._estimate is not None else 0.0

    def _event(self, old: Alert, state: AlertState, message: str) -> Alert:
        alert = dataclasses.replace(old, seq=self._next_seq, t_s=self._now_s(), state=state,
                                    message=message)
        self._next_seq += 1
        self._recent.append(alert)
        return alert

    def acknowledge(self, alert_key: int | str) -> dict[str, Any]:
        with self._lock:
            if isinstance(alert_key, str):
                param = resolve_parameter(alert_key)
                found = self._active.get(param)
                if found is None:
                    raise InputError(f"expected an active alert for {param}, got none")
            else:
                hits = [a for a in self._active.values()
                        if alert_key in (a.seq, self._raised.get(a.parameter))]
                if not hits:
                    seqs = sorted(self._raised.get(p, a.seq) for p, a in self._active.items())
                    raise InputError(f"expected the seq of an active alert {seqs}, "
                                     f"got {alert_key}")
                found = hits[0]
            if found.state == AlertState.ACKNOWLEDGED:
                raise InputError(f"expected a RAISED alert, got alert {found.seq} "
                                 f"({found.parameter}) already ACKNOWLEDGED")
            ack = self._event(found, AlertState.ACKNOWLEDGED,
                              f"{found.parameter} {found.severity.name} acknowledged")
            self._active[found.parameter] = ack
            return {"alert": alert_view(ack)}

    def baseline_reset(self, component: str) -> dict[str, Any]:
        with self._lock:
            param = resolve_parameter(component)
            events = []
            old = self._active.pop(param, None)
            if old is not None:
                events.append(alert_view(self._event(old, AlertState.CLEARED,
                                                     f"{param} baseline reset")))
            self._history.append(history_row(self._now_s(), event=f"baseline reset {param}"))
            return {"parameter": param, "t_s": self._now_s(), "events": events}

    def set_threshold(self, parameter: str, severity: Severity,
                      value_rel: float) -> dict[str, Any]:
        with self._lock:
            param = resolve_parameter(parameter)
            if not (math.isfinite(value_rel) and value_rel > 0 and value_rel != 1.0):
                raise InputError(f"expected a threshold > 0 and != 1 relative to nominal, "
                                 f"got {value_rel!r}")
            side = "low" if value_rel < 1 else "high"
            levels = list(self._thresholds[param][side])
            levels[int(severity) - 1] = float(value_rel)
            given = [v for v in levels if v is not None]
            ordered = all((a > b) if side == "low" else (a < b)
                          for a, b in zip(given, given[1:], strict=False))
            if not ordered:
                way = "decreasing" if side == "low" else "increasing"
                raise InputError(f"expected {side}-side thresholds strictly {way} with "
                                 f"severity, got {levels}")
            self._thresholds[param][side] = levels
            self._history.append(history_row(
                self._now_s(), event=f"threshold {param} {side} {severity.name} {value_rel:g}"))
            return {"parameter": param, "side": side, "severity": severity.name,
                    "value_rel": value_rel, "thresholds": self._thresholds[param]}

    def audit(self, entry: dict[str, Any]) -> None:
        with self._lock:
            self.audit_log.append(dict(entry))

    # -- the example -------------------------------------------------------------------
    @classmethod
    def example(cls, *, pin_sha256: str = "") -> StaticView:
        """A weak lateral damper (ALARM) and high conicity (ADVISORY, acknowledged)."""
        t_now = 48 * 3600.0
        est = Estimate(t_s=t_now, mean=(12.9e3, 4.02e6, 0.2475), std=(0.41e3, 0.09e6, 0.011),
                       ess=742.0, v_sy_mps=0.021, v_say_mps=0.004)
        csy_low = Severity.ALARM
        recent = [
            Alert(1, 20 * 3600.0, "csy_ns_per_m", Severity.ADVISORY, AlertState.RAISED, 0x11,
                  0.74, "csy_ns_per_m at 0.740 of nominal, low-side ADVISORY threshold 0.75"),
            Alert(2, 31 * 3600.0, "csy_ns_per_m", Severity.WARNING, AlertState.RAISED, 0x12,
                  0.549, "csy_ns_per_m at 0.549 of nominal, low-side WARNING threshold 0.55"),
            Alert(3, 44 * 3600.0, "csy_ns_per_m", csy_low, AlertState.RAISED, 0x13,
                  0.348, "csy_ns_per_m at 0.348 of nominal, low-side ALARM threshold 0.35"),
            Alert(4, 46 * 3600.0, "conicity", Severity.ADVISORY, AlertState.RAISED, 0x27,
                  1.62, "conicity at 1.620 of nominal, high-side ADVISORY threshold 1.6"),
            Alert(5, 46.5 * 3600.0, "conicity", Severity.ADVISORY, AlertState.ACKNOWLEDGED,
                  0x27, 1.63, "conicity ADVISORY acknowledged"),
        ]
        active = [recent[2], recent[4]]
        history = []
        for h in range(49):
            frac = h / 48.0
            mean = (NOMINAL["csy_ns_per_m"] * (1.0 - 0.68 * frac ** 1.5),
                    NOMINAL["csay_ns_per_m"] * (1.0 - 0.02 * frac),
                    NOMINAL["conicity"] * (1.0 + 0.65 * frac ** 2))
            std = (0.012 * mean[0], 0.022 * mean[1], 0.045 * mean[2])
            history.append(history_row(h * 3600.0, Estimate(h * 3600.0, mean, std, 750.0)))
        sensors = {
            "WSN_Lat": _sensor(999.8, 1000.0, 172_790_112, {"crc": 3}, 12, 0, False,
                               {"WSN_Acc1": 0.412, "WSN_Acc2": -0.388}),
            "BGN_Lat": _sensor(1000.0, 1000.0, 172_801_420, {}, 0, 0, False,
                               {"BGN_Acc": 0.231, "BGN_YawRate": 0.0012}),
            "BDN_Lat": _sensor(0.0, 1000.0, 172_744_002, {"counter_repeated": 41}, 96, 2, True,
                               {"BDN_Acc": 0.052}),
            "VEH_Speed": _sensor(10.0, 10.0, 1_728_011, {}, 0, 0, False,
                                 {"VEH_Speed": 42.5, "VEH_Odometer": 7_342_010.0}),
        }
        bus = {"interface": "socketcan", "channel": "can0", "state": "ERROR_ACTIVE",
               "open": True, "bitrate_bps": 1_000_000, "load_pct": 42.3, "error_frames": 7,
               "frames_rx": 518_336_546, "frames_tx": 5_184_012, "reopens": 1, "dropped": 0,
               "last_error": "open failed: [Errno 19] No such device"}
        base = Config()  # the example gateway runs 1000 particles, as its ESS line says
        cfg = dataclasses.replace(base, serial=SerialConfig(
            device="/dev/ttyS1", pin_sha256=pin_sha256 or "0" * 64),
            estimator=dataclasses.replace(base.estimator, particles=1000))
        log = [f"INFO gateway.service: checkpoint {k} written (data time {k * 5.0:.1f} s)"
               for k in range(34_540, 34_560)]
        status = {"state": "Degraded", "uptime_s": 48 * 3600.0 + 312.0, "version": __version__,
                  "data_time_s": t_now, "reason": "BDN_Lat timed out",
                  "worker": {"alive": True, "restarts": 0, "pid": 4242, "rtf": 3.1},
                  "bus": {"state": "ERROR_ACTIVE", "open": True}}
        return cls(estimate=est, active=active, recent=recent, history=history,
                   sensors=sensors, bus=bus, config_text=as_toml(cfg), log=log, status=status,
                   particles=cfg.estimator.particles)


def _sensor(rate_hz: float, expected_hz: float, accepted: int, rejected: dict[str, int],
            lost: int, timeouts: int, timed_out: bool,
            last_values: dict[str, float]) -> dict[str, Any]:
    return {"rate_hz": rate_hz, "expected_hz": expected_hz, "accepted": accepted,
            "rejected": rejected, "lost_frames": lost, "timeouts": timeouts,
            "timed_out": timed_out, "last_values": last_values}

