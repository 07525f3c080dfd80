"""The estimator worker: the RBPF in its own process, fed through a bounded queue.

Over 400 lines, on purpose: the worker's whole lifecycle (spawn, warm spare,
supervision, replay of unacknowledged blocks after a crash) is one state machine. The
messages on its queues are the typed records of :mod:`gateway.runtime.messages`.

The service sends blocks of grid samples; the worker steps the estimator, returns
estimates at the output rate (data time) and a checkpoint every
``checkpoint_interval_s`` of data time. The parent keeps every block sent since the
last checkpoint, so when a worker dies a new one restores the checkpoint and is fed
those blocks again: it resumes exactly where the dead one was. Live, a worker that
falls a full queue behind loses one contiguous run of samples (counted): every block is
dropped until it has stepped all it was given, so the estimator sees one gap, not a
block between two gaps again and again (:meth:`WorkerLink.send`). Replay blocks
instead, so replay is deterministic.
Workers are spawned (a fresh interpreter): numba's OpenMP threading layer aborts in a
process forked from one that has used it, so fork and a preloading fork server are
both unsafe here. A spawned interpreter needs seconds to import and load the compiled
kernels, so a warm spare worker always waits, imported, for its start message: a dead
worker is replaced by the spare at once (well under the 2 s target) and a new spare is
spawned in the background. A worker that dies before finishing any sample three times in a row
is an error (EstimatorError), not a restart loop.

Process hygiene: a worker dies with its parent (``PR_SET_PDEATHSIG`` = SIGKILL, and a
watchdog thread on multiprocessing's parent sentinel pipe where prctl is missing or the
parent died before it was set). It ignores SIGINT and SIGTERM (they are blocked from
before its interpreter starts), so a Ctrl-C or a process-group signal reaches only the
parent, which stops the worker and writes the final checkpoint. (Linux sends the
death signal when the *thread* that spawned the worker ends: spawn workers from the
thread that supervises them for their whole life, as the service and replay do.)
The worker lowers its CPU priority (``os.nice``); whether that worked is reported to
the parent (:attr:`WorkerStats.priority_error`), never silently dropped.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import multiprocessing as mp
import os
import queue
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, assert_never

import numpy as np

from gateway.errors import EstimatorError
from gateway.records import Estimate, Estimator, NoiseCheck, Sample
from gateway.runtime.messages import (
    BaselineReset,
    CheckpointOut,
    Control,
    EstimateOut,
    NoiseOut,
    Progress,
    Ready,
    Reply,
    Request,
    SampleBlock,
    Start,
    Stop,
    Stopped,
)

log = logging.getLogger(__name__)

WORKER_NICE = 10
"""How much lower the worker's CPU priority is than the service's."""
PR_SET_PDEATHSIG = 1  # linux/prctl.h
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Signals a worker ignores: its parent stops it (and takes the final checkpoint)."""
MAX_FAILED_STARTS = 3
"""Consecutive worker deaths before the first processed sample that make an error."""
BLOCK_SAMPLES = 20
"""Samples per queue item (20 ms at 1 kHz): amortises the inter-process cost."""


@dataclass(frozen=True)
class WorkerSettings:
    """What a worker needs to build (or restore) its estimator and pace its outputs."""

    builder: Callable[[], Estimator]
    """Picklable zero-argument callable returning a fresh estimator."""
    restorer: Callable[[bytes], Estimator]
    """Picklable callable turning checkpoint bytes back into an estimator."""
    output_interval_s: float
    checkpoint_interval_s: float
    grid_dt_s: float
    """The sample grid's step (1 / ``[resampler] fs_hz``): the time step of the
    predict-only samples that bridge a gap of dropped blocks."""
    warmup: Callable[[], None] | None = None
    """Picklable; run by a spare worker before it waits (imports, loads compiled code)."""
    lower_priority: Callable[[int], object] = os.nice
    """Picklable; called with WORKER_NICE in the worker. The unit's seccomp filter or a
    test may make it raise OSError: the worker then runs on and reports it."""


def die_with_parent(parent_pid: int) -> str:
    """Make this process die when ``parent_pid`` does: PR_SET_PDEATHSIG (Linux), and a
    watchdog thread on the multiprocessing parent sentinel (any POSIX). Returns how."""
    how = "watchdog"
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0:
                how = "pdeathsig+watchdog"
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:        # died before the death signal was armed
        os._exit(1)
    parent = mp.parent_process()
    if parent is not None and getattr(parent, "sentinel", None) is not None:
        def watch() -> None:
            parent.join()                 # returns when the parent's end of the pipe closes
            os._exit(1)
    else:
        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(0.5)
            os._exit(1)
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    return how


