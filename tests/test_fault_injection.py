"""Fault injection: one table of faults, each with its EN 50159 threat and expected counter or flag.

Every row of :data:`FAULTS` names a fault, how it is injected, the threat it maps to
(``docs/reliability.md``), the counter or flag that must show it and the predicate on
that value. Three runners take the rows that apply to them:

- ``replay``: a short nominal simulator log (made once per module and per simulator
  setting), the fault injected into its frames, then :func:`gateway.offline.replay.replay`
  (real worker process); the predicate is checked on the report's ``FrontEndStats``,
  and the front end must not go blind (measurement updates go on);
- ``live``: a real :class:`gateway.service.daemon.Service` on a python-can ``virtual`` bus, the
  same faulty frames sent by the test in real time (receive stamps as the sender gives
  them, as a kernel would), the same predicate on the service's front end and the
  health flag read back off the bus (GW_HealthFlags 0x321);
- ``state``: faults of the state directory and of the processes (full disk, unusable
  files, kill -9 at seeded random points, the worker killed during a checkpoint), run
  against the live service; each returns an :class:`Outcome`.

The front-end tests (``tests/test_frontend_*.py``) probe each mechanism in depth; this
suite runs every fault end to end through both the replay and the live service.
"""

from __future__ import annotations

import copy
import errno
import os
import random
import re
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import can
import pytest
from test_service import Running, _demo, _wait

from firmware_sim.output import send_live, write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.codec import default_codec
from gateway.can.e2e import e2e_crc
from gateway.config import Config, with_overrides
from gateway.frontend.stats import FrontEndStats
from gateway.offline.replay import replay
from gateway.sinks.store import ALERTS, POLICY, StateStore, files

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

DURATION_S = 6.0
"""Length of the simulated traffic, s."""
FAULT_S = 2.5
"""Data time at which every frame fault starts, s."""
PARTICLES = 32
"""Enough for the worker to run; the estimates are not what this suite checks."""

Frames = list[tuple[float, can.Message]]
"""Frames in bus order, each with the offset (s) added to its receive stamp: the
message's own timestamp paces the live sender, the offset is the receive-clock fault."""


# ------------------------------------------------------------------ traffic and injection
@lru_cache(maxsize=4)
def _clean(sim: tuple[tuple[str, Any], ...]) -> tuple[can.Message, ...]:
    cfg = SimConfig(duration_s=DURATION_S, seed=1, **dict(sim))
    return tuple(Simulation(get_scenario("nominal"), cfg).messages())


def traffic(sim: tuple[tuple[str, Any], ...] = ()) -> Frames:
    """A fresh copy of the nominal run (shared per simulator setting), no offsets."""
    return [(0.0, copy.copy(m)) for m in _clean(sim)]


def _ids(message: str) -> int:
    return default_codec().message(message).frame_id


def _first(frames: Frames, message: str | None = None) -> int:
    return next(i for i, (_, m) in enumerate(frames) if m.timestamp >= FAULT_S
                and (message is None or m.arbitration_id == _ids(message)))


def glitch(frames: Frames) -> Frames:
    """Ten consecutive frames (about 3 ms of traffic) stamped 0.5 s early (issue 12 #1)."""
    i0 = _first(frames)
    return [(off - 0.5 if i0 <= i < i0 + 10 else off, m) for i, (off, m) in enumerate(frames)]


def clock_step(step_s: float) -> Callable[[Frames], Frames]:
    """The receive clock steps by ``step_s`` at FAULT_S (NTP step, adapter reset)."""
    def inject(frames: Frames) -> Frames:
        return [(off + step_s if m.timestamp >= FAULT_S else off, m) for off, m in frames]
    return inject


def _reencode(m: can.Message, **changes: int) -> can.Message:
    """``m`` re-encoded with a valid CRC after changing SampleIdx and/or the counter."""
    codec = default_codec()
    f = codec.decode_message(m)
    values: dict[str, Any] = dict(f.values)
    values[f"{f.message}_SampleIdx"] = changes.get("idx", f.sample_idx)
    out = codec.encode_message(f.message, values, changes.get("counter", f.counter))
    out.timestamp = m.timestamp
    return out


