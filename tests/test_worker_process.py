"""The estimator worker as a process: its priority, reported; Ctrl-C ignored; dies with its parent;
a worker behind its queue loses one run of samples.

A tiny counting estimator stands in for the RBPF (module level: it is pickled to the
spawned worker, which imports this module), so these tests take seconds, not minutes.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from fakes.stepping import SteppedRuns

from gateway.records import Estimate, Sample
from gateway.runtime.worker import BLOCK_SAMPLES, WORKER_NICE, WorkerLink, WorkerSettings


class CountingEstimator(SteppedRuns):
    """Counts the samples it stepped; the checkpoint is that count."""

    def __init__(self, n: int = 0) -> None:
        self.n = n

    def step(self, sample: Sample) -> Estimate:
        self.n += 1
        return Estimate(sample.t_s, (float(self.n),) * 3, (1.0,) * 3, 1.0)

    def checkpoint(self) -> bytes:
        return str(self.n).encode()


def build() -> CountingEstimator:
    return CountingEstimator()


class GatedEstimator(SteppedRuns):
    """Takes one permit of ``gate`` per call of ``run`` (the test's hand on the worker's
    speed); its estimate's mean is (samples with data stepped, samples bridged without
    data, baseline resets applied)."""

    def __init__(self, gate: Any) -> None:
        self.gate, self.stepped, self.bridged, self.resets = gate, 0, 0, 0

    def step(self, sample: Sample) -> Estimate:
        if np.isnan(sample.values).all():
            self.bridged += 1
        else:
            self.stepped += 1
        return Estimate(sample.t_s, (float(self.stepped), float(self.bridged),
                                     float(self.resets)), (1.0,) * 3, 1.0)

    def reset_parameter(self, index: int) -> None:
        self.resets += 1

    def run(self, samples, output_every=None):
        self.gate.acquire()
        return super().run(samples, output_every)

    def restart_filters(self) -> None:
        raise AssertionError("a gap this short is bridged, not a restart")

    def checkpoint(self) -> bytes:
        return b""


def build_gated(gate: Any) -> GatedEstimator:
    return GatedEstimator(gate)


def restore(blob: bytes) -> CountingEstimator:
    return CountingEstimator(int(blob))


def refuse_nice(increment: int) -> int:
    """What os.nice does under the unit's seccomp filter without the setpriority rule."""
    raise PermissionError(errno.EPERM, "Operation not permitted")


def _settings(**kwargs: object) -> WorkerSettings:
    return WorkerSettings(builder=build, restorer=restore, output_interval_s=0.0,
                          checkpoint_interval_s=1e9, grid_dt_s=1e-3,
                          **kwargs)  # type: ignore[arg-type]


def _samples(n: int) -> list[Sample]:
    return [Sample(k * 1e-3, np.zeros(3), 40.0, True) for k in range(n)]


def _nice_of(pid: int) -> int:
    """Field 19 of /proc/PID/stat (after the parenthesised command name)."""
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])


def test_the_worker_runs_at_lower_priority_and_says_so():
    link = WorkerLink(_settings(), queue_blocks=4, keep_spare=False)
    try:
        assert link.wait_ready(60)
        assert link.stats.priority_error == ""
        assert link.pid is not None
        assert _nice_of(link.pid) == min(19, os.nice(0) + WORKER_NICE)
    finally:
        link.close()


def test_a_refused_priority_is_reported_in_stats_and_the_log(caplog):
    caplog.set_level(logging.WARNING, logger="gateway.runtime.worker")
    link = WorkerLink(_settings(lower_priority=refuse_nice), queue_blocks=4, keep_spare=False)
    try:
        assert link.wait_ready(60)
        assert link.stats.priority_error == "nice +10 refused: [Errno 1] Operation not permitted"
        assert link.pid is not None and _nice_of(link.pid) == os.nice(0)
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert any("runs at the service's priority" in w and "refused" in w for w in warnings)
    finally:
        link.close()


def test_sigint_and_sigterm_leave_the_worker_to_its_parent_who_takes_the_final_checkpoint():
    got: list[bytes] = []
    link = WorkerLink(_settings(), queue_blocks=4, keep_spare=False,
                      on_checkpoint=lambda seq, blob: got.append(blob))
    assert link.wait_ready(60)
    pid = link.pid
    assert pid is not None
    link.send(_samples(20))
    deadline = time.monotonic() + 30
    while link.stats.last_seq_done < 19 and time.monotonic() < deadline:
        link.poll(0.1)
    os.kill(pid, signal.SIGINT)       # what a Ctrl-C in the terminal sends the whole group
    os.kill(pid, signal.SIGTERM)      # and `kill -TERM -PGID`
    link.send(_samples(5))
    deadline = time.monotonic() + 30
    while link.stats.last_seq_done < 24 and time.monotonic() < deadline:
        link.poll(0.1)
    assert link.stats.last_seq_done == 24 and link.stats.restarts == 0
    link.close()
    assert got[-1] == b"25"           # the final checkpoint: every sample stepped


def test_a_worker_that_does_not_answer_the_stop_is_killed_and_the_log_says_what_was_missing(
        caplog):
    caplog.set_level(logging.WARNING, logger="gateway.runtime.worker")
    link = WorkerLink(_settings(), queue_blocks=4, keep_spare=False)
    assert link.wait_ready(60)
    pid = link.pid
    assert pid is not None
    os.kill(pid, signal.SIGSTOP)      # frozen: it cannot take the stop or checkpoint
    try:
        link.close(timeout_s=0.5)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    assert not Path(f"/proc/{pid}").exists() or _state_of(pid) == "Z"
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert ("worker did not stop cleanly: expected its final checkpoint within 0.5 s, got no "
            "reply (the last periodic checkpoint stands)") in warnings, warnings