def lower_priority(fn: Callable[[int], object], nice: int = WORKER_NICE) -> str:
    """Lower this process's CPU priority by ``nice``; "" if done, else why not."""
    try:
        fn(nice)
    except OSError as err:
        return f"nice +{nice} refused: {err}"
    return ""


def _worker_main(settings: WorkerSettings, in_q: Any, out_q: Any, stop: Any,
                 parent_pid: int) -> None:
    """Process entry point: warm up, wait for :class:`Start`, then step, report and
    checkpoint; exits on :class:`Stop`.

    ``Start.checkpoint_seq`` is the last sample the checkpoint has seen; older ones are
    skipped.
    """
    for sig in STOP_SIGNALS:              # blocked since the spawn: ignore, then unblock
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    die_with_parent(parent_pid)
    # The receive/decode/resample path has deadlines; the estimator has a queue. So the
    # worker yields the CPU to it (the service's main process keeps the default priority).
    priority_error = lower_priority(settings.lower_priority)
    if settings.warmup is not None:
        settings.warmup()
    start: Request = in_q.get()
    if not isinstance(start, Start):     # Stop: a spare that was never started
        return
    checkpoint = start.checkpoint
    est = settings.restorer(checkpoint) if checkpoint else settings.builder()
    last_seq = start.checkpoint_seq if checkpoint else -1
    _put(out_q, Ready(last_seq, priority_error))
    next_out = -math.inf
    next_ckpt = -math.inf
    applied: set[Control] = set()
    noise_told = False
    while True:
        item: Request = in_q.get()
        if stop.is_set():                # stop now: the backlog is not worked off
            item = Stop()
        match item:
            case Stop():
                _put(out_q, CheckpointOut(last_seq, est.checkpoint()))
                _put(out_q, Stopped(last_seq))
                return
            case BaselineReset(after_seq=after_seq, index=index):
                # replayed into a restarted worker until a checkpoint covers it: apply once
                if after_seq >= last_seq and item not in applied:
                    est.reset_parameter(index)
                    applied.add(item)
            case SampleBlock():
                block = item
                if last_seq >= 0 and block.seq0 > last_seq + 1:
                    _bridge_gap(est, block, block.seq0 - last_seq - 1, settings.grid_dt_s)
                    last_seq = block.seq0 - 1
                # runs of samples up to the next output or checkpoint go in one call
                # (Estimator.run: the same evolution as stepping them one by one)
                i, n = max(0, last_seq + 1 - block.seq0), len(block.t_s)
                while i < n:
                    j = i
                    while j < n - 1 and block.t_s[j] < next_out and block.t_s[j] < next_ckpt:
                        j += 1
                    run = [Sample(float(block.t_s[k]), block.values[k],
                                  float(block.speed_mps[k]), bool(block.update[k]))
                           for k in range(i, j + 1)]
                    e = est.run(run, output_every=len(run))[-1]
                    seq, t = block.seq0 + j, float(block.t_s[j])
                    last_seq = seq
                    if not noise_told and (check := est.noise_check()) is not None:
                        _put(out_q, NoiseOut(seq, check))
                        noise_told = True
                    if t >= next_out:
                        _put(out_q, EstimateOut(seq, e))
                        next_out = t + settings.output_interval_s
                    if t >= next_ckpt:
                        if math.isfinite(next_ckpt):
                            _put(out_q, CheckpointOut(seq, est.checkpoint()))
                        next_ckpt = t + settings.checkpoint_interval_s
                    i = j + 1
                _put(out_q, Progress(last_seq))
            case Start():
                raise EstimatorError(f"expected one Start per worker, got another "
                                     f"after sample {last_seq}")
            case _:
                assert_never(item)


def _put(out_q: Any, reply: Reply) -> None:
    """One typed reply to the parent."""
    out_q.put(reply)


MAX_PREDICT_GAP = 500
"""Longest gap (samples) bridged by predict-only steps; longer ones restart the filters."""