def idx_jump(frames: Frames) -> Frames:
    """From FAULT_S, BGN's SampleIdx jumps 20 000 ahead (its counter runs on)."""
    bgn = _ids("BGN_Lat")
    codec = default_codec()
    return [(off, _reencode(m, idx=((codec.decode_message(m).sample_idx or 0) + 20_000) % 65536)
             if m.arbitration_id == bgn and m.timestamp >= FAULT_S else m)
            for off, m in frames]


def delete(message: str, n: int) -> Callable[[Frames], Frames]:
    """``n`` consecutive frames of ``message`` from FAULT_S never arrive."""
    def inject(frames: Frames) -> Frames:
        fid = _ids(message)
        i0 = _first(frames, message)
        drop = {i for i, (_, m) in enumerate(frames[i0:], i0) if m.arbitration_id == fid}
        drop = set(sorted(drop)[:n])
        return [f for i, f in enumerate(frames) if i not in drop]
    return inject


def repeat(n: int) -> Callable[[Frames], Frames]:
    """``n`` BGN frames from FAULT_S each sent twice (same counter: a replayed frame)."""
    def inject(frames: Frames) -> Frames:
        fid, left = _ids("BGN_Lat"), n
        out: Frames = []
        for off, m in frames:
            out.append((off, m))
            if left and m.arbitration_id == fid and m.timestamp >= FAULT_S:
                out.append((off, copy.copy(m)))
                left -= 1
        return out
    return inject


def reorder(pairs: int) -> Callable[[Frames], Frames]:
    """``pairs`` pairs of consecutive BGN frames from FAULT_S swapped on the bus."""
    def inject(frames: Frames) -> Frames:
        fid = _ids("BGN_Lat")
        idx = [i for i, (_, m) in enumerate(frames) if m.arbitration_id == fid
               and m.timestamp >= FAULT_S][:2 * pairs:]
        out = list(frames)
        for a, b in zip(idx[::2], idx[1::2], strict=True):
            (oa, ma), (ob, mb) = out[a], out[b]
            ma2, mb2 = copy.copy(mb), copy.copy(ma)     # contents swapped, slots kept
            ma2.timestamp, mb2.timestamp = ma.timestamp, mb.timestamp
            out[a], out[b] = (oa, ma2), (ob, mb2)
        return out
    return inject


def corrupt(n: int) -> Callable[[Frames], Frames]:
    """One data bit flipped in ``n`` BDN frames from FAULT_S (the CRC no longer fits)."""
    def inject(frames: Frames) -> Frames:
        fid, left = _ids("BDN_Lat"), n
        out: Frames = []
        for off, m in frames:
            if left and m.arbitration_id == fid and m.timestamp >= FAULT_S:
                m = copy.copy(m)
                m.data = bytearray(m.data)
                m.data[4] ^= 0x10
                left -= 1
            out.append((off, m))
        return out
    return inject


def forge(n: int) -> Callable[[Frames], Frames]:
    """``n`` forged WSN frames with a valid CRC and the alive counter 15 (never sent)."""
    def inject(frames: Frames) -> Frames:
        fid = _ids("WSN_Lat")
        out: Frames = []
        left = n
        for off, m in frames:
            out.append((off, m))
            if left and m.arbitration_id == fid and m.timestamp >= FAULT_S:
                forged = bytearray(_reencode(m).data)
                forged[1] = (forged[1] & 0xF0) | 0x0F       # counter 15, then a valid CRC
                forged[0] = e2e_crc(fid, forged)
                out.append((off, can.Message(timestamp=m.timestamp, arbitration_id=fid,
                                             data=bytes(forged), is_extended_id=False)))
                left -= 1
        return out
    return inject


