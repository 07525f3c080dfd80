"""The live service on python-can's virtual bus: frames out, worker crash, SIGTERM, SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.canbus import open_bus, open_node_bus
from gateway.codec import default_codec
from gateway.config import Config, with_overrides
from gateway.errors import FrameError
from gateway.service import Service

ROOT = Path(__file__).resolve().parent.parent


def _wait(cond, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


class Running:
    """A Service in a thread on its own virtual channel, with a frame recorder."""

    def __init__(self, tmp_path: Path, name: str, particles: int = 200) -> None:
        self.channel = f"svc-{name}-{time.monotonic_ns()}"
        cfg = with_overrides(Config(), {
            "bus.interface": "virtual", "bus.channel": self.channel,
            "state.directory": str(tmp_path / "state"), "estimator.particles": particles,
            "estimator.checkpoint_interval_s": 1.0})
        self.service = Service(cfg)
        self.frames: list[can.Message] = []
        self._rx = open_bus(f"virtual:{self.channel}")
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self.service.run, daemon=True),
                         threading.Thread(target=self._record, daemon=True)]

    def _record(self) -> None:
        while not self._stop.is_set():
            msg = self._rx.recv(0.1)
            if msg is not None and msg.arbitration_id >= 0x300:
                self.frames.append(msg)

    def __enter__(self) -> Running:
        for t in self._threads:
            t.start()
        assert self.service.source.opened.wait(10)
        return self

    def play(self, scenario: str, duration_s: float, seed: int = 5) -> threading.Thread:
        sim = Simulation(get_scenario(scenario), SimConfig(duration_s=duration_s, seed=seed))

        def go() -> None:
            with open_node_bus(f"virtual:{self.channel}") as tx:
                send_live(sim.messages(), tx)

        t = threading.Thread(target=go, daemon=True)
        t.start()
        return t

    def decoded(self, message: str) -> list[dict[str, float]]:
        codec = default_codec()
        out = []
        for m in list(self.frames):
            try:
                f = codec.decode_message(m)
            except FrameError:
                continue
            if f.message == message:
                out.append(f.values)
        return out

    def __exit__(self, *exc: object) -> None:
        self.service.flags.stop = True
        self._threads[0].join(timeout=10)
        self._stop.set()
        self._threads[1].join(timeout=2)
        self._rx.shutdown()


def test_frames_come_back_with_e2e_and_health(tmp_path):
    with Running(tmp_path, "frames") as run:
        run.play("nominal", 6.0).join()
        assert _wait(lambda: len(run.decoded("GW_EstCsy")) >= 5, 60)
        time.sleep(1.5)
    codec = default_codec()
    for m in run.frames:
        codec.decode_message(m)                     # every frame of ours passes E2E
    est = run.decoded("GW_EstCsy")
    assert all(0 < v["GW_EstCsy_Mean"] < 131_000 for v in est)
    health = run.decoded("GW_Health")
    assert len(health) >= 3
    assert health[-1]["GW_Health_FramesRx"] > 0
    assert {v["GW_Health_BusState"] for v in health} == {0}


def test_worker_sigkill_resumes_from_checkpoint_within_2_s(tmp_path):
    with Running(tmp_path, "kill") as run:
        sender = run.play("nominal", 20.0)
        svc = run.service
        assert _wait(lambda: svc.pipeline is not None and svc.pipeline.worker.stats.checkpoints
                     >= 2, 90)
        worker = svc.pipeline.worker
        before = worker.stats.estimates
        os.kill(worker.pid, signal.SIGKILL)
        t_kill = time.monotonic()
        assert _wait(lambda: worker.stats.restarts == 1, 5)
        assert _wait(lambda: worker.stats.estimates > before + 1, 10)
        resumed_s = time.monotonic() - t_kill
        sender.join()
    assert resumed_s < 2.0, f"resumed after {resumed_s:.2f} s"
    assert worker.stats.restarts == 1


def _demo(state: Path, scenario: str, duration_s: float, log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "gateway", "-v", "demo", "--scenario", scenario, "--duration",
         str(duration_s), "--particles", "200", "--state-dir", str(state)],
        cwd=ROOT, stdout=open(log, "w"), stderr=subprocess.STDOUT)


def test_sigterm_stops_cleanly_within_5_s_and_restart_resumes(tmp_path):
    state = tmp_path / "state"
    proc = _demo(state, "nominal", 120, tmp_path / "one.log")
    try:
        assert _wait(lambda: (state / "checkpoint.bin").exists(), 120)
        stamp = (state / "checkpoint.bin").stat().st_mtime_ns
        proc.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        assert proc.wait(timeout=10) == 0
        assert time.monotonic() - t0 < 5.0
    finally:
        proc.kill()
    assert (state / "checkpoint.bin").stat().st_mtime_ns > stamp    # final checkpoint
    proc = _demo(state, "nominal", 120, tmp_path / "two.log")
    try:
        assert _wait(lambda: "resuming the estimator" in (tmp_path / "two.log").read_text(), 60)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)


@pytest.mark.slow
def test_sigkill_of_the_service_loses_no_alert(tmp_path):
    state = tmp_path / "state"
    proc = _demo(state, "lateral-failing", 60, tmp_path / "one.log")
    alerts = state / "alerts.jsonl"
    try:
        assert _wait(lambda: alerts.exists() and '"RAISED"' in alerts.read_text().upper(), 120)
        time.sleep(0.5)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    before = [json.loads(x) for x in alerts.read_text().splitlines() if x.strip()]
    proc = _demo(state, "nominal", 20, tmp_path / "two.log")
    try:
        assert _wait(lambda: "resuming the estimator" in (tmp_path / "two.log").read_text(), 60)
        time.sleep(3)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=15)
    after = [json.loads(x) for x in alerts.read_text().splitlines() if x.strip()]
    assert after[: len(before)] == before                    # nothing lost or rewritten
    seqs = [a["seq"] for a in after]
    raised = [a["seq"] for a in after if a["state"] == "RAISED"]
    assert len(set(raised)) == len(raised)                   # nothing raised twice
    assert all(b >= a for a, b in zip(seqs, seqs[1:], strict=False))   # seq survives restart
    policy = json.loads((state / "alert_policy.json").read_text())
    assert policy                                            # restored and saved again
