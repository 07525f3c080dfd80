"""Typed seams: the worker's messages, the Estimator and Sink protocols, the service's log tail.

A recording estimator stands in for the RBPF in the worker-process tests (module level:
it is pickled to the spawned worker, which imports this module), so they take seconds.
The RBPF itself is checked against the protocol by mypy (``build_estimator`` returns
an ``Estimator``; the annotated assignment below) and by a step/checkpoint/restore run.
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import signal
import time
from pathlib import Path

import can
import numpy as np
import pytest
from fakes.stepping import SteppedRuns

from gateway.can.codec import default_codec
from gateway.config import Config, with_overrides
from gateway.estimator.rbpf import RBPF
from gateway.records import Alert, AlertState, Estimate, Estimator, Sample, Severity, Sink
from gateway.runtime import messages as m
from gateway.runtime.pipeline import build_estimator, restore_estimator, worker_settings
from gateway.runtime.worker import MAX_PREDICT_GAP, WorkerLink, WorkerSettings, _bridge_gap
from gateway.service.daemon import Service
from gateway.sinks.outputs import CanSink, LogSink


class RecordingEstimator(SteppedRuns):
    """Implements :class:`Estimator`; its checkpoint is the log of what it was asked."""

    def __init__(self, state: dict[str, list[object]] | None = None) -> None:
        self.state: dict[str, list[object]] = state or {"t_s": [], "resets": [],
                                                          "restarts": []}

    def reset(self, rng: np.random.Generator) -> None:
        self.state = {"t_s": [], "resets": [], "restarts": []}

    def step(self, sample: Sample) -> Estimate:
        self.state["t_s"].append(sample.t_s)
        n = float(len(self.state["t_s"]))
        return Estimate(sample.t_s, (n,) * 3, (1.0,) * 3, 1.0, updated=sample.update)

    def checkpoint(self) -> bytes:
        return json.dumps(self.state).encode()

    @classmethod
    def restore(cls, blob: bytes) -> RecordingEstimator:
        return cls(json.loads(blob))

    def restart_filters(self) -> None:
        self.state["restarts"].append(len(self.state["t_s"]))

    def reset_parameter(self, index: int) -> None:
        self.state["resets"].append([len(self.state["t_s"]), index])


_conforms: Estimator = RecordingEstimator()          # mypy: the fake is an Estimator too


def build() -> Estimator:
    return RecordingEstimator()


def _samples(seq0: int, n: int) -> list[Sample]:
    return [Sample((seq0 + k) * 1e-3, np.zeros(3), 40.0, True) for k in range(n)]


def _settings() -> WorkerSettings:
    return WorkerSettings(builder=build, restorer=RecordingEstimator.restore,
                          output_interval_s=0.0, checkpoint_interval_s=1e9, grid_dt_s=1e-3)


def _until(cond, timeout_s: float, link: WorkerLink) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < deadline:
        link.poll(0.1)
    return bool(cond())


# ------------------------------------------------------------------ messages
def test_every_message_pickles_across_the_spawn_boundary():
    est = Estimate(1.5, (4e4, 2e6, 0.2), (1e3, 1e5, 0.01), 321.0, 0.01, 0.02, updated=False)
    block = m.SampleBlock(40, np.array([0.04, 0.041]), np.arange(6.0).reshape(2, 3),
                          np.array([40.0, 40.5]), np.array([True, False]))
    simple = [m.Start(b"ck", 39), m.Start(None, -1), m.BaselineReset(39, 2), m.Stop(),
              m.Ready(-1, ""), m.Ready(39, "nice +10 refused"), m.EstimateOut(41, est),
              m.CheckpointOut(41, b"\x00\x01"), m.Progress(41), m.Stopped(41)]
    for msg in simple:
        back = pickle.loads(pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL))
        assert type(back) is type(msg) and back == msg
    back = pickle.loads(pickle.dumps(block))
    assert back.seq0 == 40 and back.last_seq == 41
    for name in ("t_s", "values", "speed_mps", "update"):
        np.testing.assert_array_equal(getattr(back, name), getattr(block, name))
    assert m.BaselineReset(39, 2).last_seq == 39
    assert m.BaselineReset(39, 0) != m.BaselineReset(39, 2)       # both are applied
    with pytest.raises(AttributeError):
        m.Stopped(1).seq = 2  # type: ignore[misc]


def test_baseline_resets_apply_in_order_once_each_even_replayed_into_a_new_worker():
    got: list[bytes] = []
    link = WorkerLink(_settings(), queue_blocks=8, keep_spare=False,
                      on_checkpoint=lambda seq, blob: got.append(blob))
    try:
        assert link.wait_ready(60)
        link.send(_samples(0, 20))
        link.baseline_reset(0)
        link.baseline_reset(2)               # a second part, after the same sample
        link.send(_samples(20, 5))
        assert _until(lambda: link.stats.last_seq_done >= 24, 30, link)
        pid = link.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)         # no checkpoint yet: all of it is replayed
        assert _until(lambda: link.stats.restarts == 1 and link.stats.ready, 60, link)
        link.send(_samples(25, 3))
        assert _until(lambda: link.stats.last_seq_done >= 27, 30, link)
    finally:
        link.close()
    state = json.loads(got[-1])              # the final checkpoint, of the new worker
    assert state["resets"] == [[20, 0], [20, 2]]
    assert state["t_s"] == pytest.approx([k * 1e-3 for k in range(28)])
    assert state["restarts"] == []


def test_a_gap_is_bridged_on_the_configured_grid_step_even_after_a_one_sample_block():
    est = RecordingEstimator()
    block = m.SampleBlock(10, np.array([0.5]), np.zeros((1, 3)), np.array([40.0]),
                          np.array([True]))
    _bridge_gap(est, block, 3, grid_dt_s=2e-3)          # e.g. [resampler] fs_hz = 500
    assert est.state["t_s"] == pytest.approx([0.494, 0.496, 0.498])
    assert est.state["restarts"] == []
    _bridge_gap(est, block, MAX_PREDICT_GAP + 1, grid_dt_s=2e-3)
    assert est.state["restarts"] == [3] and len(est.state["t_s"]) == 3


def test_the_worker_is_told_the_grid_step_of_the_configuration():
    cfg = with_overrides(Config(), {"resampler.fs_hz": 500.0})
    assert worker_settings(cfg).grid_dt_s == 2e-3


# ---------------------------------------------------------------- estimator
def test_the_rbpf_is_an_estimator_through_the_pipelines_builder_and_restorer():
    cfg = with_overrides(Config(), {"estimator.particles": 16, "estimator.sensors": 3,
                                    "estimator.sensor_noise": "model"})
    rbpf: Estimator = build_estimator(cfg.estimator, cfg.resampler.fs_hz)
    typed: Estimator = RBPF.restore(rbpf.checkpoint())     # mypy: RBPF satisfies it
    assert isinstance(rbpf, RBPF) and isinstance(typed, RBPF)
    rng = np.random.default_rng(3)
    samples = [Sample(k * 1e-3, rng.normal(0.0, 0.1, 3), 40.0, True) for k in range(30)]
    for s in samples[:20]:
        rbpf.step(s)
    copy = restore_estimator(rbpf.checkpoint())
    a = [rbpf.step(s) for s in samples[20:25]]
    b = [copy.step(s) for s in samples[20:25]]
    assert [repr(x) for x in a] == [repr(x) for x in b]   # exactly where it left off
    z = rbpf.z.copy()
    rbpf.reset_parameter(1)              # what the worker does on BaselineReset(.., 1)
    assert np.array_equal(rbpf.z[:, [0, 2]], z[:, [0, 2]]) and not np.array_equal(
        rbpf.z[:, 1], z[:, 1])
    z, logw = rbpf.z.copy(), rbpf.logw.copy()
    rbpf.restart_filters()               # what it does after a long gap: particles kept
    assert np.array_equal(rbpf.z, z) and np.array_equal(rbpf.logw, logw)
    assert rbpf.step(samples[25]).t_s == 0.025


# --------------------------------------------------------------------- sinks
ALERT = Alert(7, 3.25, "csy_ns_per_m", Severity.ALARM, AlertState.RAISED, 0x12, 0.25, "low")
EST = Estimate(4.0, (4.0e4, 2.0e6, 0.2), (5e2, 4e4, 0.004), 300.0)


def test_sinks_take_every_record_through_emit():
    sent: list[can.Message] = []
    direct: list[can.Message] = []
    def send(msg: can.Message, out: list[can.Message] = sent) -> bool:
        out.append(msg)
        return True

    sinks: tuple[Sink, ...] = (CanSink(default_codec(), send, 500), LogSink())
    for sink in sinks:
        sink.emit(EST)
        sink.emit(ALERT)
    other = CanSink(default_codec(), lambda msg: send(msg, direct), 500)
    other.emit_estimate(EST)
    other.emit_alert(ALERT)
    assert len(sent) == 4                # three estimate frames, one alert frame
    assert [(x.arbitration_id, bytes(x.data)) for x in sent] == \
        [(x.arbitration_id, bytes(x.data)) for x in direct]
    for sink in sinks:
        sink.close()
        sink.close()                     # idempotent


def test_the_log_sink_logs_alerts_not_estimates(caplog):
    caplog.set_level(logging.INFO, logger="gateway.sinks.outputs")
    sink = LogSink()
    sink.emit(EST)
    assert caplog.records == []
    sink.emit(ALERT)
    assert [r.levelno for r in caplog.records] == [logging.ERROR]
    assert "alert #7 raised alarm csy_ns_per_m at t=3.2 s (25 % of nominal)" in caplog.text


# ------------------------------------------------------------------ log tail
def test_the_console_log_tail_is_installed_at_start_once_and_removed_on_close(tmp_path: Path):
    cfg = with_overrides(Config(), {"bus.interface": "virtual", "bus.channel": "tail-test",
                                    "state.directory": str(tmp_path)})
    root = logging.getLogger()
    before = list(root.handlers)
    svc = Service(cfg)
    try:
        assert root.handlers == before               # constructing installs nothing
        svc.install_log_tail()
        svc.install_log_tail()
        assert root.handlers == [*before, svc.view.log_tail]
        logging.getLogger("gateway.test").info("a line for the console")
        assert svc.view.log_lines(1)[0].endswith("INFO gateway.test: a line for the console")
    finally:
        svc.close()
    assert root.handlers == before
    svc.close()                                      # idempotent
    assert root.handlers == before
