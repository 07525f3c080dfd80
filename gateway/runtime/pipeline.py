"""The gateway pipeline, one code path for live service and replay.

    can.Message -> Validator -> Resampler -> Gate -> WorkerLink (RBPF process)
      -> Estimate -> AlertPolicy -> Alert -> sinks (CAN frames, log, state, JSONL)

The driver (``service.Service`` live, ``replay.replay`` from a log) feeds frames with
:meth:`Pipeline.on_frame`, advances time with :meth:`on_time` and collects outputs with
:meth:`poll`. Time is always passed in: receive time in the service, log time in replay.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields, is_dataclass
from typing import TYPE_CHECKING, Any

import can

from gateway.alerts.policy import AlertPolicy
from gateway.can.codec import Codec
from gateway.config import Config, EstimatorConfig
from gateway.estimator.threads import kernel_threads
from gateway.frontend.chain import FrontEnd
from gateway.records import Alert, Estimate, Estimator, NoiseCheck, Sample
from gateway.runtime.worker import BLOCK_SAMPLES, WorkerLink, WorkerSettings

if TYPE_CHECKING:
    from gateway.estimator.rbpf_config import RBPFConfig

log = logging.getLogger(__name__)


def estimator_config(cfg: EstimatorConfig, fs_hz: float) -> RBPFConfig:
    """The filter's settings this configuration gives (the one mapping from the service's
    ``[estimator]`` table to the RBPF's: the builder and the checkpoint test use it)."""
    from gateway.estimator.rbpf_config import (
        RBPFConfig,
        floor_for_delta,
        kernel_delta_for,
        prior_lo_for,
    )

    delta = kernel_delta_for(cfg.kernel_delta, cfg.particles)
    return RBPFConfig(fs_hz=fs_hz, n_particles=cfg.particles, sensors=cfg.sensors,
                      seed=cfg.seed, ar_paper=cfg.track_roughness,
                      estimate_ar=cfg.estimate_track_roughness,
                      walk_rel_per_sqrt_s=(cfg.drift_per_sqrt_s,) * 3, mode=cfg.mode,
                      start_ramp_s=cfg.start_ramp_s, start_ramp_m=cfg.start_ramp_m,
                      delta=delta, floor_rel=floor_for_delta(delta),
                      prior_lo=prior_lo_for(cfg.particles))


def build_estimator(cfg: EstimatorConfig, fs_hz: float) -> Estimator:
    """A fresh RBPF from the configuration (module level, so it pickles to the worker);
    with ``sensor_noise = "measured"`` it starts with the noise test."""
    from gateway.estimator.noisestart import NoiseCheckedStart
    from gateway.estimator.rbpf import RBPF

    rbpf = estimator_config(cfg, fs_hz)
    return NoiseCheckedStart(rbpf) if cfg.sensor_noise == "measured" else RBPF(rbpf)


def restore_estimator(blob: bytes) -> Estimator:
    """The estimator restored from checkpoint bytes (a filter, or one in its noise test)."""
    from gateway.estimator.noisestart import NoiseCheckedStart

    return NoiseCheckedStart.restore(blob)


def checkpoint_mismatch(cfg: EstimatorConfig, fs_hz: float, blob: bytes) -> str | None:
    """Why the checkpoint ``blob`` is not of the estimator this configuration builds, in
    one line (each setting that differs: the checkpoint's value, then the
    configuration's), or None where it is, so that resuming from it is right.

    A checkpoint carries the settings its filter was built with, and a restore keeps
    them: without this test a restart after a change of ``[estimator]`` (or of a default,
    by an upgrade) would go on with the old filter for good, or, with another sensor set,
    fail on every sample (a worker that dies at once, three times: the service stops,
    and systemd starts it on the same checkpoint again). Every setting counts but the
    sensor-noise variances a filter measured itself (``sensor_noise = "measured"``);
    under ``"model"`` a filter on measured variances, or one still in its test, is
    another filter (one whose test found the model's variances is the model's filter),
    and under ``"measured"`` so is one whose variances were never tested (a filter
    made under ``"model"``, ``RBPFConfig.noise_tested``).
    A checkpoint that cannot be read says so.

    The parent process imports the estimator's configuration module for this (about
    50 MB, only when a checkpoint exists)."""
    from gateway.errors import EstimatorError
    from gateway.estimator.noisestart import NoiseCheckedStart

    try:
        then, testing = NoiseCheckedStart.config_of(blob)
    except EstimatorError as err:
        return f"unreadable: {err}"
    measured = cfg.sensor_noise == "measured"
    differ = _differences(then, estimator_config(cfg, fs_hz),
                          skip={"noise_var", "noise_tested"} if measured else {"noise_tested"})
    if not measured and testing:
        differ.append("sensor_noise 'measured' (in its test) -> 'model'")
    if measured and not testing and not then.noise_tested:
        differ.append("sensor_noise 'model' -> 'measured' (its variances never tested)")
    return None if not differ else "made with other settings: " + "; ".join(differ)


