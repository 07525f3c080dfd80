"""Tests of the bounded logs: rotation, retention, backwards tail reads, kill -9 in rotation."""

from __future__ import annotations

import collections
import contextlib
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from gateway.errors import StateError
from gateway.records import Alert, AlertState, Severity
from gateway.sinks.store import ALERTS, AUDIT, LogBounds, StateStore, files

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

CHILD = textwrap.dedent("""
    import os, signal, sys
    from gateway.records import Alert, AlertState, Severity
    from gateway.sinks.store import ALERTS, LogBounds, StateStore, segments

    state_dir, crash_at = sys.argv[1], sys.argv[2]
    if crash_at != "none":          # SIGKILL ourselves at one step of the 2nd rotation
        real_replace, real_fsync_dir = segments.os.replace, segments.fsync_dir
        calls = []
        def die():
            calls.append(1)
            if len(calls) == 2:
                os.kill(os.getpid(), signal.SIGKILL)
        def replace(src, dst):
            if crash_at == "before_rename":
                die()
            real_replace(src, dst)
            if crash_at == "after_rename":
                die()
        def fsync_dir(path):
            real_fsync_dir(path)
            if crash_at == "after_dir_fsync":
                die()
        segments.os.replace, segments.fsync_dir = replace, fsync_dir
    st = StateStore(state_dir, bounds={ALERTS: LogBounds(512, 10000)})
    tail = st.read_alerts(last=1)
    seq = tail[-1].alert.seq + 1 if tail else 1
    while True:
        a = Alert(seq, float(seq), "csy_ns_per_m", Severity.WARNING, AlertState.RAISED,
                  0x12, 0.5, "x" * (seq % 40))
        if not st.append_alert(a):
            sys.exit(3)
        os.write(1, b"%d\\n" % seq)                # acknowledged: append returned
        seq += 1
""")


def alert(seq: int, message: str = "m") -> Alert:
    return Alert(seq, float(seq), "csy_ns_per_m", Severity.WARNING, AlertState.RAISED, 0x12,
                 0.45, message)


def _alert_bytes(d: Path) -> int:
    total = 0
    for e in os.scandir(d):
        if e.name.startswith("alerts"):
            with contextlib.suppress(FileNotFoundError):  # renamed by a rotation meanwhile
                total += e.stat().st_size
    return total


def _run_child(d: Path, crash_at: str, kill_at_bytes: int | None) -> list[int]:
    """Run the appending child until it dies (by itself, or killed once the alert files
    reach ``kill_at_bytes``); returns the seqs it acknowledged."""
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(d), crash_at],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    if kill_at_bytes is not None:
        while _alert_bytes(d) < kill_at_bytes and proc.poll() is None:
            assert time.monotonic() < deadline, "child made no progress"
        proc.send_signal(signal.SIGKILL)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, err.decode()
    return [int(x) for x in out.split()]


def _check_history(d: Path, acked: list[int]) -> list[int]:
    with StateStore(d, bounds={ALERTS: LogBounds(512, 10000)}) as st:
        seqs = [e.alert.seq for e in st.read_alerts()]
        assert st.problems == []
        assert [e.alert.seq for e in st.read_alerts(last=5)] == seqs[-5:]
    counts = collections.Counter(seqs)
    assert all(counts[s] == 1 for s in acked), "an acknowledged alert is missing or doubled"
    assert all(b > a for a, b in zip(seqs, seqs[1:], strict=False)), "seqs not increasing"
    return seqs


@pytest.mark.parametrize("crash_at", ["before_rename", "after_rename", "after_dir_fsync"])
def test_sigkill_at_each_rotation_step_loses_no_alert(tmp_path, crash_at):
    acked: list[int] = []
    for _ in range(3):                                  # crash, restart, crash again ...
        acked += _run_child(tmp_path, crash_at, None)
    seqs = _check_history(tmp_path, acked)
    assert len(acked) >= 6 and seqs[-1] >= acked[-1]
    assert len(list(tmp_path.glob("alerts.*.jsonl"))) >= 2       # it did rotate