# ------------------------------------------------------------------------- the table
@dataclass(frozen=True)
class Fault:
    """One row: a fault, its injection, threat, and the counter or flag that must show it."""

    name: str
    threat: str
    """EN 50159 threat (repetition, deletion, insertion, resequencing, corruption, delay,
    masquerade) or the non-communication fault class."""
    how: str
    counter: str
    """Where the fault shows: a ``FrontEndStats`` path, a GW_HealthFlags signal, ..."""
    expect: Callable[[Any], bool]
    """Predicate on the observed value of ``counter``."""
    expect_text: str
    measure: Callable[[Any], Any]
    """Picks the observed value out of the runner's result (FrontEndStats, Outcome)."""
    inject: Callable[[Frames], Frames] | None = None
    sim: tuple[tuple[str, Any], ...] = ()
    """SimConfig overrides of the traffic (e.g. a second sender)."""
    flag: str | None = None
    """GW_HealthFlags signal that must show the fault live (max over the frames read)."""
    flag_expect: Callable[[float], bool] | None = None
    status: tuple[str, int] | None = None
    """(estimate message, value): the ``_Status`` the last updated frame of that message
    (not PredictOnly) read live must carry (e.g. 4 Unresolved for Csy with the body node
    out)."""
    runners: frozenset[str] = frozenset({"replay", "live"})
    min_updates: float = 0.95
    """Measurement updates at least this fraction of the grid points (not blind)."""
    state: Callable[[Path], Outcome] | None = None
    """For state/process faults: runs the scenario against the live service."""
    see_also: str = ""
    live_defect: str = ""
    """A known defect of the live service on this row: its live run is a strict xfail."""


@dataclass(frozen=True)
class Outcome:
    """What a state or process fault left behind."""

    flags: dict[str, float] = field(default_factory=dict)
    quarantined: tuple[str, ...] = ()
    write_failures: int = 0
    estimates_after: int = 0
    restarts: int = 0
    resumed: int = 0
    seqs: tuple[int, ...] = ()
    next_seqs: tuple[int, ...] = ()
    dropped: int = 0
    drop_runs: int = 0


def _rej(reason: str) -> Callable[[FrontEndStats], int]:
    return lambda fe: fe.rejected.get(reason, 0)


def _lost_beyond(fe: FrontEndStats, message: str) -> int:
    """Grid points ``message`` lost beyond the other node's (BGN or BDN): the silence
    before and after the traffic is lost for every node alike (live, the grid runs on)."""
    other = "BGN_Lat" if message == "BDN_Lat" else "BDN_Lat"
    return fe.gaps[message]["lost"] - fe.gaps[other]["lost"]


FAULTS: list[Fault] = []    # filled below, once the state scenarios are defined


# ------------------------------------------------------------------------- replay runner
def _replay(frames: Frames, path: Path) -> FrontEndStats:
    msgs = []
    for off, m in frames:
        m = copy.copy(m)
        m.timestamp += off
        msgs.append(m)
    write_log(msgs, path)
    cfg = with_overrides(Config(), {"estimator.particles": PARTICLES})
    result = replay(path, cfg)
    assert result.front_end is not None and result.estimates, "the replay produced nothing"
    return result.front_end


def _check(row: Fault, value: Any) -> None:
    assert row.expect(value), f"{row.name}: {row.counter} = {value!r}, expected {row.expect_text}"


# ---------------------------------------------------------------------------- live runner
class OffsetBus:
    """Sends each frame with the next receive-stamp offset added (the receive fault)."""

    def __init__(self, bus: can.BusABC, offsets: list[float]) -> None:
        self._bus, self._offsets, self._k = bus, offsets, 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        msg.timestamp += self._offsets[self._k]
        self._k += 1
        self._bus.send(msg, timeout)


def _play(run: Running, frames: Frames) -> None:
    from gateway.can.bus import open_node_bus
    with open_node_bus(f"virtual:{run.channel}") as tx:
        send_live([m for _, m in frames], OffsetBus(tx, [off for off, _ in frames]))  # type: ignore[arg-type]


