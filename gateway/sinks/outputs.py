"""Output sinks: our CAN frames (estimates, alerts, health, E2E-protected) and the log.

Each sink is a :class:`gateway.records.Sink`: ``emit(record)`` takes an estimate or an
alert event (dispatched on its type to ``emit_estimate``/``emit_alert``), ``close()``
releases it. The CAN sink also sends the health frames (``emit_health``). It encodes
with the codec, keeps one alive counter per message and hands frames to a ``send``
callable (the bus source in the service, a list in tests and replay). It sends at most
``estimate_rate_hz`` estimate frame sets per second of *data* time (``Estimate.t_s``):
the worker makes estimates at ``[estimator] output_rate_hz``, the sink only drops.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import assert_never

import can

from gateway.can.codec import SENSOR_NODE, Codec
from gateway.can.e2e import next_counter
from gateway.errors import InputError
from gateway.model.vehicle import PARAM_NAMES, SENSORS_5
from gateway.records import Alert, AlertState, Estimate, Severity

log = logging.getLogger(__name__)

EST_MESSAGES = {"csy_ns_per_m": "GW_EstCsy", "csay_ns_per_m": "GW_EstCsay",
                "conicity": "GW_EstConicity"}
PARAM_CODE = {name: i for i, name in enumerate(PARAM_NAMES)}
CONVERGED_REL_STD = 0.05
"""sigma/theta below which an estimate frame says Valid rather than Converging."""
LEFT_OUT_NODES = tuple(dict.fromkeys(SENSOR_NODE[s] for s in SENSORS_5))
"""The nodes that send the estimator's sensors (WSN, BGN, BDN), each with a
GW_HealthFlags_<Node>LeftOut bit."""
RATE_SLACK = 1e-3
"""Fraction of the estimate period by which an estimate may come early and still be
sent: data times are float grid points, so a due time may land a hair past the
estimate of a worker that runs at the same rate."""


@dataclass(frozen=True)
class HealthFlags:
    """Faults the service runs on with, and their counters: the 1 Hz GW_HealthFlags frame."""

    state_quarantined: bool = False
    """A state file could not be used at start and was set aside."""
    persistence_failing: bool = False
    """A state-directory write has failed since start."""
    priority_not_applied: bool = False
    """The estimator worker could not lower its CPU priority."""
    front_end_resyncing: bool = False
    """The front end re-synchronised a node clock or re-based a receive-clock step since
    the previous report."""
    two_senders: bool = False
    """Two interleaved senders seen on one sensor id."""
    left_out_nodes: tuple[str, ...] = ()
    """Nodes (of WSN, BGN, BDN) a sensor of which the latest estimate left out
    (``Estimate.left_out``: no values from it)."""
    late_frames: int = 0
    gap_samples: int = 0
    write_failures: int = 0
    resyncs: int = 0
    """Node-clock resyncs plus receive-clock steps re-based (``FrontEndStats.resyncs +
    clock_steps``)."""

    def names(self) -> list[str]:
        """The raised flags, short names for the STATUS line and the log."""
        raised = (("state-quarantined", self.state_quarantined),
                  ("persistence-failing", self.persistence_failing),
                  ("priority-not-applied", self.priority_not_applied),
                  ("front-end-resyncing", self.front_end_resyncing),
                  ("two-senders", self.two_senders))
        return ([name for name, on in raised if on]
                + [f"left-out-{node}" for node in self.left_out_nodes])


@dataclass(frozen=True)
class Health:
    """What the 1 Hz health frames report."""

    gw_state: str            # Starting | Running | Degraded | Fault
    bus_state: int           # 0 active, 1 passive, 2 bus-off
    active_alerts: int
    frames_rx: int
    frames_rejected: int
    frames_dropped: int
    rtf: float              # estimator real-time factor (data s per wall s)
    flags: HealthFlags = HealthFlags()


def estimate_status(est: Estimate, index: int) -> str:
    """The estimate frame's status word for parameter ``index``."""
    if not est.updated:
        return "PredictOnly"
    if est.names[index] in est.unresolved:
        return "Unresolved"
    mean, std = est.mean[index], est.std[index]
    if not (math.isfinite(mean) and math.isfinite(std)) or mean <= 0:
        return "Init"
    return "Valid" if std / mean < CONVERGED_REL_STD and not est.provisional else "Converging"