def _differences(then: Any, now: Any, skip: set[str], prefix: str = "") -> list[str]:
    """``"name then -> now"`` for each field of two dataclasses of one type that differs,
    nested ones field by field (``faults.replay_s 0.0 -> 2.0``), ``skip`` left out."""
    out = []
    for f in fields(now):
        a, b = getattr(then, f.name), getattr(now, f.name)
        if f.name in skip or a == b:
            continue
        if is_dataclass(a) and type(a) is type(b):
            out += _differences(a, b, set(), f"{prefix}{f.name}.")
        else:
            out.append(f"{prefix}{f.name} {a!r} -> {b!r}")
    return out


def warm_estimator(numba_threads: int) -> None:
    """A worker process's start: numba's global settings (once, here), then import the
    estimator and load its compiled kernels and functions (so a spare worker waits warm
    and its first samples wait for no compile; on a cold cache this compiles them:
    minutes, see :mod:`gateway.estimator.precompile`)."""
    from gateway.estimator.threads import configure

    configure(numba_threads)
    import gateway.estimator.rbpf  # noqa: F401  (defines the kernels)
    from gateway.estimator.precompile import load_all

    load_all()


def worker_settings(cfg: Config) -> WorkerSettings:
    """How the worker builds, restores and paces the estimator for this configuration."""
    return WorkerSettings(
        builder=functools.partial(build_estimator, cfg.estimator, cfg.resampler.fs_hz),
        restorer=restore_estimator,
        output_interval_s=1.0 / cfg.estimator.output_rate_hz,
        checkpoint_interval_s=cfg.estimator.checkpoint_interval_s,
        grid_dt_s=1.0 / cfg.resampler.fs_hz,
        warmup=functools.partial(warm_estimator, kernel_threads(cfg.estimator.particles)))


@dataclass(frozen=True)
class SensorStatus:
    """One sensor message's counters and last values (the console's ``sensors``)."""

    name: str
    rate_hz: float
    """Mean accepted-frame rate since the first frame."""
    expected_hz: float
    accepted: int
    rejected: dict[str, int]
    """Rejected frames by reason (a copy)."""
    lost_frames: int
    timeouts: int
    timed_out: bool
    last_values: dict[str, float]
    """Last accepted value of each signal, SI units (a copy)."""


@dataclass(frozen=True)
class PipelineStats:
    """A snapshot of the pipeline's counters for health, STATUS= and the console, so the
    service reads one record instead of reaching into the worker and the validator."""

    worker_alive: bool
    worker_ready: bool
    """The worker has built (or restored) its estimator."""
    worker_restarts: int
    worker_pid: int | None
    last_seq_done: int
    """Last grid sample the worker has stepped (-1: none)."""
    samples_out: int
    """Grid samples the front end has released so far."""
    samples_dropped: int
    """Grid samples dropped at the full worker queue (live)."""
    drop_runs: int
    """Contiguous runs of dropped samples: each one gap, one filter restart."""
    priority_error: str | None
    """None until a worker reported; "" when its priority was lowered; else why not."""
    frames_rejected: int
    rtf: float
    """Estimator real-time factor, data s per wall s (NaN until measured)."""
    sensors: tuple[SensorStatus, ...]
    noise_check: NoiseCheck | None = None
    """The estimator's sensor-noise test, once the worker reported it."""


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

    def baseline_reset(self, index: int) -> None:
        """Parameter ``index`` (``PARAM_NAMES`` order) re-learns from its prior, after
        every sample made so far (a partly filled block is sent first)."""
        self.flush()
        self.worker.baseline_reset(index)

    def stats(self) -> PipelineStats:
        """The counters now, as one frozen record."""
        w = self.worker.stats
        return PipelineStats(
            worker_alive=w.alive, worker_ready=w.ready, worker_restarts=w.restarts,
            worker_pid=self.worker.pid, last_seq_done=w.last_seq_done,
            samples_out=self.samples_out, samples_dropped=w.samples_dropped,
            drop_runs=w.drop_runs,
            priority_error=w.priority_error,
            frames_rejected=self.validator.stats.rejected_total, rtf=self.rtf,
            sensors=tuple(SensorStatus(name, m.rate_hz(), 1.0 / m.cycle_time_s, m.accepted,
                                       dict(m.rejected), m.lost_net, m.timeouts, m.timed_out,
                                       dict(m.last_values))
                          for name, m in self.validator.messages.items()),
            noise_check=w.noise_check)

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