def _flags_max(run: Running) -> dict[str, float]:
    out: dict[str, float] = {}
    for values in run.decoded("GW_HealthFlags"):
        for k, v in values.items():
            out[k] = max(out.get(k, v), v)
    return out


# ------------------------------------------------------------------ state/process faults
def _mount_tmpfs(mnt: Path, size: str) -> bool:
    mnt.mkdir()
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size},mode=700", "tmpfs",
                           str(mnt)], capture_output=True).returncode == 0


def _fill(mnt: Path) -> None:
    fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 4096)
    except OSError as err:
        assert err.errno == errno.ENOSPC
    finally:
        os.close(fd)


def _run_on_full_disk(base: Path, state_parent: Path, monkeypatch: pytest.MonkeyPatch | None
                      ) -> Outcome:
    with Running(state_parent, "full", particles=PARTICLES) as run:
        if monkeypatch is None:
            _fill(state_parent)
        else:                                   # no tmpfs: every state write fails ENOSPC
            def write(fd: int, data: bytes) -> int:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            monkeypatch.setattr(files.os, "write", write)
        n0 = len(run.decoded("GW_EstCsy"))
        _play(run, traffic())
        svc = run.service
        assert _wait(lambda: svc.store.write_failures > 0 and len(run.decoded("GW_EstCsy"))
                     > n0 + 5, 30)
        h0 = len(run.decoded("GW_HealthFlags"))
        assert _wait(lambda: len(run.decoded("GW_HealthFlags")) >= h0 + 2, 10)
        return Outcome(flags=_flags_max(run), write_failures=svc.store.write_failures,
                       estimates_after=len(run.decoded("GW_EstCsy")) - n0)


def full_disk(tmp_path: Path) -> Outcome:
    """The state directory on a 256 kB tmpfs, filled once the service runs."""
    mnt = tmp_path / "tiny"
    if _mount_tmpfs(mnt, "256k"):
        try:
            return _run_on_full_disk(tmp_path, mnt, None)
        finally:
            subprocess.run(["umount", "-l", str(mnt)], check=False)
    with pytest.MonkeyPatch.context() as mp:
        return _run_on_full_disk(tmp_path, tmp_path, mp)


def unusable(name: str, damage: Callable[[Path], object]) -> Callable[[Path], Outcome]:
    """``name`` in the state directory made unusable before the service starts."""
    def scenario(tmp_path: Path) -> Outcome:
        state = tmp_path / "state"
        state.mkdir()
        damage(state)
        with Running(tmp_path, "bad-state", particles=PARTICLES) as run:
            h0 = len(run.decoded("GW_HealthFlags"))
            assert _wait(lambda: len(run.decoded("GW_HealthFlags")) >= h0 + 2, 10)
            return Outcome(flags=_flags_max(run), quarantined=run.service.store.quarantined)
    return scenario


def _demo_once(state: Path, log: Path, *, restarted: bool, kill_after_s: float | None) -> int:
    """One ``gateway demo`` life: up (resumed from the checkpoint if ``restarted``), a
    fresh checkpoint written, then SIGKILL ``kill_after_s`` later (None: SIGTERM).
    Returns 1 if it resumed from the checkpoint."""
    ckpt = state / "checkpoint.bin"
    stamp = ckpt.stat().st_mtime_ns if restarted else 0
    proc = _demo(state, "nominal", 60, log)
    try:
        if restarted:
            assert _wait(lambda: "resuming the estimator" in log.read_text(), 120), \
                log.read_text()[-2000:]
        assert _wait(lambda: ckpt.exists() and ckpt.stat().st_mtime_ns > stamp, 120)
        if kill_after_s is None:
            proc.send_signal(signal.SIGTERM)
        else:   # the random moment of the fault (not a synchronisation)
            end = time.monotonic() + kill_after_s
            _wait(lambda: time.monotonic() >= end or proc.poll() is not None, 3)
            proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=15)
    finally:
        proc.kill()
    return int(restarted)