class CanSink:
    """Encodes and sends the gateway's frames; counts what it could not send."""

    def __init__(self, codec: Codec, send: Callable[[can.Message], bool],
                 particles: int, *, estimate_rate_hz: float | None = None) -> None:
        """``estimate_rate_hz``: at most this many estimate frame sets per second of data
        time (``[output] estimate_rate_hz``); None sends every estimate."""
        self._codec = codec
        self._send = send
        self._particles = particles
        self._counters: dict[str, int] = {}
        self._estimate_period_s = 0.0
        self._anchor_t_s = math.nan   # data time of the grid of due times: anchor + k * period
        self._k = 0
        self._last_estimate_t_s = math.nan
        self.sent = 0
        self.failed = 0
        self.estimates_skipped = 0
        """Estimates not sent because the next one due (on the data-time grid of period
        1 / estimate_rate_hz) had not come yet."""
        self.set_estimate_rate(estimate_rate_hz)

    def set_estimate_rate(self, estimate_rate_hz: float | None) -> None:
        """Change the estimate rate limit (a configuration reload); None: no limit. The
        next set is due 1 / estimate_rate_hz of data time after the last one sent."""
        if estimate_rate_hz is not None and not (math.isfinite(estimate_rate_hz)
                                                 and estimate_rate_hz > 0):
            raise InputError(f"expected a positive finite estimate rate in Hz, got "
                             f"{estimate_rate_hz!r}")
        self._estimate_period_s = 0.0 if estimate_rate_hz is None else 1.0 / estimate_rate_hz
        self._anchor_t_s, self._k = self._last_estimate_t_s, 1

    def _estimate_due(self, t_s: float) -> bool:
        """Whether an estimate at data time ``t_s`` is sent (and if so, count it).

        Sets are due on a grid ``anchor + k / estimate_rate_hz`` (a product, so no sum
        drifts over hours), so 3 Hz out of a 10 Hz stream is 3 sets per data second, not
        every 4th. A gap re-anchors the grid at the next estimate (no burst after it);
        data time running backwards (a new run) too. A non-finite time is always sent.
        """
        if not math.isfinite(t_s):
            return True
        period = self._estimate_period_s
        if not t_s >= self._last_estimate_t_s:          # the first, or time went back
            self._anchor_t_s, self._k = t_s, 0
        if t_s < self._anchor_t_s + self._k * period - period * RATE_SLACK:
            return False
        self._k += 1
        if self._anchor_t_s + self._k * period <= t_s:   # fell behind the grid: a gap
            self._anchor_t_s, self._k = t_s, 1
        self._last_estimate_t_s = t_s
        return True

    def _out(self, name: str, signals: dict[str, float | str | None]) -> None:
        counter = self._counters.get(name, 0)
        self._counters[name] = next_counter(counter)
        msg = self._codec.encode_message(name, signals, counter, saturate=True)
        if self._send(msg):
            self.sent += 1
        else:
            self.failed += 1

    def emit(self, record: Estimate | Alert) -> None:
        """An estimate's or an alert event's frames (:class:`gateway.records.Sink`)."""
        match record:
            case Estimate():
                self.emit_estimate(record)
            case Alert():
                self.emit_alert(record)
            case _:
                assert_never(record)

    def emit_estimate(self, est: Estimate) -> None:
        """One frame per parameter: mean, std, status and ESS %; nothing when ``est.t_s``
        comes before the next set is due (``_estimate_due``)."""
        if not self._estimate_due(est.t_s):
            self.estimates_skipped += 1
            return
        ess_pct = min(100.0, 100.0 * est.ess / self._particles) if self._particles else None
        for i, name in enumerate(PARAM_NAMES):
            msg = EST_MESSAGES[name]
            mean, std = est.mean[i], est.std[i]
            self._out(msg, {f"{msg}_Status": estimate_status(est, i),
                            f"{msg}_Mean": mean if math.isfinite(mean) else None,
                            f"{msg}_Std": std if math.isfinite(std) else None,
                            f"{msg}_EssPct": ess_pct})

    def emit_alert(self, alert: Alert) -> None:
        """One GW_Alert frame per alert event."""
        self._out("GW_Alert", {
            "GW_Alert_Seq": alert.seq, "GW_Alert_Code": min(alert.code, 254),
            "GW_Alert_Severity": int(alert.severity),
            "GW_Alert_Param": PARAM_CODE.get(alert.parameter),   # else NotAvailable
            "GW_Alert_State": int(alert.state),
            "GW_Alert_ValueRel": alert.value_rel if math.isfinite(alert.value_rel) else None})

    def emit_health(self, h: Health) -> None:
        """The 1 Hz GW_Health and GW_HealthFlags frames; counters wrap at their width."""
        self._out("GW_Health", {
            "GW_Health_GwState": h.gw_state, "GW_Health_BusState": h.bus_state,
            "GW_Health_ActiveAlerts": min(h.active_alerts, 6),
            "GW_Health_FramesRx": h.frames_rx, "GW_Health_FramesRejected": h.frames_rejected,
            "GW_Health_FramesDropped": h.frames_dropped,
            "GW_Health_RtFactor": h.rtf if math.isfinite(h.rtf) else None})
        f = h.flags
        self._out("GW_HealthFlags", {
            "GW_HealthFlags_StateQuarantined": int(f.state_quarantined),
            "GW_HealthFlags_PersistFailing": int(f.persistence_failing),
            "GW_HealthFlags_PriorityNotApplied": int(f.priority_not_applied),
            "GW_HealthFlags_FrontEndResync": int(f.front_end_resyncing),
            "GW_HealthFlags_TwoSenders": int(f.two_senders),
            **{f"GW_HealthFlags_{node.capitalize()}LeftOut": int(node in f.left_out_nodes)
               for node in LEFT_OUT_NODES},
            "GW_HealthFlags_LateFrames": f.late_frames, "GW_HealthFlags_GapSamples": f.gap_samples,
            "GW_HealthFlags_WriteFailures": f.write_failures, "GW_HealthFlags_Resyncs": f.resyncs})

    def close(self) -> None:
        """Nothing to release; idempotent."""


class LogSink:
    """Alerts to the log (journald picks up stderr under systemd); estimates are not
    logged (the CAN frames and the state directory carry them)."""

    def emit(self, record: Estimate | Alert) -> None:
        """Log an alert event (:class:`gateway.records.Sink`); ignore an estimate."""
        match record:
            case Alert():
                self.emit_alert(record)
            case Estimate():
                pass
            case _:
                assert_never(record)

    def emit_alert(self, alert: Alert) -> None:
        level = {Severity.ADVISORY: logging.INFO, Severity.WARNING: logging.WARNING,
                 Severity.ALARM: logging.ERROR}[alert.severity]
        if alert.state is not AlertState.RAISED:
            level = logging.INFO
        log.log(level, "alert #%d %s %s %s at t=%.1f s (%.0f %% of nominal) %s", alert.seq,
                alert.state.name.lower(), alert.severity.name.lower(), alert.parameter,
                alert.t_s, 100 * alert.value_rel, alert.message)

    def close(self) -> None:
        """Nothing to release; idempotent."""
