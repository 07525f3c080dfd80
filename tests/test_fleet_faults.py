"""Fleet replay fault tolerance: a Dask worker killed mid-run, and an interrupted replay resumed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

from firmware_sim.fleet import FleetSpec, simulate_fleet  # noqa: E402
from gateway.config import Config, with_overrides  # noqa: E402
from gateway.fleet.replay import ReplayReport, dask_client, replay_store, result_path  # noqa: E402
from gateway.fleet.runs import estimator_version  # noqa: E402
from gateway.fleet.store import Store  # noqa: E402

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

SPEC = FleetSpec(vehicles=2, days=2, runs_per_day=1, run_s=5.0, seed=7)
CFG = with_overrides(Config(), {"estimator.particles": 100})


def wait_for(cond: object, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)           # polling a condition with a deadline, not synchronising


def attempts_by_run(d: Path) -> dict[str, int]:
    out: dict[str, int] = {}
    for p in d.iterdir():
        out[p.name.split(".")[0]] = out.get(p.name.split(".")[0], 0) + 1
    return out


@pytest.fixture()
def store(tmp_path: Path) -> Store:
    simulate_fleet(SPEC, tmp_path / "sim")
    s = Store(tmp_path / "store")
    assert len(s.ingest([tmp_path / "sim" / "logs"], CFG).added) == 4
    return s


def check_results(store: Store) -> None:
    import pyarrow.parquet as pq

    version = estimator_version(CFG)
    runs = store.runs()
    files = list((store.root / "results").rglob("*.parquet"))
    assert len(files) == len(runs)
    for r in runs:
        assert pq.read_table(result_path(store.root.resolve(), version, r)).num_rows >= 10
    assert not list(store.root.rglob("*.tmp"))


def test_worker_killed_mid_run_is_retried_nothing_lost_or_doubled(store: Store,
                                                                  tmp_path: Path) -> None:
    attempts = tmp_path / "attempts"
    attempts.mkdir()
    result: list[ReplayReport] = []
    errors: list[BaseException] = []
    with dask_client(workers=2) as client:
        def run() -> None:
            try:
                result.append(replay_store(store, CFG, client, attempts_dir=str(attempts),
                                           progress=False))
            except BaseException as err:  # noqa: BLE001 - reported below
                errors.append(err)

        th = threading.Thread(target=run)
        th.start()
        wait_for(lambda: any(attempts.iterdir()), 120, "a task to start")
        first = sorted(attempts.iterdir(), key=lambda p: p.stat().st_mtime_ns)[0]
        victim_run = first.name.split(".")[0]
        pid = int(first.read_text())
        assert pid != os.getpid()
        os.kill(pid, signal.SIGKILL)          # the Dask worker process running the task
        th.join(timeout=600)
    assert not errors, errors
    assert result and result[0].ran == 4
    by_run = attempts_by_run(attempts)
    assert set(by_run) == {r.run_id for r in store.runs()}
    assert by_run[victim_run] >= 2            # the killed task ran again elsewhere
    check_results(store)


def test_interrupted_replay_resumes_without_redoing_finished_runs(store: Store,
                                                                  tmp_path: Path) -> None:
    attempts = tmp_path / "attempts"
    attempts.mkdir()
    cmd = [sys.executable, "-m", "gateway", "fleet", "replay", str(store.root), "--workers",
           "1", "--particles", "100", "--no-progress", "--attempts-dir", str(attempts)]
    # Ctrl-C as at a terminal: a shell starts background jobs with SIGINT ignored, and a
    # child inherits that (Python then installs no KeyboardInterrupt handler), so a test
    # run from a background job would otherwise send a signal the command never sees
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # one worker, one thread: the second task starts only once the first has written
        # its result, so interrupting then leaves 1 or 2 runs done and 2 or 3 to resume
        wait_for(lambda: len(list(attempts.iterdir())) >= 2, 300, "a second task to start")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    done = {p.name.removeprefix("run-").removesuffix(".parquet")
            for p in (store.root / "results").rglob("*.parquet")}
    assert 1 <= len(done) < 4, (done, proc.returncode, out[-300:], err[-500:])
    assert proc.returncode == 130, err[-500:]
    before = attempts_by_run(attempts)
    with dask_client(workers=2) as client:
        rep = replay_store(store, CFG, client, attempts_dir=str(attempts), progress=False)
    assert rep.done_before == len(done) and rep.ran == 4 - len(done)
    after = attempts_by_run(attempts)
    for run_id in done:                        # finished runs were not run again
        assert after[run_id] == before[run_id] == 1
    check_results(store)