def kill9_at_random_points(tmp_path: Path) -> Outcome:
    """``gateway demo`` (service and simulator in one process) SIGKILLed at 3 seeded random
    moments after its first checkpoint, restarted on the same state directory each time."""
    rng = random.Random(12)
    state = tmp_path / "state"
    resumed = 0
    next_seqs: list[int] = []
    quarantined: list[str] = []
    for k in range(4):
        log = tmp_path / f"run{k}.log"
        resumed += _demo_once(state, log, restarted=k > 0,
                              kill_after_s=rng.uniform(0.0, 2.0) if k < 3 else None)
        quarantined += re.findall(r"state: (\S+) set aside", log.read_text())
        with StateStore(state, on_corrupt="quarantine") as st:
            assert st.load_checkpoint() is not None
            policy = st.load_policy()
            next_seqs.append(int(policy["next_seq"]) if policy else 1)
            quarantined += list(st.quarantined)
    return Outcome(quarantined=tuple(quarantined), resumed=resumed,
                   next_seqs=tuple(next_seqs))


def worker_killed_in_checkpoint(tmp_path: Path) -> Outcome:
    """The worker SIGKILLed while the service persists the checkpoint it just sent
    (between the blob's arrival and its atomic write): the restarted worker resumes from
    the last checkpoint, the file on disk is whole, and a fresh start uses it."""
    with Running(tmp_path, "ckpt", particles=PARTICLES) as run:
        svc = run.service
        real = svc.store.save_checkpoint
        killed: list[int] = []

        def save(blob: bytes, t_s: float, version: str = "") -> bool:
            p = svc.pipeline
            if not killed and p is not None and p.worker.pid is not None \
                    and p.worker.stats.checkpoints >= 2:
                killed.append(p.worker.pid)
                os.kill(p.worker.pid, signal.SIGKILL)
            return real(blob, t_s, version)

        svc.store.save_checkpoint = save   # type: ignore[method-assign]
        sender = threading.Thread(target=_play, args=(run, traffic()), daemon=True)
        sender.start()
        worker = svc.pipeline.worker if svc.pipeline is not None else None
        assert worker is not None
        assert _wait(lambda: bool(killed) and worker.stats.restarts >= 1, 30)
        n = worker.stats.estimates
        assert _wait(lambda: worker.stats.estimates > n + 1, 15)
        sender.join(30)
        restarts, after = worker.stats.restarts, worker.stats.estimates - n
    with StateStore(tmp_path / "state", on_corrupt="quarantine") as st:
        assert st.load_checkpoint() is not None
        quarantined = st.quarantined
    return Outcome(restarts=restarts, estimates_after=after, quarantined=quarantined)


def worker_stopped(tmp_path: Path) -> Outcome:
    """The worker stopped (SIGSTOP: what a slower box or a second load does to it, in
    the extreme) until more than its queue is behind, then continued: the samples it
    could not take are dropped as one run, it is not restarted (a stopped process is
    alive), and its estimates resume."""
    with Running(tmp_path, "stopped", particles=PARTICLES,
                 overrides={"estimator.queue_samples": 2000}) as run:
        sender = threading.Thread(target=_play, args=(run, traffic()), daemon=True)
        sender.start()
        worker = run.service.pipeline.worker if run.service.pipeline is not None else None
        assert worker is not None and worker.pid is not None
        assert _wait(lambda: worker.stats.estimates >= 2, 30)
        pid = worker.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            assert _wait(lambda: worker.stats.samples_dropped >= 1000, 30)
        finally:
            os.kill(pid, signal.SIGCONT)
        n = worker.stats.estimates
        assert _wait(lambda: worker.stats.estimates > n + 5, 15)
        sender.join(30)
        return Outcome(restarts=worker.stats.restarts, estimates_after=worker.stats.estimates - n,
                       dropped=worker.stats.samples_dropped, drop_runs=worker.stats.drop_runs)


# ------------------------------------------------------------------------- the rows
_LIVE_ONLY = frozenset({"live"})
_REPLAY_ONLY = frozenset({"replay"})
_STATE = frozenset({"state"})

