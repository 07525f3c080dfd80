"""The live gateway service: wires bus, pipeline, sinks, state, console and systemd.

``Service.run()`` is the daemon's main loop. SIGTERM/SIGINT stop it cleanly (final
checkpoint, state flushed). SIGHUP re-reads the config file and applies the keys in
``RELOADABLE`` at once: ``[output] estimate_rate_hz`` and ``health_rate_hz``. A change
to any other key is logged as needing a restart and the running value stays (the
console's ``config`` shows what is in force); a file that fails validation is logged
and changes nothing. Alert thresholds are not config keys: ``threshold set`` on the
console changes them and the persisted policy keeps them.

READY=1 is sent once the bus is open and the worker runs; until the worker is up (its
first start compiles the numba kernels, minutes on a cold cache) the start time-out
is extended by EXTEND_TIMEOUT_USEC, for at most ``STARTUP_EXTEND_LIMIT_S``. WATCHDOG=1
only while the pipeline makes progress; STATUS= shows the live estimates.

Over 400 lines: it is the one place that wires every stage (bus, pipeline, sinks, state,
console, systemd) and its main loop; each stage's logic lives in its own package.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Any

import can

from gateway.can.bus import BusSpec, open_bus, set_receive_buffer
from gateway.can.busload import frame_bits_worst_case
from gateway.can.codec import SENSOR_NODE, Codec, default_codec
from gateway.can.source import BusSource
from gateway.config import Config, load_config, with_overrides
from gateway.errors import ConfigError
from gateway.model.vehicle import PARAM_NAMES
from gateway.records import Alert, Estimate, Sink
from gateway.runtime.pipeline import Pipeline, checkpoint_mismatch
from gateway.service.losses import LossCounts, LossLog
from gateway.service.sdnotify import Notifier
from gateway.service.view import ServiceViewImpl
from gateway.sinks.outputs import LEFT_OUT_NODES, CanSink, Health, HealthFlags, LogSink
from gateway.sinks.state import restore_policy
from gateway.sinks.store import CHECKPOINT, StateStore

log = logging.getLogger(__name__)

FRAME_BITS = frame_bits_worst_case(8)
PROGRESS_TIMEOUT_S = 5.0
"""The worker must have advanced within this long (while work is queued) to feed the watchdog."""
STARTUP_EXTEND_EVERY_S = 5.0
STARTUP_EXTEND_S = 30.0
"""While the worker warms up, every STARTUP_EXTEND_EVERY_S the start time-out is extended
to STARTUP_EXTEND_S from then (systemd applies it only beyond TimeoutStartSec)."""
RELOADABLE: tuple[tuple[str, str], ...] = (("output", "estimate_rate_hz"),
                                          ("output", "health_rate_hz"))
"""The (section, key)s SIGHUP applies to the running service; every other key needs a
restart (the bus, the pipeline, the worker, the state store and the console port are
built from them at start)."""
STARTUP_EXTEND_LIMIT_S = 900.0
"""No extension after this long: a worker not up by then is broken, and systemd's
time-out and Restart= take over."""


def status_line(est: Estimate | None, active_alerts: int, bus_state: str, rtf: float,
                flags: Sequence[str] = ()) -> str:
    """The one-line STATUS= text, e.g. ``Csy 39.8+-0.7 kNs/m, ...``; raised health flags
    (``HealthFlags.names()``) at the end, e.g. ``; flags priority-not-applied``."""
    tail = f"; flags {','.join(flags)}" if flags else ""
    if est is None:
        return f"waiting for estimates; bus {bus_state}{tail}"
    m, s = est.mean, est.std
    return (f"Csy {m[0] / 1e3:.1f}+-{s[0] / 1e3:.1f} kNs/m, Csay {m[1] / 1e3:.0f}+-"
            f"{s[1] / 1e3:.0f} kNs/m, conicity {m[2]:.3f}+-{s[2]:.3f}; t={est.t_s:.0f} s; "
            f"{active_alerts} active alert(s); bus {bus_state}; RTF {rtf:.2f}{tail}")


@dataclass
class ServiceFlags:
    """What the signal handlers ask of the main loop."""

    stop: bool = False
    reload: bool = False


class Service:
    """The daemon: ``run()`` until stopped; returns the exit status."""

    def __init__(self, cfg: Config, *, config_path: str | None = None,
                 notifier: Notifier | None = None, codec: Codec | None = None,
                 console_factory: Callable[[Service], Any] | None = None) -> None:
        self.cfg = cfg
        self.config_path = config_path
        self._file_cfg = load_config(config_path) if config_path else None
        """The file as read at start, without command-line overrides: a reload compares
        the file with it, so an override (``--bus``) is not taken for a change."""
        self.notifier = notifier or Notifier()
        self.codec = codec or default_codec()
        self.flags = ServiceFlags()
        self.started_monotonic = time.monotonic()
        self.store = StateStore(cfg.state.directory, on_corrupt="quarantine")
        self._console_factory = console_factory
        self.console: Any = None
        self.recent_log: list[str] = []
        self.lock = threading.Lock()
        spec = BusSpec(cfg.bus.interface, cfg.bus.channel)
        self.rx_filters = self.codec.can_filters()
        """The DBC's sensor ids: kernel filters on SocketCAN (foreign frames never reach
        Python), python-can's software filter on ``virtual``."""
        self.source = BusSource(lambda: self._open_bus(spec),
                                queue_frames=cfg.bus.rx_queue_frames,
                                reopen_min_s=cfg.bus.reopen_min_s,
                                reopen_max_s=cfg.bus.reopen_max_s)
        self.can_sink = CanSink(self.codec, self.source.send, cfg.estimator.particles,
                                estimate_rate_hz=cfg.output.estimate_rate_hz)
        self.log_sink = LogSink()
        self.sinks: tuple[Sink, ...] = (self.can_sink, self.log_sink)
        """Every estimate and alert event goes to each of these, in order."""
        self.policy, history = restore_policy(self.store)   # never raises for bad state
        self.recent_alerts: collections.deque[Alert] = collections.deque(history[-50:],
                                                                          maxlen=50)
        self.pipeline: Pipeline | None = None
        self._old_handlers: dict[int, Any] = {}
        self.view = ServiceViewImpl(self)
        self._log_installed = False
        self._load_mark = (time.monotonic(), 0)
        self._load_pct = 0.0
        self._resyncs_reported = 0
        self._losses = LossLog()

    # -------------------------------------------------------------- callbacks
    def _on_checkpoint(self, seq: int, blob: bytes) -> None:
        t = self.pipeline.last_estimate.t_s if self.pipeline and self.pipeline.last_estimate \
            else math.nan
        self.store.save_checkpoint(blob, t_s=t)
        self.store.save_policy(self.policy.snapshot())

    def _on_estimate(self, est: Estimate) -> None:
        for sink in self.sinks:
            sink.emit(est)
        self.store.record_estimate(est)

    def on_alert(self, alert: Alert) -> None:
        """Every alert event, from the policy or a console command: to all sinks."""
        for sink in self.sinks:
            sink.emit(alert)
        self.store.append_alert(alert)
        self.recent_alerts.append(alert)
        self.store.save_policy(self.policy.snapshot())
        if self.console is not None:
            self.console.notify_alert(alert)

    # ---------------------------------------------------------------- signals
    def install_signal_handlers(self) -> None:
        def stop(signum: int, frame: FrameType | None) -> None:
            self.flags.stop = True

        def hup(signum: int, frame: FrameType | None) -> None:
            self.flags.reload = True

        self._old_handlers = {sig: signal.signal(sig, handler) for sig, handler in
                              ((signal.SIGTERM, stop), (signal.SIGINT, stop), (signal.SIGHUP, hup))}

    def _restore_signal_handlers(self) -> None:
        for sig, handler in self._old_handlers.items():
            signal.signal(sig, handler)
        self._old_handlers = {}

    def _reload(self) -> None:
        """SIGHUP: re-read the file; apply the ``RELOADABLE`` keys, log every other
        changed key as needing a restart; a bad file changes nothing."""
        self.flags.reload = False
        self.notifier.notify(RELOADING=1,
                             MONOTONIC_USEC=time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000)
        try:
            self._apply_reload()
        except Exception as err:  # noqa: BLE001 - a bad reload keeps the running config
            log.error("reload failed, keeping the running configuration: %s", err)
            self.notifier.notify(READY=1, STATUS=f"reload failed: {err}".replace("\n", " "))
        else:
            self.notifier.notify(READY=1, STATUS="configuration reloaded")

    def _apply_reload(self) -> None:
        if self.config_path is None:
            log.warning("reload: no config file (built-in defaults and command-line "
                        "options only); nothing to reload")
            return
        new = load_config(self.config_path)
        before = self._file_cfg or Config()
        changes: dict[str, object] = {}
        for section in ("bus", "resampler", "gating", "estimator", "output", "state", "serial"):
            old_s, new_s = getattr(before, section), getattr(new, section)
            for f in dataclasses.fields(new_s):
                value = getattr(new_s, f.name)
                if (section, f.name) in RELOADABLE:
                    if value != getattr(getattr(self.cfg, section), f.name):
                        changes[f"{section}.{f.name}"] = value
                elif value != getattr(old_s, f.name):
                    shown = "<redacted>" if f.name == "pin_hash" else repr(value)
                    log.warning("reload: [%s] %s = %s in %s needs a restart to take "
                                "effect; running with the value from start", section,
                                f.name, shown, self.config_path)
        if not changes:
            log.info("reload: no reloadable key changed in %s", self.config_path)
            return
        # the same checks as at start, on what will run (e.g. estimate_rate_hz at most the
        # running [estimator] output_rate_hz); a ConfigError changes nothing
        mark = f"{self.config_path} (reload)"
        try:
            cfg = with_overrides(dataclasses.replace(self.cfg, source=mark), changes)
        except ConfigError as err:
            text = str(err).removeprefix(f"{mark} (with command-line overrides): ")
            raise ConfigError(f"{self.config_path}: {text} (with the running values of the "
                              f"keys that need a restart)") from err
        cfg = dataclasses.replace(cfg, source=self.cfg.source)
        self.can_sink.set_estimate_rate(cfg.output.estimate_rate_hz)
        for dotted, value in changes.items():
            section, _, key = dotted.partition(".")
            log.info("reload: [%s] %s %r -> %r", section, key,
                     getattr(getattr(self.cfg, section), key), value)
        self.cfg = cfg
        log.info("configuration reloaded from %s", self.config_path)

    # ------------------------------------------------------------------- loop
    def health(self) -> Health:
        p = self.pipeline
        src = self.source.stats
        ps = p.stats() if p is not None else None
        if p is None or ps is None or p.last_estimate is None:
            state = "Starting"
        elif not src.bus_open or not ps.worker_alive:
            state = "Fault"
        elif any(m.timed_out for m in ps.sensors):
            state = "Degraded"
        else:
            state = "Running"
        dropped = src.dropped_queue_full + src.dropped_kernel + \
            (ps.samples_dropped if ps else 0)
        return Health(state, int(src.bus_state), len(self.policy.active),
                      src.frames_rx, ps.frames_rejected if ps else 0, dropped,
                      ps.rtf if ps else math.nan, self.health_flags())

    def _log_losses(self, now_s: float) -> None:
        src, p = self.source.stats, self.pipeline
        line = self._losses.line(LossCounts(
            src.dropped_kernel, src.dropped_queue_full,
            p.stats().samples_dropped if p is not None else 0), now_s)
        if line is not None:
            log.warning("%s", line)

    def health_flags(self) -> HealthFlags:
        """The faults the service runs on with, for GW_HealthFlags, STATUS= and the console."""
        p = self.pipeline
        late = gaps = resyncs = 0
        two_senders = False
        if p is not None:               # the front end's counters, every reason summed
            fe = p.front.stats()        # a receive-clock step re-based counts as a resync
            late, two_senders = fe.late_total, bool(fe.two_senders)
            resyncs = fe.resyncs + fe.clock_steps
            gaps = fe.gap_points
        priority_error = p.stats().priority_error if p is not None else None
        est = p.last_estimate if p is not None else None
        left_out = {SENSOR_NODE[s] for s in est.left_out} if est is not None else set()
        return HealthFlags(
            state_quarantined=bool(self.store.quarantined),
            persistence_failing=self.store.write_failures > 0,
            priority_not_applied=bool(priority_error),
            front_end_resyncing=resyncs > self._resyncs_reported,
            two_senders=two_senders,
            left_out_nodes=tuple(n for n in LEFT_OUT_NODES if n in left_out),
            late_frames=late, gap_samples=gaps, write_failures=self.store.write_failures,
            resyncs=resyncs)

    def _progressing(self, last_done: list[float]) -> bool:
        p = self.pipeline
        if p is None:
            return False
        ps = p.stats()
        backlog = ps.samples_out - 1 - ps.last_seq_done
        now = time.monotonic()
        if ps.last_seq_done != last_done[0]:
            last_done[0], last_done[1] = ps.last_seq_done, now
        return ps.worker_alive and (backlog <= 2 * 20
                                    or now - last_done[1] < PROGRESS_TIMEOUT_S)

    def run(self) -> int:
        """Main loop; returns 0 after a clean stop."""
        ck = self.store.load_checkpoint()
        blob = ck.blob if ck is not None else None
        if blob is not None:
            why = checkpoint_mismatch(self.cfg.estimator, self.cfg.resampler.fs_hz, blob)
            if why is None:
                log.info("resuming the estimator from the persisted checkpoint")
            else:       # set aside (kept, a health flag); the estimator starts fresh
                self.store.quarantine(CHECKPOINT, f"not this configuration's estimator, "
                                                  f"which starts fresh: {why}")
                blob = None
        self.install_log_tail()
        self.source.start()
        self.pipeline = Pipeline(self.cfg, self.codec, policy=self.policy, checkpoint=blob,
                                 on_checkpoint=self._on_checkpoint,
                                 on_estimate=self._on_estimate, on_alert=self.on_alert)
        self.view.publish()
        if self._console_factory is not None:
            self.console = self._console_factory(self)
        elif self.cfg.serial.device:
            from gateway.console.port import console_port

            self.console = console_port(self.view, self.cfg.serial)
            if self.console is not None:
                self.console.start()
        ready = False
        next_health = next_status = next_publish = started = next_extend = time.monotonic()
        last_done = [-2.0, time.monotonic()]
        p = self.pipeline
        try:
            while not self.flags.stop:
                # Read once per turn: READY, the extension and STATUS must agree on it (a
                # worker that came up between them let "waiting for estimates" out first).
                warming = not ready and not p.stats().worker_ready
                if not ready and not warming and self.source.opened.wait(0.05):
                    ready = True
                    self.notifier.ready("pipeline up: bus open, estimator running")
                    log.info("pipeline up")
                elif warming and \
                        started + STARTUP_EXTEND_LIMIT_S > time.monotonic() >= next_extend:
                    next_extend = time.monotonic() + STARTUP_EXTEND_EVERY_S
                    self.notifier.extend_timeout(STARTUP_EXTEND_S, "starting: estimator "
                                                 "warming up (a first start compiles its "
                                                 "kernels: minutes)")
                msg = self.source.get(0.01)
                n = 0
                while msg is not None and n < 2000:
                    p.on_frame(msg)
                    n += 1
                    msg = self.source.get() if n < 2000 else None
                if n < 2000:
                    # Queue drained: the receive clock's "now" is as far as the receive thread
                    # has read. Not wall time: frames still waiting in the kernel are not
                    # missing, and a deadline passed on them would drop them as late.
                    # With the bus closed nothing waits in a kernel: wall time it is, so
                    # sensor timeouts and gaps still show during an outage.
                    src = self.source.stats
                    horizon = min(time.time(), src.rx_horizon_s) if src.bus_open \
                        else time.time()
                    if math.isfinite(horizon):
                        p.on_time(horizon)
                p.poll()
                self.view.run_pending()
                if self.flags.reload:
                    self._reload()       # a new health rate counts from now, not the old tick
                    next_health = min(next_health, time.monotonic()
                                      + 1.0 / self.cfg.output.health_rate_hz)
                now = time.monotonic()
                if now >= next_health:
                    next_health = now + 1.0 / self.cfg.output.health_rate_hz
                    health = self.health()
                    self.can_sink.emit_health(health)
                    self._resyncs_reported = health.flags.resyncs
                    self._log_losses(now)
                    if self._progressing(last_done):
                        self.notifier.watchdog()
                if now >= next_publish:
                    next_publish = now + 0.5
                    self._count_load(now)
                    self.view.publish()
                if now >= next_status and not warming:
                    # While the worker warms up, the extension's STATUS says so: not
                    # overwritten by "waiting for estimates" (systemctl status shows it).
                    next_status = now + 2.0
                    self.notifier.status(status_line(
                        p.last_estimate, len(self.policy.active), self.source.stats.bus_state.name,
                        p.rtf, self.health_flags().names()))
        finally:
            self.close()
        return 0

    def close(self) -> None:
        """Stop everything, flushing state; idempotent and bounded in time (< 5 s)."""
        self.notifier.stopping()
        if self.console is not None:
            self.console.close()
            self.console = None
        if self.pipeline is not None:
            self.pipeline.close()
            self.store.save_policy(self.policy.snapshot())
        self.source.close()
        for sink in self.sinks:
            sink.close()
        self.store.close()
        self.notifier.close()
        self.remove_log_tail()
        if self._old_handlers and threading.current_thread() is threading.main_thread():
            self._restore_signal_handlers()

    def install_log_tail(self) -> None:
        """Keep the last log lines for the console's ``log`` (a root handler, installed
        once when the service starts, removed by :meth:`close`); the console shows INFO
        and up, so the ``gateway`` logger passes INFO."""
        if self._log_installed:
            return
        logging.getLogger().addHandler(self.view.log_tail)
        ours = logging.getLogger("gateway")
        if ours.getEffectiveLevel() > logging.INFO:
            ours.setLevel(logging.INFO)
        self._log_installed = True

    def remove_log_tail(self) -> None:
        """Undo :meth:`install_log_tail`; idempotent."""
        if self._log_installed:
            logging.getLogger().removeHandler(self.view.log_tail)
            self._log_installed = False

    def data_time_s(self) -> float:
        """Data time of the latest estimate (NaN before the first)."""
        p = self.pipeline
        return p.last_estimate.t_s if p is not None and p.last_estimate is not None else math.nan

    def _count_load(self, now: float) -> None:
        frames = self.source.stats.frames_rx + self.source.stats.frames_tx
        t0, f0 = self._load_mark
        if now - t0 >= 1.0:
            rate = (frames - f0) / (now - t0)
            self._load_pct = 100.0 * rate * FRAME_BITS / self.codec.bitrate_bps
            self._load_mark = (now, frames)

    def _open_bus(self, spec: BusSpec) -> can.BusABC:
        """The sensor bus with the DBC's filters and the configured receive buffer (its
        size, or why it is smaller, goes to the journal at every open)."""
        bus = open_bus(spec, can_filters=self.rx_filters)
        buf = set_receive_buffer(bus, self.cfg.bus.rcvbuf_bytes)
        if buf is not None:
            (log.warning if buf.clamped else log.info)("%s", buf.describe())
        return bus

    def bus_load_pct(self) -> float:
        """Measured bus load over the last second or so (worst-case frame length), %."""
        return round(self._load_pct, 1)

    @property
    def uptime_s(self) -> float:
        return time.monotonic() - self.started_monotonic

    def param_names(self) -> tuple[str, ...]:
        return PARAM_NAMES
