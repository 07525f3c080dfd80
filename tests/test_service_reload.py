"""SIGHUP: each reloadable key takes effect on the running service; any other key logs
that it needs a restart and keeps its running value; a bad file changes nothing.

The reloadable keys are ``gateway.service.daemon.RELOADABLE`` ([output] estimate_rate_hz,
health_rate_hz). Effects are observed from outside: frame rates off the virtual bus
(a Service in a thread of this process, whose SIGHUP handler gets a real signal), and
the notify datagrams and the journal lines of a real ``python -m gateway run --config``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import open_bus, open_node_bus
from gateway.can.codec import default_codec
from gateway.config import load_config
from gateway.model.vehicle import PARAM_NAMES
from gateway.records import Estimate
from gateway.service.daemon import RELOADABLE, Service
from gateway.sinks.outputs import CanSink

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

ROOT = Path(__file__).resolve().parent.parent
HEALTH_ID = default_codec().message("GW_Health").frame_id
EST_CSY_ID = default_codec().message("GW_EstCsy").frame_id


def _wait(cond, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


def _toml(channel: str, state: Path, *, particles: int = 32, estimate_rate_hz: float = 10.0,
          health_rate_hz: float = 1.0, interface: str = "virtual") -> str:
    return (f'[bus]\ninterface = "{interface}"\nchannel = "{channel}"\n'
            f'[estimator]\nparticles = {particles}\ncheckpoint_interval_s = 60.0\n'
            f'[output]\nestimate_rate_hz = {estimate_rate_hz}\n'
            f'health_rate_hz = {health_rate_hz}\n'
            f'[state]\ndirectory = "{state}"\n')


def test_the_reloadable_keys_are_the_output_section():
    """What the docs (README, docs/alerts.md, the example TOML) promise; a new
    reloadable key needs its own test below."""
    assert set(RELOADABLE) == {("output", "estimate_rate_hz"), ("output", "health_rate_hz")}


# ------------------------------------------------------------ the CAN sink's rate limit
def _estimates(t0_s: float, n: int, rate_hz: float) -> list[Estimate]:
    mean = np.array([40e3, 4.114e6, 0.15])
    return [Estimate(t0_s + k / rate_hz, mean, 0.01 * mean, 500.0, True) for k in range(n)]


@pytest.mark.parametrize("t0_s", [0.0, 1.7e9])
def test_the_can_sink_sends_estimate_rate_hz_sets_per_data_second(t0_s):
    """10 Hz of estimates over 10 s of data time: 2 Hz -> every 5th set (20 sets of 3
    frames), 3 Hz -> 30 sets, 10 Hz -> all 100 (data times on the grid, epoch-sized or
    not), none -> all."""
    for rate_hz, sets in ((2.0, 20), (10.0, 100), (None, 100), (3.0, 30)):
        sent: list[can.Message] = []
        sink = CanSink(default_codec(), lambda m, out=sent: out.append(m) or True, 500,
                       estimate_rate_hz=rate_hz)
        for est in _estimates(t0_s, 100, 10.0):
            sink.emit_estimate(est)
        assert len(sent) == 3 * sets, (rate_hz, len(sent))
        assert sink.estimates_skipped == 100 - sets


def test_the_can_sink_counts_from_the_last_set_sent_and_restarts_on_a_new_run():
    sent: list[can.Message] = []
    sink = CanSink(default_codec(), lambda m: sent.append(m) or True, 500,
                   estimate_rate_hz=1.0)
    for est in _estimates(100.0, 20, 10.0):          # 100.0 .. 101.9 s: 100.0 and 101.0
        sink.emit_estimate(est)
    assert len(sent) == 2 * len(PARAM_NAMES)
    sink.set_estimate_rate(10.0)                    # a reload: every later estimate
    for est in _estimates(102.0, 5, 10.0):
        sink.emit_estimate(est)
    assert len(sent) == 7 * len(PARAM_NAMES)
    for est in _estimates(5.0, 1, 10.0):            # data time ran backwards: sent
        sink.emit_estimate(est)
    assert len(sent) == 8 * len(PARAM_NAMES)


# ------------------------------------------------- a Service in a thread, a real SIGHUP
class Reloading:
    """A Service from a config file on a virtual channel, run in a thread; its SIGHUP
    handler is installed in this (the main) thread, so ``hup()`` is a real signal."""

    def __init__(self, tmp_path: Path, **keys: float) -> None:
        self.channel = f"reload-{time.monotonic_ns()}"
        self.state = tmp_path / "state"
        self.path = tmp_path / "railgw.toml"
        self.path.write_text(_toml(self.channel, self.state, **keys))
        self.service = Service(load_config(self.path), config_path=str(self.path))
        self.frames: list[tuple[float, int]] = []   # (monotonic receive time, id)
        self._rx = open_bus(f"virtual:{self.channel}")
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self.service.run, daemon=True),
                         threading.Thread(target=self._record, daemon=True)]

    def _record(self) -> None:
        while not self._stop.is_set():
            msg = self._rx.recv(0.1)
            if msg is not None and msg.arbitration_id >= 0x300:
                self.frames.append((time.monotonic(), msg.arbitration_id))

    def __enter__(self) -> Reloading:
        self.service.install_signal_handlers()
        for t in self._threads:
            t.start()
        assert _wait(lambda: self.service.pipeline is not None
                     and self.service.pipeline.worker.stats.ready, 180)
        return self

    def __exit__(self, *exc: object) -> None:
        self.service.flags.stop = True
        self._threads[0].join(timeout=10)
        self._stop.set()
        self._threads[1].join(timeout=2)
        self._rx.shutdown()
        self.service._restore_signal_handlers()

    def play(self, scenario: str, duration_s: float) -> threading.Thread:
        sim = Simulation(get_scenario(scenario), SimConfig(duration_s=duration_s, seed=5))

        def go() -> None:
            with open_node_bus(f"virtual:{self.channel}") as tx:
                send_live(sim.messages(), tx, stop=self._stop.is_set)

        t = threading.Thread(target=go, daemon=True)
        t.start()
        return t

    def hup(self, **keys: float) -> float:
        """Rewrite the file with ``keys`` and send SIGHUP; returns the monotonic time."""
        self.path.write_text(_toml(self.channel, self.state, **keys))
        t = time.monotonic()
        os.kill(os.getpid(), signal.SIGHUP)
        return t

    def count(self, frame_id: int, since: float, window_s: float) -> int:
        return sum(1 for t, i in list(self.frames) if i == frame_id and since <= t < since
                   + window_s)

    def window_after(self, frame_id: int, since: float, window_s: float) -> int | None:
        """Frames of ``frame_id`` in the latest complete ``window_s`` after ``since``
        (None until that long has passed)."""
        now = time.monotonic()
        if now - since < window_s:
            return None
        return self.count(frame_id, now - window_s, window_s)


def test_sighup_applies_a_new_health_rate_hz(tmp_path):
    """[output] health_rate_hz 1 -> 5 Hz: the GW_Health frames off the bus follow."""
    with Reloading(tmp_path, health_rate_hz=1.0) as run:
        t0 = time.monotonic()
        assert _wait(lambda: time.monotonic() - t0 >= 4.0, 10)
        before = run.count(HEALTH_ID, t0, 4.0)
        assert 2 <= before <= 6, before                      # ~1 Hz
        t_hup = run.hup(health_rate_hz=5.0)
        assert _wait(lambda: (run.window_after(HEALTH_ID, t_hup, 2.0) or 0) >= 8, 15), \
            run.window_after(HEALTH_ID, t_hup, 2.0)          # ~5 Hz: 10 in 2 s
        assert run.service.cfg.output.health_rate_hz == 5.0


def test_sighup_applies_a_new_estimate_rate_hz(tmp_path):
    """[output] estimate_rate_hz 10 -> 1 Hz (data time): GW_EstCsy frames off the bus go
    from ~10 to ~1 per second of (live, real-time) data while estimates keep coming."""
    with Reloading(tmp_path, estimate_rate_hz=10.0) as run:
        sender = run.play("nominal", 60.0)
        assert _wait(lambda: run.count(EST_CSY_ID, 0.0, 1e12) >= 1, 60)
        t0 = time.monotonic()
        assert _wait(lambda: time.monotonic() - t0 >= 4.0, 10)
        before = run.count(EST_CSY_ID, t0, 4.0)
        assert before >= 20, before                          # ~40 at 10 Hz
        t_hup = run.hup(estimate_rate_hz=1.0)

        def slow() -> bool:
            n = run.window_after(EST_CSY_ID, t_hup + 1.0, 4.0)
            return n is not None and 1 <= n <= 7              # ~4 at 1 Hz
        assert _wait(slow, 20), run.window_after(EST_CSY_ID, t_hup + 1.0, 4.0)
        assert run.service.cfg.output.estimate_rate_hz == 1.0
        assert run.service.can_sink.estimates_skipped > 0
        run._stop.set()
        sender.join(timeout=5)


def test_sighup_with_a_key_that_needs_a_restart_logs_it_and_keeps_running_values(
        tmp_path, caplog):
    """[estimator] particles changed: logged as needing a restart, the running value
    stays (the console's ``config`` shows it); an estimate rate above the running
    [estimator] output_rate_hz is refused whole; a broken file changes nothing."""
    caplog.set_level(logging.INFO, logger="gateway.service.daemon")
    with Reloading(tmp_path, particles=32, health_rate_hz=1.0) as run:
        svc = run.service
        run.hup(particles=64, health_rate_hz=2.0)
        assert _wait(lambda: "needs a restart" in caplog.text, 10), caplog.text
        assert _wait(lambda: svc.cfg.output.health_rate_hz == 2.0, 5)
        assert "[estimator] particles = 64" in caplog.text
        assert svc.cfg.estimator.particles == 32
        assert "particles = 32" in svc.view.config_text()
        assert "health_rate_hz = 2.0" in svc.view.config_text()

        caplog.clear()
        run.path.write_text(_toml(run.channel, run.state, health_rate_hz=4.0).replace(
            "[estimator]\n", "[estimator]\noutput_rate_hz = 50.0\n").replace(
            "estimate_rate_hz = 10.0", "estimate_rate_hz = 20.0"))
        os.kill(os.getpid(), signal.SIGHUP)
        assert _wait(lambda: "reload failed" in caplog.text, 10), caplog.text
        assert "expected at most [estimator] output_rate_hz (10), got 20.0" in caplog.text
        assert svc.cfg.output.health_rate_hz == 2.0             # nothing applied
        assert svc.cfg.output.estimate_rate_hz == 10.0

        caplog.clear()
        run.path.write_text("[output]\nhealth_rate_hz = 'fast'\n")
        os.kill(os.getpid(), signal.SIGHUP)
        assert _wait(lambda: "reload failed" in caplog.text, 10), caplog.text
        assert "health_rate_hz: expected float" in caplog.text
        assert svc.cfg.output.health_rate_hz == 2.0


# --------------------------------------- the real daemon: python -m gateway run --config
class Daemon:
    """``python -m gateway run --config F`` with our NOTIFY_SOCKET; a reader thread keeps
    every datagram (the socket's queue holds only a few) with its arrival time."""

    def __init__(self, tmp_path: Path) -> None:
        self.path = tmp_path / "railgw.toml"
        self.channel = f"daemon-{os.getpid()}"
        self.state = tmp_path / "state"
        # --bus overrides the file's socketcan: an override is no reload change
        self.path.write_text(_toml("can0", self.state, interface="socketcan"))
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind(str(tmp_path / "notify"))
        self._sock.settimeout(0.2)
        self.got: list[tuple[float, dict[str, str]]] = []
        self.stderr_path = tmp_path / "stderr.log"
        self._stderr = self.stderr_path.open("w")
        self._done = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "gateway", "run", "--config", str(self.path),
             "--bus", f"virtual:{self.channel}"],
            cwd=ROOT, env=dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify")),
            stdout=subprocess.DEVNULL, stderr=self._stderr, start_new_session=True)

    def _read(self) -> None:
        while not self._done.is_set():
            try:
                text = self._sock.recv(4096).decode()
            except TimeoutError:
                continue
            except OSError:
                return
            self.got.append((time.monotonic(),
                             dict(line.split("=", 1) for line in text.splitlines())))

    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def has(self, key: str, value: str | None = None) -> bool:
        return any(key in m and (value is None or m[key] == value) for _, m in self.got)

    def watchdogs(self, since: float, window_s: float) -> int:
        return sum(1 for t, m in list(self.got) if "WATCHDOG" in m and since <= t < since
                   + window_s)

    def close(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)
        self._done.set()
        self._reader.join(timeout=2)
        self._sock.close()
        self._stderr.close()