FAULTS += [
    Fault("timestamp glitch", "delay",
          "10 consecutive frames at 2.5 s stamped 0.5 s early (issue 12 #1)",
          "late_total, retimed_frames", lambda v: v == (0, 10), "(0 late, 10 retimed)",
          lambda fe: (fe.late_total, fe.retimed_frames), inject=glitch,
          flag="GW_HealthFlags_LateFrames", flag_expect=lambda v: v == 0,
          see_also="tests/test_frontend_faults.py::"
                   "test_ten_frames_half_a_second_early_do_not_blind_the_front_end"),
    Fault("receive clock step forward", "delay", "receive clock +3600 s at 2.5 s (NTP step)",
          "clock_steps, late_total", lambda v: v == (1, 0), "(1 step re-based, 0 late)",
          lambda fe: (fe.clock_steps, fe.late_total), inject=clock_step(3600.0),
          runners=_REPLAY_ONLY,
          see_also="tests/test_frontend_faults.py::"
                   "test_a_receive_clock_step_is_rebased_without_losing_data"),
    Fault("receive clock step back", "delay", "receive clock -0.5 s at 2.5 s",
          "clock_steps, late_total", lambda v: v == (1, 0), "(1 step re-based, 0 late)",
          lambda fe: (fe.clock_steps, fe.late_total), inject=clock_step(-0.5),
          # a receive-clock step counts with the resyncs in health (GW_HealthFlags_Resyncs)
          flag="GW_HealthFlags_Resyncs", flag_expect=lambda v: v == 1),
    Fault("duplicate sender", "masquerade",
          "a second BGN node (valid CRC, own counter/SampleIdx/clock, values x1.5) "
          "from 1.5 s to 3.5 s (issue 12 #8)",
          "two_sender_events[BGN_Lat], rejected[two_senders]",
          lambda v: v[0] == 1 and v[1] > 2000 and v[2] == (), "(1 event, > 2000, cleared)",
          lambda fe: (fe.two_sender_events["BGN_Lat"], fe.rejected.get("two_senders", 0),
                      fe.two_senders),
          inject=lambda f: f, sim=(("second_sender", "BGN"),
                                   ("second_sender_window_s", (1.5, 3.5))),
          flag="GW_HealthFlags_TwoSenders", flag_expect=lambda v: v == 1, min_updates=0.4,
          see_also="tests/test_frontend_replay.py::"
                   "test_second_sender_is_counted_excluded_and_harmless"),
    Fault("SampleIdx jump", "resequencing",
          "BGN's SampleIdx jumps 20 000 ahead at 2.5 s, its counter runs on",
          "sample_idx_jumps[BGN_Lat][idx_jump]", lambda v: v == 1, "1",
          lambda fe: fe.sample_idx_jumps["BGN_Lat"]["idx_jump"], inject=idx_jump,
          min_updates=0.7,
          see_also="tests/test_frontend_senders.py::test_sample_index_jumps_are_counted_by_reason"),
    Fault("deleted frames", "deletion", "40 consecutive BDN frames from 2.5 s never arrive",
          "gaps[BDN_Lat][lost] - gaps[BGN_Lat][lost]", lambda v: 38 <= v <= 42, "40 +- 2",
          lambda fe: _lost_beyond(fe, "BDN_Lat"), inject=delete("BDN_Lat", 40),
          flag="GW_HealthFlags_GapSamples", flag_expect=lambda v: v >= 38),
    Fault("dead node", "deletion",
          "BDN falls silent at 2.5 s and stays silent (unplugged, its sensor dead)",
          "gaps[BDN_Lat][lost] - gaps[BGN_Lat][lost]", lambda v: v >= 3000, ">= 3000",
          lambda fe: _lost_beyond(fe, "BDN_Lat"), inject=delete("BDN_Lat", 1_000_000),
          flag="GW_HealthFlags_BdnLeftOut", flag_expect=lambda v: v == 1,
          status=("GW_EstCsy", 4), see_also="tests/test_dead_sensor.py"),
    Fault("repeated frames", "repetition",
          "20 BGN frames from 2.5 s sent twice (same counter, same bytes)",
          "rejected[counter_repeated]", lambda v: v == 20, "20",
          _rej("counter_repeated"), inject=repeat(20)),
    Fault("resequenced frames", "resequencing",
          "20 pairs of consecutive BGN frames from 2.5 s swapped on the bus",
          "rejected (all), late_total, gaps[BGN_Lat][lost] - gaps[BDN_Lat][lost]",
          lambda v: v[:2] == (0, 0) and v[2] <= 1,
          "(0, 0, <= 1): placed by SampleIdx (the clean run loses 1 point at its start)",
          lambda fe: (sum(fe.rejected.values()), fe.late_total, _lost_beyond(fe, "BGN_Lat")),
          inject=reorder(20)),
    Fault("corrupted frames", "corruption", "one data bit flipped in 30 BDN frames from 2.5 s",
          "rejected[crc]", lambda v: v == 30, "30", _rej("crc"), inject=corrupt(30)),
    Fault("inserted frames", "insertion",
          "25 forged WSN frames with a valid CRC and the never-sent alive counter 15",
          "rejected[counter]", lambda v: v == 25, "25", _rej("counter"), inject=forge(25)),
    Fault("full disk", "full disk",
          "state directory on a 256 kB tmpfs filled while the service runs "
          "(ENOSPC from every write where no tmpfs can be mounted)",
          "GW_HealthFlags PersistFailing, WriteFailures; estimates go on",
          lambda o: o.flags.get("GW_HealthFlags_PersistFailing") == 1
          and o.flags.get("GW_HealthFlags_WriteFailures", 0) >= 1 and o.estimates_after > 5,
          "flag 1, >= 1 failure on the bus, > 5 estimates after", lambda o: o,
          runners=_STATE, state=full_disk,
          see_also="tests/test_state_startup.py::test_seq_unique_across_restarts_on_a_real_full_disk"),
    Fault("alert policy of the wrong shape", "corrupt state",
          'alert_policy.json = {"version": 1, "next_seq": "x"} before start (issue 12 #2)',
          "store.quarantined, GW_HealthFlags StateQuarantined",
          lambda o: o.quarantined == (POLICY,)
          and o.flags.get("GW_HealthFlags_StateQuarantined") == 1, "(alert_policy.json,), 1",
          lambda o: o, runners=_STATE,
          state=unusable(POLICY, lambda d: (d / POLICY).write_bytes(
              b'{"version": 1, "next_seq": "x"}')),
          see_also="tests/test_state_startup.py::"
                   "test_service_starts_with_an_unusable_file_set_aside"),
    Fault("alert history unreadable", "corrupt state",
          "alerts.jsonl is a directory before start (issue 12 #2)",
          "store.quarantined, GW_HealthFlags StateQuarantined",
          lambda o: o.quarantined == (ALERTS,)
          and o.flags.get("GW_HealthFlags_StateQuarantined") == 1, "(alerts.jsonl,), 1",
          lambda o: o, runners=_STATE,
          state=unusable(ALERTS, lambda d: (d / ALERTS).mkdir())),
    Fault("kill -9 at random points", "power loss / kill -9",
          "gateway demo SIGKILLed 0-2 s (seeded) after a checkpoint, 3 times, restarted",
          "resumed from checkpoint, nothing set aside, policy next_seq never goes back",
          lambda o: o.resumed == 3 and o.quarantined == ()
          and list(o.next_seqs) == sorted(o.next_seqs), "3 resumes, (), non-decreasing",
          lambda o: o, runners=_STATE, state=kill9_at_random_points,
          see_also="tests/test_state_rotation.py::test_sigkill_at_random_points_loses_no_alert"),
    Fault("worker killed during a checkpoint", "process crash",
          "the worker SIGKILLed while the service writes the checkpoint it just sent",
          "worker restarts, estimates after, checkpoint whole",
          lambda o: o.restarts == 1 and o.estimates_after > 1 and o.quarantined == (),
          "1 restart, estimates resume, nothing set aside", lambda o: o, runners=_STATE,
          state=worker_killed_in_checkpoint,
          see_also="tests/test_service.py::test_worker_sigkill_resumes_from_checkpoint_within_2_s"),
    Fault("worker stopped", "process stall",
          "the worker SIGSTOPped until 1 s of samples beyond its queue (2 s here) is "
          "dropped, then SIGCONT",
          "samples_dropped, drop_runs, worker restarts; estimates resume",
          lambda o: o.dropped >= 1000 and o.drop_runs == 1 and o.restarts == 0
          and o.estimates_after > 5,
          ">= 1000 dropped in 1 run, no restart, > 5 estimates after", lambda o: o,
          runners=_STATE, state=worker_stopped,
          see_also="tests/test_worker_process.py::"
                   "test_a_worker_behind_its_queue_loses_one_run_of_samples_not_a_block_between_gaps"),
]


