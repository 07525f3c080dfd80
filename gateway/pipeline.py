"""The gateway pipeline, one code path for live service and replay.

    can.Message -> Validator -> Resampler -> Gate -> WorkerLink (RBPF process)
      -> Estimate -> AlertPolicy -> Alert -> sinks (CAN frames, log, state, JSONL)

The driver (``service.Service`` live, ``replay.replay`` from a log) feeds frames with
:meth:`Pipeline.on_frame`, advances time with :meth:`on_time` and collects outputs with
:meth:`poll`. Time is always passed in: receive time in the service, log time in replay.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from gateway.alerts import AlertPolicy
from gateway.codec import Codec
from gateway.config import Config, EstimatorConfig
from gateway.gating import Gate, GateConfig
from gateway.records import Alert, Estimate, GridSample, Sample
from gateway.resample import LATERAL_MESSAGES, Resampler, ResamplerConfig
from gateway.validate import Validator
from gateway.worker import BLOCK_SAMPLES, WorkerLink, WorkerSettings

log = logging.getLogger(__name__)


def build_estimator(cfg: EstimatorConfig, fs_hz: float) -> Any:
    """A fresh RBPF from the configuration (module level, so it pickles to the worker)."""
    from gateway.rbpf import RBPF, RBPFConfig

    return RBPF(RBPFConfig(fs_hz=fs_hz, n_particles=cfg.particles, sensors=cfg.sensors,
                           seed=cfg.seed, ar_paper=cfg.track_roughness,
                           estimate_ar=cfg.estimate_track_roughness,
                           walk_rel_per_sqrt_s=(cfg.drift_per_sqrt_s,) * 3))


def restore_estimator(blob: bytes) -> Any:
    """An RBPF restored from checkpoint bytes."""
    from gateway.rbpf import RBPF

    return RBPF.restore(blob)


def warm_estimator() -> None:
    """Import the estimator and load its compiled kernels (a spare worker's warm-up)."""
    import gateway.rbpf  # noqa: F401


def worker_settings(cfg: Config) -> WorkerSettings:
    """How the worker builds, restores and paces the estimator for this configuration."""
    return WorkerSettings(
        builder=functools.partial(build_estimator, cfg.estimator, cfg.resampler.fs_hz),
        restorer=restore_estimator,
        output_interval_s=1.0 / cfg.estimator.output_rate_hz,
        checkpoint_interval_s=cfg.estimator.checkpoint_interval_s, warmup=warm_estimator)


def resampler_config(cfg: Config) -> ResamplerConfig:
    """The resampler settings from the configuration (0 Hz = filter off)."""
    r = cfg.resampler

    def hz(x: float) -> float | None:
        return x if x > 0 else None

    return ResamplerConfig(fs_hz=r.fs_hz, deadline_s=r.deadline_s,
                           lowpass_hz=(hz(r.lowpass_wheelset_acc_hz), hz(r.lowpass_wheelset_acc_hz),
                                       hz(r.lowpass_bogie_acc_hz), hz(r.lowpass_gyro_hz),
                                       hz(r.lowpass_body_acc_hz)))


def gate_config(cfg: Config) -> GateConfig:
    g = cfg.gating
    return GateConfig(sensors=cfg.estimator.sensors, speed_min_mps=g.speed_min_mps,
                      speed_max_mps=g.speed_max_mps,
                      curve_yaw_rate_max_radps=g.curve_yaw_rate_max_radps)


@dataclass(frozen=True)
class FrontEndStats:
    """What the front end made of the traffic so far: for the replay report, the health
    frame and the console (``docs/resampler.md``, "Front-end statistics").

    Counts are totals since start. ``rejected``: frames refused by validation, by reason
    (incl. ``two_senders``). ``late``: frames dropped because the grid had passed their
    sample, by reason (:data:`gateway.resample.LATE_REASONS`). ``gaps``: per lateral
    message, grid points with its entries MISSING, by reason
    (:data:`gateway.resample.GAP_REASONS`). ``gating``: samples per gating reason
    (``updated`` = measurement updates). ``clock_steps``: receive-clock steps re-based
    (``rx_offset_s`` the correction in force, s); ``resyncs``: node clock models
    restarted; ``retimed_frames``: frames with a disbelieved receive time placed by
    their SampleIdx; ``outlier_frames``: such frames that fitted nowhere and were
    dropped. ``sample_idx_jumps``: per message, SampleIdx breaks the alive counter does
    not explain, by reason (:data:`gateway.e2e.IDX_JUMP_REASONS`). ``two_senders``: the
    messages flagged now (two interleaved counter/SampleIdx sequences on one id; their
    frames are rejected, so they are excluded from the estimator); ``two_sender_events``:
    per message, times that flag was raised. ``horizon``: receive times beyond a horizon,
    by reason (:data:`gateway.resample.HORIZON_REASONS`); ``grid_jump_points``: grid
    points skipped by grid jumps over empty time (never emitted).
    """

    frames: int
    accepted: int
    rejected: dict[str, int]
    grid_points: int
    late: dict[str, int]
    gaps: dict[str, dict[str, int]]
    gating: dict[str, int]
    clock_steps: int
    rx_offset_s: float
    resyncs: int
    retimed_frames: int
    outlier_frames: int
    duplicate_frames: int
    sample_idx_jumps: dict[str, dict[str, int]]
    two_senders: tuple[str, ...]
    two_sender_events: dict[str, int]
    horizon: dict[str, int] = field(default_factory=dict)
    grid_jump_points: int = 0

    @property
    def late_total(self) -> int:
        """Frames dropped as late, all reasons."""
        return sum(self.late.values())

    @property
    def gap_points(self) -> int:
        """Grid points x messages with MISSING entries, all reasons."""
        return sum(sum(g.values()) for g in self.gaps.values())

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON types (the replay report's ``front_end``)."""
        out = dataclasses.asdict(self)
        out["two_senders"] = list(self.two_senders)
        return out


class FrontEnd:
    """Frames to estimator samples: Validator -> Resampler -> Gate, no worker, no clock.

    The part of the pipeline before the estimator, shared by :class:`Pipeline` and the
    offline readers of CAN logs. ``speed_mps`` (offline use only) stands in for the
    vehicle's speed frames: every grid point is gated with that speed. A lateral message
    the validator flags with two senders is excluded from the grid until the flag
    clears.
    """

    def __init__(self, cfg: Config, codec: Codec, *, speed_mps: float | None = None) -> None:
        self.validator = Validator(codec)
        self.resampler = Resampler(resampler_config(cfg))
        self.gate = Gate(gate_config(cfg))
        self.speed_mps = speed_mps
        self._lateral = {codec.message(m).frame_id: self.validator.messages[m]
                         for m in LATERAL_MESSAGES}
        self._by_id = {codec.message(m).frame_id: stats
                       for m, stats in self.validator.messages.items()}
        self._excluded: set[str] = set()

    def on_frame(self, msg: can.Message) -> list[Sample]:
        """One received frame (any id); rejected frames are counted, never raised."""
        frame = self.validator.feed(msg)
        m = self._lateral.get(msg.arbitration_id)
        if m is not None and m.two_senders != (m.name in self._excluded):
            self._excluded.symmetric_difference_update((m.name,))
            self.resampler.set_excluded(m.name, m.two_senders)
            log.warning("%s: %s", m.name, "two senders on one id: excluded from the estimator"
                        if m.two_senders else "single sender again: back in the estimator")
        return [] if frame is None else self._gate(self.resampler.push(frame))

    def two_senders_of(self, frame_id: int) -> tuple[str, bool] | None:
        """``(message, two-senders flag now)`` of a sensor id; None for another id."""
        m = self._by_id.get(frame_id)
        return None if m is None else (m.name, m.two_senders)

    def data_time_s(self) -> float:
        """Data time now: the grid's next point, s (NaN before the grid starts)."""
        return self.resampler.grid_time_s()

    def stats(self) -> FrontEndStats:
        """A snapshot of the front end's counters."""
        v, r = self.validator, self.resampler.stats()
        return FrontEndStats(
            frames=v.stats.frames, accepted=v.stats.accepted, rejected=dict(v.stats.rejected),
            grid_points=r.grid_points, late=r.late, gaps=r.gaps, gating=self.gate.counts,
            clock_steps=r.clock_steps, rx_offset_s=r.rx_offset_s, resyncs=r.resyncs,
            retimed_frames=r.retimed_frames, outlier_frames=r.outlier_frames,
            duplicate_frames=r.duplicate_frames,
            sample_idx_jumps={n: m.sample_idx_jumps for n, m in v.messages.items()},
            two_senders=v.two_senders(),
            two_sender_events={n: m.sender.state.events for n, m in v.messages.items()},
            horizon=r.horizon, grid_jump_points=r.grid_jump_points)

    def on_time(self, now_s: float) -> list[Sample]:
        """Advance time (receive clock): deadlines, message timeouts."""
        out = self._gate(self.resampler.pop_ready(now_s))
        self.validator.check_timeouts(now_s)
        return out

    def finish(self) -> list[Sample]:
        """End of data: every grid point the frames cover."""
        return self._gate(self.resampler.flush())

    def _gate(self, grid: list[GridSample]) -> list[Sample]:
        if self.speed_mps is not None:
            grid = [dataclasses.replace(g, speed_mps=self.speed_mps) for g in grid]
        return [self.gate.apply(g) for g in grid]


@dataclass
class Output:
    """What one poll produced, in order."""

    estimates: list[Estimate] = field(default_factory=list)
    alerts: list[Alert] = field(default_factory=list)


class Pipeline:
    """Everything between the bus and the sinks; owns the worker process."""

    def __init__(self, cfg: Config, codec: Codec, *, policy: AlertPolicy,
                 checkpoint: bytes | None = None, blocking: bool = False,
                 on_checkpoint: Callable[[int, bytes], None] | None = None,
                 on_estimate: Callable[[Estimate], None] | None = None,
                 on_alert: Callable[[Alert], None] | None = None,
                 keep_spare: bool = True) -> None:
        self.cfg = cfg
        self.front = FrontEnd(cfg, codec)
        self.validator, self.resampler, self.gate = (
            self.front.validator, self.front.resampler, self.front.gate)
        self.policy = policy
        self.worker = WorkerLink(worker_settings(cfg),
                                 queue_blocks=max(2, cfg.estimator.queue_samples // BLOCK_SAMPLES),
                                 checkpoint=checkpoint, blocking=blocking,
                                 on_checkpoint=on_checkpoint, keep_spare=keep_spare)
        self._on_estimate = on_estimate
        self._on_alert = on_alert
        self._front_alerts: list[Alert] = []
        """Front-end alert events (two senders) not yet in a poll's Output."""
        self._block: list[Sample] = []
        self.last_estimate: Estimate | None = None
        self.samples_out = 0
        self._rtf_mark: tuple[float, float] | None = None
        self.rtf = math.nan

    # ------------------------------------------------------------------ input
    def on_frame(self, msg: can.Message) -> None:
        """One received frame (any id); rejected frames are counted, never raised. A
        change of the frame's two-sender flag goes to the alert policy (raise or clear),
        and its events to ``on_alert`` like every other alert."""
        self._forward(self.front.on_frame(msg))
        senders = self.front.two_senders_of(msg.arbitration_id)
        if senders is not None and senders[1] != self.policy.two_senders_active(senders[0]):
            t_s = self.front.data_time_s()
            if not math.isfinite(t_s):
                t_s = self.last_estimate.t_s if self.last_estimate is not None else 0.0
            t_s = t_s if math.isfinite(t_s) else 0.0
            for alert in self.policy.two_senders(senders[0], senders[1], t_s):
                self._front_alerts.append(alert)
                if self._on_alert is not None:
                    self._on_alert(alert)

    def on_time(self, now_s: float) -> None:
        """Advance time (receive clock): deadlines, message timeouts."""
        self._forward(self.front.on_time(now_s))

    def finish(self) -> None:
        """End of data: release every grid point the frames cover, then flush."""
        self._forward(self.front.finish())
        self.flush()

    def flush(self) -> None:
        """Send a partly filled block (end of data, or before a checkpoint)."""
        if self._block:
            self.worker.send(self._block)
            self._block = []

    def _forward(self, samples: list[Sample]) -> None:
        for sample in samples:
            self._block.append(sample)
            self.samples_out += 1
            if len(self._block) >= BLOCK_SAMPLES:
                self.flush()

    # ----------------------------------------------------------------- output
    def poll(self, timeout_s: float = 0.0) -> Output:
        """Estimates from the worker and the alerts they raise; restarts a dead worker."""
        return self._handle(self.worker.poll(timeout_s))

    def drain(self) -> Output:
        """Process everything sent so far (replay end)."""
        self.flush()
        return self._handle(self.worker.drain())

    def _handle(self, estimates: list[Estimate]) -> Output:
        out = Output(alerts=self._front_alerts)
        self._front_alerts = []
        for est in estimates:
            self._update_rtf(est.t_s)
            self.last_estimate = est
            out.estimates.append(est)
            if self._on_estimate is not None:
                self._on_estimate(est)
            for alert in self.policy.step(est):
                out.alerts.append(alert)
                if self._on_alert is not None:
                    self._on_alert(alert)
        return out

    def _update_rtf(self, t_data_s: float) -> None:
        now = time.monotonic()
        if self._rtf_mark is None:
            self._rtf_mark = (now, t_data_s)
            return
        wall0, data0 = self._rtf_mark
        if now - wall0 >= 2.0:
            self.rtf = (t_data_s - data0) / (now - wall0)
            self._rtf_mark = (now, t_data_s)

    def close(self) -> Output:
        """Stop the worker (final checkpoint); idempotent."""
        self.flush()
        return self._handle(self.worker.close())