def _state_of(pid: int) -> str:
    """Field 3 of /proc/PID/stat: R, S, T, Z..."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


class GatedLink:
    """A live link whose worker (a :class:`GatedEstimator`, built afresh by every worker,
    a restarted one too) steps one sample per permit the test gives."""

    def __init__(self, queue_blocks: int) -> None:
        self.gate = mp.get_context("spawn").Semaphore(0)
        settings = WorkerSettings(builder=partial(build_gated, self.gate), restorer=restore,
                                  output_interval_s=0.0, checkpoint_interval_s=1e9,
                                  grid_dt_s=1e-3)
        self.link = WorkerLink(settings, queue_blocks=queue_blocks, keep_spare=False)
        self.got: list[Estimate] = []

    @staticmethod
    def block(k: int) -> list[Sample]:
        """Block ``k`` of the grid: samples k * BLOCK_SAMPLES ... , 1 ms apart."""
        return [Sample((k * BLOCK_SAMPLES + i) * 1e-3, np.zeros(3), 40.0, True)
                for i in range(BLOCK_SAMPLES)]

    def step(self, n: int, upto: int) -> None:
        """Let the worker step ``n`` samples (one run each: output every sample) and wait
        until the parent has heard that sample ``upto`` is done."""
        for _ in range(n):
            self.gate.release()
        deadline = time.monotonic() + 30
        while self.link.stats.last_seq_done < upto and time.monotonic() < deadline:
            self.got.extend(self.link.poll(0.1))
        assert self.link.stats.last_seq_done == upto

    def close(self, permits: int) -> None:
        for _ in range(permits):           # never leave a worker waiting on the gate
            self.gate.release()
        self.link.close()


def test_a_worker_behind_its_queue_loses_one_run_of_samples_not_a_block_between_gaps():
    """Live, a worker a full queue behind (here held by the test; on a slow box, a filter
    start at exact-mode speed) loses one contiguous run: blocks keep being dropped until
    it has stepped everything it was given, not put on the queue as soon as there is room
    between two gaps. The estimator then bridges that one gap."""
    g = GatedLink(queue_blocks=4)          # 80 samples
    link, got = g.link, g.got
    try:
        assert link.wait_ready(60)
        for k in range(6):                 # 4 blocks fit, the 5th starts a run of drops
            link.send(g.block(k))
        assert (link.stats.samples_dropped, link.stats.drop_runs) == (40, 1)
        g.step(40, 39)
        link.send(g.block(6))              # room on the queue, 40 samples still to step
        assert (link.stats.samples_dropped, link.stats.drop_runs) == (60, 1)
        g.step(40, 79)
        link.send(g.block(7))              # caught up: taken, after one gap of 60
        g.step(20, 159)
        assert (link.stats.samples_dropped, link.stats.drop_runs) == (60, 1)
        assert link.stats.samples_sent == 100
        # one estimate per sample stepped with data; the 60 bridged before sample 140
        assert [round(e.t_s * 1e3) for e in got] == list(range(80)) + list(range(140, 160))
        assert [e.mean[1] for e in got] == [0.0] * 80 + [60.0] * 20
        assert got[-1].mean[0] == 100.0
    finally:
        g.close(100)


def test_a_restarted_worker_gets_its_replay_and_instructions_without_holding_the_caller():
    """A worker killed with more blocks since its last checkpoint than its queue holds:
    the restart replays them all, in order, but from an outbox the caller tops up, so
    neither the restart nor a baseline reset sent meanwhile waits for the new worker
    (here held by the test; on a vehicle, a slow start or a worker that died again).
    Before, the restart put the replay on the queue with a blocking put and held the
    service's main loop until the worker made room, for ever if it never did."""
    g = GatedLink(queue_blocks=3)          # 60 samples
    link, got = g.link, g.got

    def restart_and_reset() -> None:
        deadline = time.monotonic() + 30
        while link.stats.restarts == 0 and time.monotonic() < deadline:
            got.extend(link.poll(0.1))
        link.baseline_reset(0)

    try:
        assert link.wait_ready(60)
        for k in range(3):
            link.send(g.block(k))
        g.step(60, 59)
        for k in range(3, 6):              # 60 more on the queue: 120 since the start
            link.send(g.block(k))
        assert link.pid is not None
        os.kill(link.pid, signal.SIGKILL)   # no checkpoint yet: all 120 are replayed
        caller = threading.Thread(target=restart_and_reset, daemon=True)
        caller.start()
        caller.join(60)
        assert not caller.is_alive(), "the restart waited for the new worker's queue"
        assert link.stats.restarts == 1 and link.stats.replay_backlog == 6
        g.step(120, 119)                   # the replay, in order, then the reset
        link.send(g.block(6))
        g.step(20, 139)
        assert link.stats.samples_dropped == 0 and link.stats.restarts == 1
        # the old worker's 60, the new worker's 120 (all replayed) and 20 more
        assert [round(e.t_s * 1e3) for e in got] == (list(range(60)) + list(range(140)))
        assert got[-1].mean == (140.0, 0.0, 1.0)     # none bridged, the reset applied once
        assert got[-21].mean == (120.0, 0.0, 0.0)    # ... after the replay, not in it
    finally:
        g.close(300)
