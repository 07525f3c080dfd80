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
from dataclasses import dataclass, field
from typing import Any

import can

from gateway.alerts.policy import AlertPolicy
from gateway.can.codec import Codec
from gateway.config import Config, EstimatorConfig
from gateway.estimator.threads import kernel_threads
from gateway.frontend.chain import FrontEnd
from gateway.records import Alert, Estimate, Sample
from gateway.runtime.worker import BLOCK_SAMPLES, WorkerLink, WorkerSettings

log = logging.getLogger(__name__)


def build_estimator(cfg: EstimatorConfig, fs_hz: float) -> Any:
    """A fresh RBPF from the configuration (module level, so it pickles to the worker)."""
    from gateway.estimator.rbpf import RBPF, RBPFConfig

    return RBPF(RBPFConfig(fs_hz=fs_hz, n_particles=cfg.particles, sensors=cfg.sensors,
                           seed=cfg.seed, ar_paper=cfg.track_roughness,
                           estimate_ar=cfg.estimate_track_roughness,
                           walk_rel_per_sqrt_s=(cfg.drift_per_sqrt_s,) * 3))


def restore_estimator(blob: bytes) -> Any:
    """An RBPF restored from checkpoint bytes."""
    from gateway.estimator.rbpf import RBPF

    return RBPF.restore(blob)


def warm_estimator(numba_threads: int) -> None:
    """A worker process's start: numba's global settings (once, here), then import the
    estimator and load its compiled kernels (so a spare worker waits warm)."""
    from gateway.estimator.threads import configure

    configure(numba_threads)
    import gateway.estimator.rbpf  # noqa: F401


def worker_settings(cfg: Config) -> WorkerSettings:
    """How the worker builds, restores and paces the estimator for this configuration."""
    return WorkerSettings(
        builder=functools.partial(build_estimator, cfg.estimator, cfg.resampler.fs_hz),
        restorer=restore_estimator,
        output_interval_s=1.0 / cfg.estimator.output_rate_hz,
        checkpoint_interval_s=cfg.estimator.checkpoint_interval_s,
        warmup=functools.partial(warm_estimator, kernel_threads(cfg.estimator.particles)))


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