def _bridge_gap(est: Estimator, block: SampleBlock, missing: int, grid_dt_s: float) -> None:
    """Samples that never reached the worker (dropped blocks): predict through a short
    gap, one step of ``grid_dt_s`` per missing sample; after a long one restart the
    state filters (parameter particles kept), since predicting through seconds would
    only fall further behind."""
    if missing > MAX_PREDICT_GAP:
        est.restart_filters()
        return
    nan = np.full(block.values.shape[1], np.nan)
    for j in range(missing, 0, -1):
        est.advance(Sample(float(block.t_s[0]) - j * grid_dt_s, nan,
                           float(block.speed_mps[0]), False))


@dataclass
class WorkerStats:
    """Counters of the worker link."""

    samples_sent: int = 0
    samples_dropped: int = 0
    drop_runs: int = 0
    """Contiguous runs of dropped samples: each one gap in the estimator's data."""
    ready: bool = False
    restarts: int = 0
    estimates: int = 0
    checkpoints: int = 0
    last_seq_done: int = -1
    alive: bool = False
    last_checkpoint_seq: int = -1
    replay_backlog: int = 0
    priority_error: str | None = None
    """None until a worker reported; "" when its priority was lowered; else why not."""
    noise_check: NoiseCheck | None = None
    """The estimator's sensor-noise test, once a worker reported it."""
    errors: list[str] = field(default_factory=list)