def _rows(runner: str) -> list[Any]:
    return [pytest.param(r, id=r.name.replace(" ", "-"), marks=[pytest.mark.xfail(
                strict=True, reason=r.live_defect)] if runner == "live" and r.live_defect
            else []) for r in FAULTS if runner in r.runners]


def test_the_table_is_whole():
    """Every fault the issue names is a row, every row has a runner and a threat."""
    names = {r.name for r in FAULTS}
    assert {"timestamp glitch", "receive clock step back", "duplicate sender",
            "SampleIdx jump", "full disk", "alert history unreadable",
            "kill -9 at random points", "worker killed during a checkpoint"} <= names
    threats = {"repetition", "deletion", "insertion", "resequencing", "corruption", "delay",
               "masquerade"}
    assert threats <= {r.threat for r in FAULTS}
    for r in FAULTS:
        assert r.runners and (r.inject is not None) != (r.state is not None), r.name
    text = (Path(__file__).parent.parent / "docs" / "reliability.md").read_text()
    assert all(r.name in text for r in FAULTS), [r.name for r in FAULTS if r.name not in text]


@pytest.mark.parametrize("row", _rows("replay"))
def test_replay(row: Fault, tmp_path: Path) -> None:
    assert row.inject is not None
    fe = _replay(row.inject(traffic(row.sim)), tmp_path / "fault.log")
    _check(row, row.measure(fe))
    assert fe.gating["updated"] >= row.min_updates * fe.grid_points, fe.gating