def test_the_daemon_reloads_health_rate_hz_on_sighup_and_logs_what_needs_a_restart(
        tmp_path):
    """A real daemon and a real SIGHUP: RELOADING=1 (with MONOTONIC_USEC) then READY=1;
    WATCHDOG=1, sent at each health tick, goes from ~1 to ~10 a second; the journal names
    the applied key and the one that needs a restart; the --bus override is not taken
    for a change."""
    run = Daemon(tmp_path)
    try:
        assert _wait(lambda: run.has("READY", "1") or run.proc.poll() is not None, 180)
        assert run.has("READY", "1"), run.stderr()
        t0 = time.monotonic()
        assert _wait(lambda: time.monotonic() - t0 >= 4.0, 10)
        assert 2 <= run.watchdogs(t0, 4.0) <= 6, run.watchdogs(t0, 4.0)
        run.path.write_text(_toml("can0", run.state, interface="socketcan",
                                  health_rate_hz=10.0, particles=64))
        t_hup = time.monotonic()
        os.kill(run.proc.pid, signal.SIGHUP)
        assert _wait(lambda: any(m.get("STATUS") == "configuration reloaded"
                                 for _, m in run.got), 15), run.stderr()
        reloading = [m for _, m in run.got if m.get("RELOADING") == "1"]
        assert reloading and int(reloading[0]["MONOTONIC_USEC"]) > 0
        assert _wait(lambda: run.watchdogs(time.monotonic() - 2.0, 2.0) >= 12
                     and time.monotonic() - t_hup > 2.0, 15), run.watchdogs(t_hup, 1e9)
        assert _wait(lambda: "health_rate_hz 1.0 -> 10.0" in run.stderr(), 5), run.stderr()
        err = run.stderr()
        assert "[estimator] particles = 64" in err and "needs a restart" in err, err
        assert "[bus]" not in err, err
        assert run.proc.poll() is None
    finally:
        run.close()
    assert run.proc.returncode == 0, run.stderr()
