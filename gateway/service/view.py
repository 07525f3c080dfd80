"""What the running service shows the maintenance console (gateway.console.view.ServiceView).

Reads return snapshots that the main loop publishes (:meth:`publish`) under a lock;
writes are queued to the main loop, which alone touches the alert policy and the
worker, and the console thread waits for their result. Thread-safe by construction.
"""

from __future__ import annotations

import collections
import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast

from gateway import __version__
from gateway.config import as_toml
from gateway.console.session import LockoutState
from gateway.console.view import (
    AckResult,
    BaselineResult,
    ThresholdResult,
    estimates_view,
    history_row,
)
from gateway.errors import InputError, StateError
from gateway.model.vehicle import PARAM_NAMES
from gateway.records import Alert, Severity

if TYPE_CHECKING:
    from gateway.alerts.policy import AlertPolicy
    from gateway.can.source import BusSource
    from gateway.config import Config
    from gateway.frontend.stats import FrontEndStats
    from gateway.runtime.pipeline import Pipeline
    from gateway.sinks.outputs import Health
    from gateway.sinks.store import StateStore


class Service(Protocol):
    """The narrow part of the daemon (:class:`gateway.service.daemon.Service`) this view
    reads and drives; a Protocol, so the view does not import the daemon (no cycle)."""

    cfg: Config
    store: StateStore
    policy: AlertPolicy
    pipeline: Pipeline | None
    source: BusSource
    recent_alerts: collections.deque[Alert]

    @property
    def uptime_s(self) -> float: ...

    def health(self) -> Health: ...

    def data_time_s(self) -> float: ...

    def bus_load_pct(self) -> float: ...

    def on_alert(self, alert: Alert) -> None: ...

log = logging.getLogger(__name__)
WRITE_TIMEOUT_S = 5.0
T = TypeVar("T")


def front_end_view(fe: FrontEndStats | None) -> dict[str, Any]:
    """The ``status`` reply's ``front_end``: late frames and gap points by reason (gaps
    summed over the lateral messages), resyncs, clock steps, receive times beyond a
    horizon by reason, the messages with two senders now (plus raise counts), and each
    node's timing (``nodes``: :meth:`gateway.frontend.stats.NodeTiming.as_dict` per
    message)."""
    if fe is None:
        return {"late": {}, "gaps": {}, "resyncs": 0, "clock_steps": 0, "horizon": {},
                "two_senders": [], "two_sender_events": 0, "nodes": {}}
    gaps: dict[str, int] = {}
    for by_reason in fe.gaps.values():
        for why, n in by_reason.items():
            gaps[why] = gaps.get(why, 0) + n
    return {"late": dict(fe.late), "gaps": gaps, "resyncs": fe.resyncs,
            "clock_steps": fe.clock_steps, "horizon": dict(fe.horizon),
            "two_senders": list(fe.two_senders),
            "two_sender_events": sum(fe.two_sender_events.values()),
            "nodes": {m: t.as_dict() for m, t in fe.nodes.items()}}


def state_dir_view(write_failures: int, set_aside: Sequence[str]) -> dict[str, Any]:
    """The ``status`` reply's ``state_dir``: failed state writes since start and the state
    files set aside (quarantined) at start (:class:`gateway.sinks.store.StateStore`)."""
    return {"write_failures": int(write_failures), "set_aside": list(set_aside)}


class LogTail(logging.Handler):
    """Keeps the last lines of the log for the console's ``log`` command."""

    def __init__(self, size: int = 500) -> None:
        super().__init__(level=logging.INFO)
        self.lines: collections.deque[str] = collections.deque(maxlen=size)
        self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.lines.append(self.format(record))
        except Exception:  # noqa: BLE001 - a log handler must never raise
            self.handleError(record)


