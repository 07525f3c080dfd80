"""Tests of gateway.sinks.store: atomic files, JSONL durability, crashes, full disk, restart."""

from __future__ import annotations

import errno
import json
import math
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from gateway.alerts.policy import AlertPolicy
from gateway.errors import StateError
from gateway.model.vehicle import THETA_NOMINAL
from gateway.records import Alert, AlertState, Estimate, Severity
from gateway.sinks.store import (
    ALERTS,
    CHECKPOINT,
    ESTIMATES,
    ESTIMATES_PREVIOUS,
    POLICY,
    StateStore,
    files,
)


class FakeClock:
    def __init__(self, t: float = 1.7e9) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def alert(seq: int, state: AlertState = AlertState.RAISED) -> Alert:
    return Alert(seq, float(seq), "csy_ns_per_m", Severity.WARNING, state, 0x12, 0.45, "m")


def est(t_s: float, csy_rel: float = 1.0) -> Estimate:
    nom = THETA_NOMINAL.as_array()
    mean = (nom[0] * csy_rel, nom[1], nom[2])
    return Estimate(t_s, tuple(float(m) for m in mean),
                    tuple(0.02 * float(n) for n in nom), ess=400.0)


def test_checkpoint_round_trip_and_latest_only(tmp_path):
    clock = FakeClock()
    with StateStore(tmp_path, clock=clock) as st:
        assert st.load_checkpoint() is None
        assert st.save_checkpoint(b"first", t_s=1.0, version="rbpf-1")
        clock.t += 5
        assert st.save_checkpoint(b"\x00second" * 1000, t_s=2.5, version="rbpf-1")
        ck = st.load_checkpoint()
    assert ck is not None
    assert (ck.blob, ck.t_s, ck.wall_time_s, ck.version) == (
        b"\x00second" * 1000, 2.5, clock.t, "rbpf-1")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", CHECKPOINT]


@pytest.mark.parametrize("damage", ["truncate", "flip", "magic", "empty"])
def test_corrupt_checkpoint_is_set_aside_and_estimator_starts_fresh(tmp_path, damage):
    with StateStore(tmp_path) as st:
        st.save_checkpoint(bytes(range(256)) * 10, t_s=1.0, version="v")
    path = tmp_path / CHECKPOINT
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[:-100]
    elif damage == "flip":
        data[-7] ^= 0x40
    elif damage == "magic":
        data[:8] = b"NOTACKPT"
    else:
        data = bytearray()
    path.write_bytes(bytes(data))
    with StateStore(tmp_path) as st:
        assert st.load_checkpoint() is None
        assert len(st.problems) == 1 and "expected" in st.problems[0]
        assert (tmp_path / f"{CHECKPOINT}.corrupt-1").exists() and not path.exists()
        assert st.save_checkpoint(b"fresh", t_s=0.0, version="v")
        assert st.load_checkpoint().blob == b"fresh"


CRASH_CHILD = textwrap.dedent("""
    import os, sys
    from gateway.records import Alert, AlertState, Severity
    from gateway.sinks.store import StateStore
    state_dir, target, arm_at = sys.argv[1], sys.argv[2], int(sys.argv[3])
    real_write, armed = os.write, False

    def write(fd, data):
        # once armed, the first write to the target file writes half, then waits to die
        if armed and target in os.readlink(f"/proc/self/fd/{fd}"):
            real_write(fd, bytes(data[:len(data) // 2]))
            print("mid", flush=True)
            sys.stdin.read()
        return real_write(fd, data)

    os.write = write
    st = StateStore(state_dir)
    for i in range(1, 100000):
        armed = i >= arm_at
        st.save_checkpoint(bytes([i % 256]) * 300000 + i.to_bytes(4, "little"), float(i), "v")
        st.append_alerts([Alert(i, float(i), "csy_ns_per_m", Severity.ALARM,
                                AlertState.RAISED, 0x13, 0.2, "x" * 50)])
        print(i, flush=True)
""")


