"""The estimator worker as a process: its priority, reported; Ctrl-C ignored; dies with its parent.

A tiny counting estimator stands in for the RBPF (module level: it is pickled to the
spawned worker, which imports this module), so these tests take seconds, not minutes.
"""

from __future__ import annotations

import errno
import logging
import os
import signal
import time
from pathlib import Path

import numpy as np
from fakes.stepping import SteppedRuns

from gateway.records import Estimate, Sample
from gateway.runtime.worker import WORKER_NICE, WorkerLink, WorkerSettings


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