class ServiceViewImpl:
    """The service's side of the console seam."""

    def __init__(self, service: Service) -> None:
        self._service = service
        self._lock = threading.Lock()
        self._snap: dict[str, Any] = {}
        self._requests: queue.Queue[tuple[Callable[[], Any], queue.Queue[Any]]] = \
            queue.Queue()
        self.log_tail = LogTail()
        """Filled once the service installs it as a log handler (at its start)."""

    # ------------------------------------------------------ main-loop side
    def publish(self) -> None:
        """Snapshot what the console reads (called by the main loop, twice a second)."""
        s = self._service
        p = s.pipeline
        pol = s.policy.config.params
        est = p.last_estimate if p else None
        src = s.source.stats
        ps = p.stats() if p is not None else None
        snap = {
            "status": {"state": s.health().gw_state, "uptime_s": round(s.uptime_s, 1),
                       "version": __version__, "data_time_s": est.t_s if est else None,
                       "worker": {"alive": ps.worker_alive if ps else False,
                                  "restarts": ps.worker_restarts if ps else 0,
                                  "pid": ps.worker_pid if ps else None,
                                  "rtf": ps.rtf if ps else None,
                                  "sensor_noise": (ps.noise_check.summary()
                                                   if ps and ps.noise_check else None)},
                       "bus": {"state": src.bus_state.name, "open": src.bus_open},
                       "active_alerts": len(s.policy.active),
                       "front_end": front_end_view(p.front.stats() if p else None),
                       "state_dir": state_dir_view(s.store.write_failures,
                                                   s.store.quarantined)},
            "estimates": estimates_view(
                est, thresholds={n: {"low": pp.low_rel, "high": pp.high_rel}
                                 for n, pp in pol.items()},
                active=s.policy.active, particles=s.cfg.estimator.particles,
                max_std_rel={n: pp.max_std_rel for n, pp in pol.items()}),
            "sensors": {} if ps is None else {
                m.name: {"rate_hz": round(m.rate_hz, 1), "expected_hz": m.expected_hz,
                         "accepted": m.accepted, "rejected": m.rejected,
                         "lost_frames": m.lost_frames, "timeouts": m.timeouts,
                         "timed_out": m.timed_out, "last_values": m.last_values}
                for m in ps.sensors},
            "bus": {"interface": s.cfg.bus.interface, "channel": s.cfg.bus.channel,
                    "state": src.bus_state.name, "open": src.bus_open,
                    "load_pct": s.bus_load_pct(), "error_frames": src.error_frames,
                    "frames_rx": src.frames_rx, "frames_tx": src.frames_tx,
                    "reopens": src.reopens,
                    "dropped": src.dropped_queue_full + src.dropped_kernel,
                    "last_error": src.last_error},
            "alerts": (tuple(s.policy.active), tuple(s.recent_alerts)),
        }
        with self._lock:
            self._snap = snap

    def run_pending(self) -> None:
        """Execute queued write requests (main loop only)."""
        while True:
            try:
                action, reply = self._requests.get_nowait()
            except queue.Empty:
                return
            try:
                result = action()
            except Exception as err:  # noqa: BLE001 - handed back to the console thread
                reply.put(("err", err))
                continue
            self.publish()      # the console's next read shows what it just wrote
            reply.put(("ok", result))

    def _call(self, action: Callable[[], T]) -> T:
        reply: queue.Queue[Any] = queue.Queue(maxsize=1)
        self._requests.put((action, reply))
        try:
            kind, value = reply.get(timeout=WRITE_TIMEOUT_S)
        except queue.Empty:
            raise InputError("expected the service to answer within 5 s, got no answer") \
                from None
        if kind == "err":
            raise value
        return cast(T, value)

    def _get(self, key: str, default: Any) -> Any:
        with self._lock:
            return self._snap.get(key, default)

    # ------------------------------------------------------ console side
    def status(self) -> dict[str, Any]:
        return dict(self._get("status", {"state": "Starting"}))

    def estimates(self) -> dict[str, Any]:
        return dict(self._get("estimates", {"parameters": {}}))

    def alerts(self) -> tuple[Sequence[Alert], Sequence[Alert]]:
        active, recent = self._get("alerts", ((), ()))
        return active, recent

    def history(self, hours: float) -> list[dict[str, Any]]:
        store = self._service.store
        since = time.time() - hours * 3600.0
        rows: list[tuple[float, dict[str, Any]]] = []
        for e in store.read_estimates(since_wall_s=since):
            iso = datetime.fromtimestamp(e.wall_time_s, UTC).isoformat(timespec="seconds")
            rows.append((e.wall_time_s, {
                "t_s": e.t_s, "time": iso, "event": None,
                "estimates": {n: {"mean": m, "std": s}
                              for n, m, s in zip(e.names, e.mean, e.std, strict=True)}}))
        for b in store.read_baselines():
            if b.wall_time_s >= since:
                iso = datetime.fromtimestamp(b.wall_time_s, UTC).isoformat(timespec="seconds")
                rows.append((b.wall_time_s, history_row(b.t_s, None, time=iso,
                                                        event=f"baseline reset {b.parameter}")))
        return [r for _, r in sorted(rows, key=lambda x: x[0])]

    def sensors(self) -> dict[str, Any]:
        return dict(self._get("sensors", {}))

    def bus(self) -> dict[str, Any]:
        return dict(self._get("bus", {}))

    def config_text(self) -> str:
        return as_toml(self._service.cfg)

    def log_lines(self, n: int) -> list[str]:
        return list(self.log_tail.lines)[-max(0, n):]

    def acknowledge(self, alert_key: int | str) -> AckResult:
        def act() -> AckResult:
            s = self._service
            alert = s.policy.acknowledge(alert_key, s.data_time_s())
            s.on_alert(alert)
            return AckResult(alert)
        return self._call(act)

    def baseline_reset(self, component: str) -> BaselineResult:
        if component not in PARAM_NAMES:
            raise InputError(f"expected a parameter from {list(PARAM_NAMES)}, got {component!r}")

        def act() -> BaselineResult:
            s = self._service
            t = s.data_time_s()
            cleared = s.policy.reset_baseline(component, t)
            for alert in cleared:
                s.on_alert(alert)
            if s.pipeline is not None:
                s.pipeline.baseline_reset(PARAM_NAMES.index(component))
            s.store.append_baseline(component, t, note="baseline reset from the console")
            s.store.save_policy(s.policy.snapshot())
            return BaselineResult(component, t, tuple(cleared))
        return self._call(act)

    def set_threshold(self, parameter: str, severity: Severity,
                      value_rel: float) -> ThresholdResult:
        def act() -> ThresholdResult:
            s = self._service
            s.policy.set_threshold(parameter, severity, value_rel)
            s.store.save_policy(s.policy.snapshot())
            pp = s.policy.config.params[parameter]
            return ThresholdResult(parameter, "low" if value_rel < 1 else "high", severity,
                                   value_rel, pp.low_rel, pp.high_rel)
        return self._call(act)

    def audit(self, entry: dict[str, Any]) -> bool:
        """Persist one audit entry (fsynced); False if it could not be written."""
        detail = json.dumps({k: v for k, v in entry.items() if k not in ("command",)},
                            default=str, sort_keys=True)
        return self._service.store.append_audit(str(entry.get("command", "")),
                                                entry.get("result") == "ok", detail)

    def load_lockout(self) -> LockoutState | None:
        """The persisted PIN lockout; an unusable file locks (fail closed)."""
        try:
            saved = self._service.store.load_console_lockout()
            if saved is None:
                return None
            return LockoutState(int(saved["failures"]), float(saved["locked_until_unix_s"]))
        except (StateError, KeyError, TypeError, ValueError, OverflowError) as err:
            log.error("console: PIN lockout state unusable (%s); login locked", err)
            return LockoutState(0, math.inf)

    def save_lockout(self, state: LockoutState) -> bool:
        return self._service.store.save_console_lockout(
            {"failures": state.failures, "locked_until_unix_s": state.locked_until_unix_s})
