"""Start-up that never loops: unusable state files are set aside; alert seqs never repeat."""

from __future__ import annotations

import errno
import json
import os
import subprocess
from pathlib import Path

import pytest

from gateway.config import Config, with_overrides
from gateway.model.vehicle import THETA_NOMINAL
from gateway.records import Estimate
from gateway.service.daemon import Service
from gateway.sinks.state import restore_policy
from gateway.sinks.store import ALERTS, AUDIT, BASELINES, ESTIMATES, POLICY, StateStore, files

NESTED = b"[" * 100_000 + b"]" * 100_000
ALERT_LINE = json.dumps({"seq": 7, "t_s": 1.0, "wall_time_s": 1.0, "parameter": "csy_ns_per_m",
                         "severity": "WARNING", "state": "RAISED", "code": 0x12,
                         "value_rel": 0.5, "message": ""}) + "\n"


def _write(d: Path, name: str, data: bytes) -> None:
    (d / name).write_bytes(data)


CASES = {
    "policy of the wrong shape": (POLICY, lambda d: _write(d, POLICY,
                                                           b'{"version": 1, "next_seq": "x"}')),
    "policy nested too deep": (POLICY, lambda d: _write(d, POLICY, NESTED)),
    "alerts a directory": (ALERTS, lambda d: (d / ALERTS).mkdir()),
    "alerts a FIFO": (ALERTS, lambda d: os.mkfifo(d / ALERTS)),
    "alerts nested too deep": (ALERTS, lambda d: _write(d, ALERTS, b'{"a":' + NESTED + b"}\n"
                                                        + ALERT_LINE.encode())),
    "estimates corrupt": (ESTIMATES, lambda d: _write(d, ESTIMATES, b"\0garbage\n{}\n")),
    "baselines corrupt": (BASELINES, lambda d: _write(d, BASELINES, b"zzz\n{}\n")),
    "audit corrupt": (AUDIT, lambda d: _write(d, AUDIT, b'{"ok": "x"}\n{}\n')),
}


def _service(state_dir: Path) -> Service:
    cfg = with_overrides(Config(), {"bus.interface": "virtual", "bus.channel": "startup-test",
                                    "state.directory": str(state_dir)})
    return Service(cfg)


@pytest.mark.parametrize("case", sorted(CASES))
def test_service_starts_with_an_unusable_file_set_aside(tmp_path, case, caplog):
    name, damage = CASES[case]
    (tmp_path / ALERTS).write_text(ALERT_LINE) if name != ALERTS else None
    damage(tmp_path)
    svc = _service(tmp_path)                            # constructing did not raise
    try:
        assert svc.store.quarantined == (name,)
        assert (tmp_path / f"{name}.corrupt-1").exists() and name in svc.store.problems[0]
        assert f"{name} set aside" in caplog.text       # the journal line
        assert svc.policy.next_seq >= (8 if name != ALERTS else 1)
        assert svc.store.append_alerts([]) and svc.store.append_audit("x", ok=True)
    finally:
        svc.store.close()


def test_unreadable_alerts_file(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root reads a chmod 000 file: the directory and FIFO cases cover it")
    (tmp_path / ALERTS).write_text(ALERT_LINE)
    os.chmod(tmp_path / ALERTS, 0)
    with StateStore(tmp_path, on_corrupt="quarantine") as st:
        policy, _ = restore_policy(st)
        assert st.quarantined == (ALERTS,) and policy.next_seq == 1


def test_history_event_that_cannot_be_replayed_is_skipped(tmp_path):
    bad = ALERT_LINE.replace('"code": 18', '"code": 153')
    (tmp_path / ALERTS).write_text(ALERT_LINE.replace('"seq": 7', '"seq": 6') + bad)
    with StateStore(tmp_path, on_corrupt="quarantine") as st:
        policy, recent = restore_policy(st)
        assert [a.seq for a in recent] == [6, 7] and policy.next_seq == 8
        assert len(policy.active) == 1 and "seq 7 skipped" in st.problems[0]


def _estimate(t_s: float, csy_rel: float) -> Estimate:
    nom = THETA_NOMINAL.as_array()
    return Estimate(t_s, (float(nom[0]) * csy_rel, float(nom[1]), float(nom[2])),
                    tuple(0.01 * float(n) for n in nom), ess=400.0)


def _run(state_dir: Path, t0: float, cycles: int) -> list[int]:
    """Start as the service does, raise and clear an alarm ``cycles`` times, persisting
    each event as the service does; returns the seqs that went out (on CAN)."""
    out: list[int] = []
    with StateStore(state_dir, on_corrupt="quarantine") as st:
        policy, _ = restore_policy(st)
        t = t0
        for _ in range(cycles):
            for rel, n in ((0.3, 50), (1.0, 70)):
                for _ in range(n):
                    t += 0.1
                    for a in policy.step(_estimate(t, rel)):
                        out.append(a.seq)
                        st.append_alert(a)
                        st.save_policy(policy.snapshot())
    return out


def _assert_never_repeat(runs: list[list[int]]) -> None:
    seqs = [s for run in runs for s in run]
    assert len(seqs) == len(set(seqs)) and seqs == sorted(seqs), runs


def test_seq_unique_across_restarts_on_a_real_full_disk(tmp_path, caplog):
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,mode=700", "tmpfs",
                              str(mnt)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {mounted.stderr.decode().strip()}")
    try:
        state = mnt / "state"
        runs = [_run(state, 0.0, 1)]                   # persisted normally
        fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            while True:
                os.write(fd, b"\0" * 1024)
        except OSError as err:
            assert err.errno == errno.ENOSPC
        finally:
            os.close(fd)
        runs += [_run(state, 100.0, 2), _run(state, 200.0, 2)]    # disk full: not persisted
        assert "cannot write alert_policy.json" in caplog.text      # the snapshot failed
        (mnt / "filler").unlink()
        runs.append(_run(state, 300.0, 1))
        _assert_never_repeat(runs)
        assert all(len(r) == 2 * c for r, c in zip(runs, (1, 2, 2, 1), strict=True))
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_seq_unique_across_restarts_when_appends_fail(tmp_path, monkeypatch):
    """The same without a tmpfs: every ``os.write`` fails with ENOSPC (appends and atomic
    replaces), while an in-place overwrite of blocks the ledger owns still works."""
    runs = [_run(tmp_path, 0.0, 1)]
    real_write = os.write

    def write(fd: int, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(files.os, "write", write)
    runs += [_run(tmp_path, 100.0, 2), _run(tmp_path, 200.0, 1)]
    monkeypatch.setattr(files.os, "write", real_write)
    runs.append(_run(tmp_path, 300.0, 1))
    _assert_never_repeat(runs)
    with StateStore(tmp_path) as st:
        assert [e.alert.seq for e in st.read_alerts()] == runs[0] + runs[3]


def test_lost_ledger_skips_a_block(tmp_path):
    first = _run(tmp_path, 0.0, 1)
    (tmp_path / "alert_seq.bin").write_bytes(b"\0" * 1024)          # both slots bad
    (tmp_path / ALERTS).unlink()                                    # and no history
    (tmp_path / POLICY).unlink()
    second = _run(tmp_path, 100.0, 1)
    _assert_never_repeat([first, second])