def test_sigkill_at_random_points_loses_no_alert(tmp_path):
    rng = random.Random(20240611)
    acked: list[int] = []
    for _ in range(8):
        target = _alert_bytes(tmp_path) + rng.randint(200, 4000)
        acked += _run_child(tmp_path, "none", target)
    seqs = _check_history(tmp_path, acked)
    assert len(acked) > 50 and len(seqs) >= len(acked)
    segments = list(tmp_path.glob("alerts.*.jsonl"))
    assert len(segments) > 10 and all(p.stat().st_size <= 512 for p in segments)


def test_retention_bounds_every_log_and_tail_read(tmp_path):
    bounds = {ALERTS: LogBounds(1024, 3), AUDIT: LogBounds(512, 2)}
    with StateStore(tmp_path, bounds=bounds) as st:
        for i in range(1, 301):
            assert st.append_alert(alert(i))
            assert st.append_audit(f"ack {i}", ok=True)
        alert_files = st.log_paths(ALERTS)
        assert len(alert_files) == 4 and sum(p.stat().st_size for p in alert_files) <= 4096
        assert [p.name for p in alert_files][-1] == ALERTS
        assert sum(p.stat().st_size for p in st.log_paths(AUDIT)) <= 3 * 512
        kept = [e.alert.seq for e in st.read_alerts()]
        assert kept == list(range(kept[0], 301)) and kept[0] > 250
        assert [e.alert.seq for e in st.read_alerts(last=3)] == [298, 299, 300]
        since = [e.alert.seq for e in st.read_alerts(last=2, since_seq=290)]
        assert since == list(range(290, 301))
        assert st.read_audit(last=1)[0].command == "ack 300"


def test_tail_read_does_not_read_the_whole_history(tmp_path, monkeypatch):
    with StateStore(tmp_path, bounds={ALERTS: LogBounds(1 << 20, 2)}) as st:
        st.append_alerts([alert(i, "y" * 100) for i in range(1, 5001)])   # ~1 MB, one file
    read: list[int] = []
    real_pread = os.pread

    def pread(fd: int, n: int, offset: int) -> bytes:
        read.append(n)
        return real_pread(fd, n, offset)

    monkeypatch.setattr(files.os, "pread", pread)
    with StateStore(tmp_path) as st:
        got = [e.alert.seq for e in st.read_alerts(last=50)]
    assert got == list(range(4951, 5001))
    assert sum(read) <= 2 * files.TAIL_BYTES < (tmp_path / ALERTS).stat().st_size


def test_backwards_reader_handles_block_edges_and_torn_tail(tmp_path):
    path = tmp_path / "x.jsonl"
    lines = [files.dumps_line({"i": i, "pad": "z" * (i % 37)}) for i in range(200)]
    path.write_bytes(b"".join(lines) + b'{"torn": ')
    for block in (7, 64, 1000, 1 << 20):
        got = [obj["i"] for _, obj in files.read_jsonl_backwards(path, block)]
        assert got == list(range(199, -1, -1))
    path.write_bytes(b"".join(lines[:3]) + b"garbage\n" + b"".join(lines[3:6]))
    with pytest.raises(StateError, match=r"x.jsonl: expected a JSON object per line.*at byte"):
        list(files.read_jsonl_backwards(path, 16))


def test_bad_segment_is_set_aside_alone(tmp_path):
    with StateStore(tmp_path, bounds={ALERTS: LogBounds(512, 100)}) as st:
        for i in range(1, 30):
            st.append_alert(alert(i))
    segs = sorted(tmp_path.glob("alerts.*.jsonl"), key=lambda p: int(p.name.split(".")[1]))
    segs[1].write_bytes(b"not json\n" + segs[1].read_bytes())
    with StateStore(tmp_path, bounds={ALERTS: LogBounds(512, 100)},
                    on_corrupt="quarantine") as st:
        seqs = [e.alert.seq for e in st.read_alerts()]
        assert st.quarantined == (segs[1].name,)
        assert seqs[-1] == 29 and len(seqs) < 29 and (tmp_path / f"{segs[1].name}.corrupt-1"
                                                      ).exists()