@pytest.mark.parametrize("row", _rows("live"))
def test_live(row: Fault, tmp_path: Path) -> None:
    assert row.inject is not None
    frames = row.inject(traffic(row.sim))
    with Running(tmp_path, "fault", particles=PARTICLES) as run:
        _play(run, frames)
        svc = run.service
        assert svc.pipeline is not None
        # everything sent is through the validator; then two more health frames
        assert _wait(lambda: svc.pipeline.front.stats().frames >= len(frames), 10)
        h0 = len(run.decoded("GW_HealthFlags"))
        assert _wait(lambda: len(run.decoded("GW_HealthFlags")) >= h0 + 2, 10)
        fe = svc.pipeline.front.stats()
        flags = _flags_max(run)
        if row.status is not None:
            message, want = row.status
            said = [d[f"{message}_Status"] for d in run.decoded(message)]
            updated = [v for v in said if v != 3]   # 3 PredictOnly: after the traffic
            assert updated and updated[-1] == want, (message, said)
    _check(row, row.measure(fe))
    assert fe.gating["updated"] >= row.min_updates * 0.9 * DURATION_S * 1000, fe.gating
    if row.flag is not None:
        assert row.flag_expect is not None and row.flag in flags, flags
        assert row.flag_expect(flags[row.flag]), (row.flag, flags)


@pytest.mark.parametrize("row", _rows("state"))
def test_state(row: Fault, tmp_path: Path) -> None:
    assert row.state is not None
    _check(row, row.measure(row.state(tmp_path)))