@pytest.mark.parametrize("target", ["checkpoint", "alerts", "nothing"])
def test_sigkill_mid_write_leaves_previous_valid_files(tmp_path, target):
    """SIGKILL a writer half-way through a checkpoint write or an alert append (or at a
    free-running moment): the previous checkpoint and every complete alert survive."""
    child = subprocess.Popen([sys.executable, "-c", CRASH_CHILD, str(tmp_path), target, "8"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    done, line = 0, ""
    while line != "mid" and done < 15:     # synchronise on the child's output, not on time
        line = child.stdout.readline().strip()
        done = int(line) if line.isdigit() else done
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=30)
    for stream in (child.stdin, child.stdout):
        assert stream is not None
        stream.close()
    if target == "checkpoint":                # killed with a half-written temp file
        assert line == "mid" and done == 7 and (tmp_path / ".checkpoint.bin.tmp").exists()
    if target == "alerts":                    # killed with half a line appended
        assert line == "mid" and done == 7
        assert not (tmp_path / ALERTS).read_bytes().endswith(b"\n")
    with StateStore(tmp_path) as st:
        ck = st.load_checkpoint()
        assert ck is not None and st.problems == []
        i = int.from_bytes(ck.blob[-4:], "little")
        assert i >= done and ck.blob == bytes([i % 256]) * 300000 + i.to_bytes(4, "little")
        assert ck.t_s == float(i)
        seqs = [e.alert.seq for e in st.read_alerts()]
        assert seqs == list(range(1, len(seqs) + 1)) and len(seqs) >= done
        assert st.append_alerts([alert(len(seqs) + 1)])
        assert [e.alert.seq for e in st.read_alerts()][-1] == len(seqs) + 1
    assert not list(tmp_path.glob(".*.tmp"))


def test_torn_last_line_tolerated_and_repaired(tmp_path):
    with StateStore(tmp_path) as st:
        st.append_alerts([alert(1), alert(2, AlertState.ACKNOWLEDGED)])
    with open(tmp_path / ALERTS, "ab") as f:
        f.write(b'{"seq":3,"t_s":3.0,"param')          # power cut mid-append
    with StateStore(tmp_path) as st:
        assert [e.alert for e in st.read_alerts()] == [alert(1), alert(2, AlertState.ACKNOWLEDGED)]
        assert st.append_alerts([alert(3)])
        assert [e.alert.seq for e in st.read_alerts()] == [1, 2, 3]
    lines = (tmp_path / ALERTS).read_bytes().split(b"\n")
    assert lines[-1] == b"" and all(json.loads(x) for x in lines[:-1])


def test_corrupt_middle_line_is_a_state_error_or_set_aside(tmp_path):
    with StateStore(tmp_path) as st:
        st.append_alerts([alert(1)])
    good = (tmp_path / ALERTS).read_bytes()
    with open(tmp_path / ALERTS, "ab") as f:
        f.write(b"garbage\n" + good)
    with StateStore(tmp_path) as st, pytest.raises(StateError, match=r"alerts.jsonl:2: exp"):
        st.read_alerts()
    with open(tmp_path / ALERTS, "ab") as f:
        f.write(b'{"seq": "one"}\n')
    with StateStore(tmp_path, on_corrupt="quarantine") as st:
        assert st.read_alerts() == []
        assert "alerts.jsonl:2: expected" in st.problems[0]
        assert (tmp_path / f"{ALERTS}.corrupt-1").exists()
        assert st.append_alerts([alert(7)]) and [e.alert.seq for e in st.read_alerts()] == [7]


def test_corrupt_policy_snapshot(tmp_path):
    (tmp_path / POLICY).write_text("{not json")
    with StateStore(tmp_path) as st, pytest.raises(StateError, match="expected a JSON object"):
        st.load_policy()
    with StateStore(tmp_path, on_corrupt="quarantine") as st:
        assert st.load_policy() is None and st.problems


def test_seq_and_active_alerts_persist_across_restarts(tmp_path):
    def feed(policy, store, t0, t1, rel):
        for k in range(t0 * 10, t1 * 10):
            events = policy.step(est(k / 10, rel))
            store.append_alerts(events)
            if events and k < 80:       # the second restart comes without a fresh snapshot
                store.save_policy(policy.snapshot())

    with StateStore(tmp_path) as st:
        p = AlertPolicy()
        feed(p, st, 0, 5, 0.45)                         # WARNING raised, seq 1
        st.append_alerts([p.acknowledge("csy_ns_per_m", 5.0)])
        st.save_policy(p.snapshot())
    with StateStore(tmp_path) as st:                    # restart 1
        p = AlertPolicy.restore(st.load_policy(), history=[e.alert for e in st.read_alerts()])
        assert [(a.seq, a.state) for a in p.active] == [(2, AlertState.ACKNOWLEDGED)]
        feed(p, st, 5, 10, 0.2)                         # ALARM raised, seq 3, snapshot saved
        feed(p, st, 10, 20, 1.0)                        # CLEARED, seq 4, no snapshot (SIGKILL)
    with StateStore(tmp_path) as st:                    # restart 2
        history = [e.alert for e in st.read_alerts()]
        p = AlertPolicy.restore(st.load_policy(), history=history)
        assert p.active == () and p.next_seq == 5
        assert [a.seq for a in history] == [1, 2, 3, 4]


def test_estimate_history_decimation_rotation_and_retention(tmp_path):
    clock = FakeClock()
    with StateStore(tmp_path, clock=clock, history_interval_s=10.0,
                    history_keep_s=100.0) as st:
        for k in range(0, 600):                         # 60 s at 10 Hz -> 6 points
            assert st.record_estimate(est(k / 10))
        got = st.read_estimates()
        assert [e.t_s for e in got] == [0.0, 10.0, 20.0, 30.0, 40.0, 50.0]
        assert got[0].names[0] == "csy_ns_per_m" and got[0].mean[0] == 40e3
        st.record_estimate(Estimate(1.0, (math.nan,), (math.inf,), 1.0, names=("ar",)))
        assert math.isnan(st.read_estimates()[-1].mean[0])   # data time went back: kept
        clock.t += 100.5                                # segment spans the keep time
        st.record_estimate(est(70.0))
        assert (tmp_path / ESTIMATES_PREVIOUS).exists()
        assert [e.t_s for e in st.read_estimates()] == [70.0]   # older than 100 s dropped
        assert st.read_estimates(since_wall_s=clock.t + 1) == []
        clock.t += 150.0
        st.record_estimate(est(80.0))
        assert [e.t_s for e in st.read_estimates()] == [80.0]
    size_limited = tmp_path / "sized"
    with StateStore(size_limited, history_interval_s=0.0, history_max_bytes=4000) as st:
        for k in range(200):
            st.record_estimate(est(float(k)))
        paths = st.log_paths(ESTIMATES)                 # 7 rotated segments + current
        assert len(paths) == 8 and not (size_limited / ESTIMATES_PREVIOUS).exists()
        assert all(p.stat().st_size <= 500 for p in paths)
        assert sum(p.stat().st_size for p in paths) <= 4000
        kept = [e.t_s for e in st.read_estimates()]     # the newest, contiguous
        assert kept == [float(k) for k in range(200 - len(kept), 200)] and len(kept) >= 8


def test_baselines_and_audit(tmp_path):
    clock = FakeClock(1000.0)
    with StateStore(tmp_path, clock=clock) as st:
        assert st.append_baseline("csy_ns_per_m", 12.5, note="damper replaced")
        for i in range(5):
            clock.t += 1
            st.append_audit(f"ack {i}", ok=i % 2 == 0, detail="by fitter", t_s=float(i))
    with StateStore(tmp_path, clock=clock) as st:
        (b,) = st.read_baselines()
        assert (b.parameter, b.t_s, b.wall_time_s, b.note) == (
            "csy_ns_per_m", 12.5, 1000.0, "damper replaced")
        audit = st.read_audit(last=2)
        assert [(a.command, a.ok, a.t_s, a.wall_time_s) for a in audit] == [
            ("ack 3", False, 3.0, 1004.0), ("ack 4", True, 4.0, 1005.0)]


def test_lock_close_and_leftovers(tmp_path):
    (tmp_path / f".{CHECKPOINT}{files.TMP_SUFFIX}").write_bytes(b"half")
    st = StateStore(tmp_path)
    assert not (tmp_path / f".{CHECKPOINT}{files.TMP_SUFFIX}").exists()
    with pytest.raises(StateError, match="locked by another process"):
        StateStore(tmp_path)
    st.close()
    st.close()
    assert st.append_audit("x", ok=True) is False
    with StateStore(tmp_path):
        pass
    (tmp_path / "file").write_text("")
    with pytest.raises(StateError, match="expected a writable state directory"):
        StateStore(tmp_path / "file")


@pytest.fixture()
def tiny_dir(tmp_path):
    """A 64 KiB tmpfs: a real full disk (needs root and mount permission)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,mode=700", "tmpfs",
                              str(mnt)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {mounted.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def _assert_survives_full_disk(st: StateStore, fill) -> None:
    assert st.save_checkpoint(b"a" * 8000, t_s=1.0, version="v")
    assert st.append_alerts([alert(1)])
    fill()
    assert st.save_checkpoint(b"b" * 60000, t_s=2.0, version="v") is False
    results = [st.append_alerts([alert(i)]) for i in range(2, 200)]
    assert results.count(False) > 0 and st.write_failures >= 2
    assert st.load_checkpoint().blob == b"a" * 8000        # previous checkpoint intact
    seqs = [e.alert.seq for e in st.read_alerts()]           # no half-written line
    assert seqs == list(range(1, len(seqs) + 1))


def test_full_disk_real_tmpfs(tiny_dir, caplog):
    filler = tiny_dir / "filler"
    with StateStore(tiny_dir / "state") as st:
        def fill() -> None:
            fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
            try:
                while True:
                    os.write(fd, b"\0" * 1024)
            except OSError as err:
                assert err.errno == errno.ENOSPC
            finally:
                os.close(fd)

        _assert_survives_full_disk(st, fill)
        assert "No space left on device" in caplog.text
        filler.unlink()                                      # space comes back
        assert st.save_checkpoint(b"c" * 8000, t_s=3.0, version="v")
        assert st.append_alerts([alert(999)]) and st.read_alerts()[-1].alert.seq == 999


def test_full_disk_simulated_enospc(tmp_path, monkeypatch):
    """The same guarantees where no tmpfs can be mounted: os.write fails with ENOSPC after
    writing part of the data (a short write, then the error)."""
    real_write = os.write
    full = {"on": False}

    def write(fd: int, data) -> int:
        if full["on"]:
            if len(data) > 8:
                return real_write(fd, bytes(data[:8]))
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)

    monkeypatch.setattr(files.os, "write", write)
    with StateStore(tmp_path) as st:
        _assert_survives_full_disk(st, lambda: full.update(on=True))
        full["on"] = False
        assert st.append_alerts([alert(999)])
    with StateStore(tmp_path) as st:
        assert st.read_alerts()[-1].alert.seq == 999