class WorkerLink:
    """The parent's end: start, feed, poll, supervise and stop the worker process."""

    def __init__(self, settings: WorkerSettings, *, queue_blocks: int,
                 checkpoint: bytes | None = None, blocking: bool = False,
                 on_checkpoint: Callable[[int, bytes], None] | None = None,
                 keep_spare: bool = True) -> None:
        self._ctx = mp.get_context("spawn")
        self._stop = self._ctx.Event()
        self._settings = settings
        self._queue_blocks = queue_blocks
        self._blocking = blocking
        self._on_checkpoint = on_checkpoint
        self._checkpoint = checkpoint
        self._pending: deque[SampleBlock | Control] = deque()
        self._outbox: deque[SampleBlock | Control] = deque()
        """Items for the worker, in order, not yet on its queue (:meth:`_feed`)."""
        self._proc: Any = None
        self._in_q: Any = None
        self._out_q: Any = None
        self.stats = WorkerStats()
        self._seq = 0
        self._shedding = False
        """Live: dropping every block until the worker has stepped what it was given."""
        self._failures = 0
        self._done_at_start = -1
        self._spare: tuple[Any, Any, Any] | None = None
        self._early: list[Estimate] = []
        self._keep_spare = keep_spare
        self._start()

    def _spawn(self) -> tuple[Any, Any, Any]:
        """A new (not yet started on data) worker process and its queues."""
        in_q = self._ctx.Queue(maxsize=self._queue_blocks)
        out_q = self._ctx.Queue()
        proc = self._ctx.Process(target=_worker_main, name="railgw-rbpf", daemon=True,
                                 args=(self._settings, in_q, out_q, self._stop, os.getpid()))
        # The child inherits this thread's signal mask through exec: a Ctrl-C while its
        # interpreter boots stays pending until the worker has chosen to ignore it.
        old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        return proc, in_q, out_q

    @staticmethod
    def _release(*queues: Any) -> None:
        """Close queues without waiting for their feeder threads (the reader may be dead)."""
        for q in queues:
            if q is not None:
                q.cancel_join_thread()
                q.close()

    def _start(self) -> None:
        self._release(self._in_q, self._out_q)
        self._done_at_start = self.stats.last_seq_done
        spare = self._spare
        self._spare = None
        if spare is None or not spare[0].is_alive():
            spare = self._spawn()
        self._proc, self._in_q, self._out_q = spare
        self._in_q.put(Start(self._checkpoint, self.stats.last_checkpoint_seq))
        self.stats.alive = True
        self.stats.ready = False
        if self._keep_spare:
            self._spare = self._spawn()
        # replay what the checkpoint has not seen: it can be more than the queue holds,
        # so it goes through the outbox, which the main loop tops up and never waits on
        self._outbox = deque(self._pending)
        self.stats.replay_backlog = len(self._pending)
        self._feed()

    def _feed(self) -> None:
        """Move items from the outbox onto the worker's queue while it has room; never
        waits. A restarted worker's replay (up to a checkpoint interval plus a queue) and
        an instruction sent while the queue is full wait here, in order, so that neither
        holds the service's main loop: a blocking put there held it for as long as the
        worker took to make room, and for ever if the new worker died or stopped."""
        while self._outbox:
            try:
                self._in_q.put_nowait(self._outbox[0])
            except queue.Full:
                return
            self._outbox.popleft()

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    @property
    def backlog_samples(self) -> int:
        """Samples on the queue that the worker has not stepped yet, as of the last poll
        (the blocks kept for a restart since the last checkpoint hold them all)."""
        n = 0
        for item in reversed(self._pending):
            if item.last_seq <= self.stats.last_seq_done:
                break
            if isinstance(item, SampleBlock):
                n += len(item.t_s)
        return n

    def send(self, samples: list[Sample]) -> None:
        """Queue a block of consecutive samples. Replay waits for room; live, a block
        that does not fit is dropped (counted), and so is every later one until the
        worker has stepped all it was given (:meth:`_shed`)."""
        if not samples:
            return
        block = SampleBlock(self._seq, np.array([s.t_s for s in samples]),
                            np.stack([s.values for s in samples]),
                            np.array([s.speed_mps for s in samples]),
                            np.array([s.update for s in samples]))
        self._seq += len(samples)
        if not self._blocking and self._shed(block):
            return
        self.stats.samples_sent += len(samples)
        self._enqueue(block)
        while self._blocking and self._outbox:   # replay: wait for room, supervised
            try:
                self._in_q.put(self._outbox[0], timeout=0.5)
                self._outbox.popleft()
            except queue.Full:
                self.supervise()

    def _shed(self, block: SampleBlock) -> bool:
        """Live: whether to drop ``block`` (True: counted and logged) rather than send it.

        A worker behind its queue loses one contiguous run of samples: once a block does
        not fit (the backlog would pass the queue's ``queue_blocks * BLOCK_SAMPLES``),
        every block is dropped until the worker has stepped all it was given. Dropping
        only while there is no room would hand a worker slower than the data one block
        between two gaps, again and again; each gap costs the estimator a filter
        restart, and fast mode's restart runs the exact recursion, slower still:
        measured, a worker that once fell behind never caught up (docs/reliability.md
        "Worker behind")."""
        n, backlog = len(block.t_s), self.backlog_samples
        if self._shedding and backlog > 0:
            self.stats.samples_dropped += n
            return True
        if self._shedding:
            self._shedding = False
            log.warning("estimator worker caught up; %d samples dropped in %d run(s) so "
                        "far", self.stats.samples_dropped, self.stats.drop_runs)
        if backlog + n <= self._queue_blocks * BLOCK_SAMPLES:
            return False
        self._shedding = True
        self.stats.drop_runs += 1
        log.warning("estimator worker %d samples behind, its queue full: dropping samples "
                    "until it has stepped them; its filters restart after the gap", backlog)
        self.stats.samples_dropped += n
        return True

    def baseline_reset(self, index: int) -> None:
        """Parameter ``index`` re-learns from its prior, after every sample sent so far
        (:meth:`gateway.records.Estimator.reset_parameter`)."""
        self._control(BaselineReset(self._seq - 1, index))

    def _control(self, item: BaselineReset) -> None:
        """Queue an instruction after every block sent before it (never waits: the
        outbox, :meth:`_feed`); kept for replay into a restarted worker until a
        checkpoint covers it."""
        self._enqueue(item)

    def _enqueue(self, item: SampleBlock | Control) -> None:
        """Keep ``item`` for a restart's replay and hand it on after everything before it."""
        self._pending.append(item)
        self._outbox.append(item)
        self._feed()

    def poll(self, timeout_s: float = 0.0) -> list[Estimate]:
        """Estimates received since the last poll; restarts a dead worker first and
        tops up its queue from the outbox."""
        self.supervise()
        self._feed()
        out: list[Estimate] = self._early
        self._early = []
        wait = timeout_s
        while True:
            try:
                reply: Reply = self._out_q.get(timeout=wait) if wait > 0 else \
                    self._out_q.get_nowait()
            except queue.Empty:
                return out
            wait = 0.0
            self.stats.last_seq_done = max(self.stats.last_seq_done, reply.seq)
            match reply:
                case EstimateOut(estimate=est):
                    out.append(est)
                    self.stats.estimates += 1
                case CheckpointOut(seq=seq, blob=blob):
                    self._checkpointed(seq, blob)
                case Ready(priority_error=error):
                    self.stats.ready = True
                    self._priority_reported(error)
                case NoiseOut(check=check):
                    self._noise_reported(check)
                case Progress() | Stopped():
                    pass
                case _:
                    assert_never(reply)

    def _noise_reported(self, check: NoiseCheck) -> None:
        if check != self.stats.noise_check:
            log.log(logging.WARNING if any(check.replaced) or check.note else logging.INFO,
                    "estimator: %s", check.summary())
        self.stats.noise_check = check

    def _priority_reported(self, error: str | None) -> None:
        if error is None:
            return
        if error and error != self.stats.priority_error:
            log.warning("estimator worker %s runs at the service's priority: %s (the "
                        "receive path now competes with it for the CPU)", self.pid, error)
        self.stats.priority_error = error

    def wait_ready(self, timeout_s: float) -> bool:
        """Poll until the worker has built its estimator; estimates meanwhile are kept
        for the next :meth:`poll`."""
        end = time.monotonic() + timeout_s
        while not self.stats.ready and time.monotonic() < end:
            self._early.extend(self.poll(timeout_s=0.1))
        return self.stats.ready

    def _checkpointed(self, seq: int, blob: bytes) -> None:
        self._checkpoint = blob
        self.stats.checkpoints += 1
        self.stats.last_checkpoint_seq = seq
        while self._pending and self._pending[0].last_seq <= seq:
            self._pending.popleft()
        if self._on_checkpoint is not None:
            self._on_checkpoint(seq, blob)

    def supervise(self) -> bool:
        """Restart the worker from the last checkpoint if it died; True if it did."""
        if self._proc is None or self._proc.is_alive():
            return False
        code = self._proc.exitcode
        if self.stats.last_seq_done == self._done_at_start:
            self._failures += 1
            if self._failures >= MAX_FAILED_STARTS:
                raise EstimatorError(f"expected the estimator worker to run, got "
                                     f"{self._failures} deaths in a row before its first "
                                     f"sample (last exit code {code})")
        else:
            self._failures = 0
        log.error("estimator worker %s died (exit %s); restarting from checkpoint at sample %d",
                  self._proc.pid, code, self.stats.last_checkpoint_seq)
        self.stats.restarts += 1
        self.stats.alive = False
        self._start()
        return True

    def drain(self, timeout_s: float = 600.0) -> list[Estimate]:
        """Wait until every sent sample is processed; the estimates produced meanwhile."""
        out: list[Estimate] = []
        while self.stats.last_seq_done < self._seq - 1:
            got = self.poll(timeout_s=0.5)
            out.extend(got)
            timeout_s -= 0.5
            if timeout_s <= 0:
                break
        return out

    def close(self, timeout_s: float = 3.0) -> list[Estimate]:
        """Ask the worker for a final checkpoint and stop it; idempotent."""
        if self._proc is None:
            return []
        out: list[Estimate] = []
        if self._spare is not None:              # holds no state: no need to wait for it
            self._spare[0].kill()
        if not self._blocking:
            self._stop.set()                     # live: checkpoint now, skip the backlog
        try:
            self._in_q.put(Stop(), timeout=timeout_s)
            while True:
                reply: Reply = self._out_q.get(timeout=timeout_s)
                match reply:
                    case EstimateOut(estimate=est):
                        out.append(est)
                    case CheckpointOut(seq=seq, blob=blob):
                        self._checkpointed(seq, blob)
                    case Stopped():
                        break
                    case NoiseOut(check=check):
                        self._noise_reported(check)
                    case Ready() | Progress():
                        pass
                    case _:
                        assert_never(reply)
        except queue.Empty:
            log.warning("worker did not stop cleanly: expected its final checkpoint within "
                        "%.1f s, got no reply (the last periodic checkpoint stands)", timeout_s)
        except queue.Full:
            log.warning("worker did not stop cleanly: expected room in its input queue "
                        "within %.1f s, it stayed full (the last periodic checkpoint "
                        "stands)", timeout_s)
        except (OSError, ValueError) as err:
            log.warning("worker did not stop cleanly: its queues failed: %s: %s",
                        type(err).__name__, err)
        self._proc.join(timeout=timeout_s)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(timeout=1.0)
        self._proc = None
        self.stats.alive = False
        self._release(self._in_q, self._out_q)
        self._in_q = self._out_q = None
        if self._spare is not None:
            proc, in_q, out_q = self._spare
            self._spare = None
            with contextlib.suppress(queue.Full, OSError, ValueError):
                in_q.put_nowait(Stop())
            proc.join(timeout=timeout_s)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=1.0)
            self._release(in_q, out_q)
        return out
