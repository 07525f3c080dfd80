"""The example ServiceView: in memory, built from real records and the real alert policy.

:meth:`ExampleView.example` is a bogie whose lateral damper has faded to a third of
nominal (ALARM) and whose wheelset conicity is high (ADVISORY, acknowledged), with two
days of hourly history: the transcript in ``docs/console.md``. Alerts, thresholds and
every write go through a real :class:`gateway.alerts.policy.AlertPolicy` (restored from the
example's alert history, exactly as the service restores its own), so the example can
never judge differently from the product. Every audit entry is kept in
:attr:`ExampleView.audit_log`; ``audit_ok = False`` makes audit writes fail, and the
lockout is kept in :attr:`ExampleView.lockout` (a restart is a new view given it).
A test double: it lives in ``tests/``, never in the wheel.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Sequence
from typing import Any

from gateway import __version__
from gateway.alerts.policy import AlertPolicy
from gateway.config import Config, SerialConfig, as_toml
from gateway.console.session import LockoutState
from gateway.console.view import (
    NOMINAL,
    AckResult,
    BaselineResult,
    ThresholdResult,
    estimates_view,
    history_row,
)
from gateway.errors import InputError
from gateway.frontend.stats import FrontEndStats
from gateway.model.vehicle import PARAM_NAMES
from gateway.records import Alert, AlertState, Estimate, Severity
from gateway.service.view import front_end_view, state_dir_view


class ExampleView:
    """A :class:`~gateway.console.view.ServiceView` over fixed data; thread-safe."""

    def __init__(self, *, estimate: Estimate | None, history_alerts: Sequence[Alert] = (),
                 history: Sequence[dict[str, Any]] = (), sensors: dict[str, Any] | None = None,
                 bus: dict[str, Any] | None = None, config_text: str = "",
                 log: Sequence[str] = (), status: dict[str, Any] | None = None,
                 particles: int = 1000, lockout: LockoutState | None = None) -> None:
        self._lock = threading.Lock()
        self._estimate = estimate
        self.policy = AlertPolicy.restore(None, None, history_alerts)
        self._recent = list(history_alerts)
        self._history = list(history)
        self._sensors = sensors or {}
        self._bus = bus or {}
        self._config_text = config_text
        self._log = list(log)
        self._status = status or {"state": "Running", "version": __version__}
        self._particles = particles
        self.audit_log: list[dict[str, Any]] = []
        self.audit_ok = True
        self.lockout = lockout

    # -- read side ---------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        with self._lock:
            return {**self._status, "active_alerts": len(self.policy.active)}

    def estimates(self) -> dict[str, Any]:
        with self._lock:
            params = self.policy.config.params
            return estimates_view(self._estimate,
                                  thresholds={n: {"low": pp.low_rel, "high": pp.high_rel}
                                              for n, pp in params.items()},
                                  active=self.policy.active, particles=self._particles,
                                  max_std_rel={n: pp.max_std_rel for n, pp in params.items()})

    def alerts(self) -> tuple[list[Alert], list[Alert]]:
        with self._lock:
            return list(self.policy.active), list(self._recent)

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

    # -- write side: the real policy, as the service's main loop calls it ----------------
    def _now_s(self) -> float:
        return self._estimate.t_s if self._estimate is not None else math.nan

    def acknowledge(self, alert_key: int | str) -> AckResult:
        with self._lock:
            alert = self.policy.acknowledge(alert_key, self._now_s())
            self._recent.append(alert)
            return AckResult(alert)

    def baseline_reset(self, component: str) -> BaselineResult:
        if component not in PARAM_NAMES:
            raise InputError(f"expected a parameter from {list(PARAM_NAMES)}, got {component!r}")
        with self._lock:
            t = self._now_s()
            cleared = self.policy.reset_baseline(component, t)
            self._recent.extend(cleared)
            self._history.append(history_row(t, event=f"baseline reset {component}"))
            return BaselineResult(component, t, tuple(cleared))

    def set_threshold(self, parameter: str, severity: Severity,
                      value_rel: float) -> ThresholdResult:
        with self._lock:
            self.policy.set_threshold(parameter, severity, value_rel)
            pp = self.policy.config.params[parameter]
            return ThresholdResult(parameter, "low" if value_rel < 1 else "high", severity,
                                   value_rel, pp.low_rel, pp.high_rel)

    def audit(self, entry: dict[str, Any]) -> bool:
        with self._lock:
            if not self.audit_ok:
                return False
            self.audit_log.append(dict(entry))
            return True

    def load_lockout(self) -> LockoutState | None:
        return self.lockout

    def save_lockout(self, state: LockoutState) -> bool:
        self.lockout = state
        return True

    # -- the example -------------------------------------------------------------------
    @classmethod
    def example(cls, *, pin_hash: str = "") -> ExampleView:
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
            device="/dev/ttyS1", pin_hash=pin_hash),
            estimator=dataclasses.replace(base.estimator, particles=1000))
        log = [f"INFO gateway.service.daemon: checkpoint {k} written (data time {k * 5.0:.1f} s)"
               for k in range(34_540, 34_560)]
        status = {"state": "Degraded", "uptime_s": 48 * 3600.0 + 312.0, "version": __version__,
                  "data_time_s": t_now, "reason": "BDN_Lat timed out",
                  "worker": {"alive": True, "restarts": 0, "pid": 4242, "rtf": 3.1},
                  "bus": {"state": "ERROR_ACTIVE", "open": True},
                  "front_end": front_end_view(_front_end()),
                  "state_dir": state_dir_view(0, ())}
        return cls(estimate=est, history_alerts=recent, history=history,
                   sensors=sensors, bus=bus, config_text=as_toml(cfg), log=log, status=status,
                   particles=cfg.estimator.particles)


def _sensor(rate_hz: float, expected_hz: float, accepted: int, rejected: dict[str, int],
            lost: int, timeouts: int, timed_out: bool,
            last_values: dict[str, float]) -> dict[str, Any]:
    return {"rate_hz": rate_hz, "expected_hz": expected_hz, "accepted": accepted,
            "rejected": rejected, "lost_frames": lost, "timeouts": timeouts,
            "timed_out": timed_out, "last_values": last_values}


def _front_end() -> FrontEndStats:
    """The example's front end: BDN silent for 96 frames and timed out twice, one receive
    clock step (NTP), one BGN node restart, a second BGN sender seen once (gone)."""
    none = {"lost": 0, "late": 0, "outlier": 0, "not_seen": 0, "excluded": 0}
    return FrontEndStats(
        frames=518_336_546, accepted=518_336_502, rejected={"crc": 3, "counter_repeated": 41},
        grid_points=172_800_000, late={"deadline": 14, "not_waited": 0, "clock": 2},
        gaps={"WSN_Lat": {**none, "lost": 12}, "BGN_Lat": {**none, "excluded": 1200},
              "BDN_Lat": {**none, "lost": 96, "late": 14}},
        gating={"updated": 171_000_000}, clock_steps=1, rx_offset_s=-0.5, resyncs=1,
        retimed_frames=10, outlier_frames=0, duplicate_frames=0,
        sample_idx_jumps={"BGN_Lat": {"idx_jump": 1}}, two_senders=(),
        two_sender_events={"WSN_Lat": 0, "BGN_Lat": 1, "BDN_Lat": 0, "VEH_Speed": 0},
        horizon={"time_range": 0, "far_time": 0, "far_step": 0, "grid_jump": 0})
