"""The console against the running service, fed by the simulator, over a real pty."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
from fakes.ptyterm import PtyTerminal

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import open_node_bus
from gateway.config import Config, with_overrides
from gateway.pin import hash_pin
from gateway.service.daemon import Service

PIN = "482913"


@pytest.fixture()
def rig(tmp_path: Path):
    with PtyTerminal(tmp_path) as term:
        channel = f"console-{time.monotonic_ns()}"
        cfg = with_overrides(Config(), {
            "bus.interface": "virtual", "bus.channel": channel,
            "state.directory": str(tmp_path / "state"), "estimator.particles": 200,
            "serial.device": str(term.path),
            "serial.pin_hash": hash_pin(PIN)})
        service = Service(cfg)
        thread = threading.Thread(target=service.run, daemon=True)
        thread.start()
        assert service.source.opened.wait(10)
        end = time.monotonic() + 120
        while not (service.pipeline and service.pipeline.worker.stats.ready):
            assert time.monotonic() < end
            time.sleep(0.1)
        sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=8.0, seed=4))
        with open_node_bus(f"virtual:{channel}") as tx:
            send_live(sim.messages(), tx)
        end = time.monotonic() + 30
        while service.pipeline.last_estimate is None or service.pipeline.last_estimate.t_s < 1:
            assert time.monotonic() < end
            time.sleep(0.1)
        time.sleep(1.0)                       # one more publish of the view
        assert service.console is not None and service.console.wait_for(
            lambda s: s.opens >= 1, 10)
        try:
            yield term, service, tmp_path / "state"
        finally:
            service.flags.stop = True
            thread.join(timeout=15)


def test_every_command_against_the_running_service(rig):
    term, service, state = rig
    term.read_prompt(10)                       # the banner, sent when the port opened
    status = term.command("status")
    assert "Running" in status or "Degraded" in status
    est = term.command("estimates")
    assert "Csy" in est and "Csay" in est and "lambda" in est and "kNs/m" in est
    assert "alerts" in term.command("alerts").lower()
    sensors = term.command("sensors")
    for message in ("WSN_Lat", "BGN_Lat", "BDN_Lat", "VEH_Speed"):
        assert message in sensors
    bus = term.command("bus")
    assert "virtual" in bus and "ERROR_ACTIVE" in bus
    assert "[estimator]" in term.command("config") and "<redacted>" in term.command("config")
    assert "0.1.0" in term.command("version")
    assert "pipeline up" in term.command("log 200")
    assert "history" in term.command("history 1")
    assert "refused" in term.command("ack csy")
    # machine-readable mode: every reply parses and carries the live figures
    term.write(b"mode json\r")
    first = term.read_until(lambda b: b.endswith(b"}\r\n")).split(b"\r\n")
    assert json.loads(first[-2])["data"] == {"mode": "json"}
    js = term.json_command("estimates")
    assert js["ok"] and set(js["data"]["parameters"]) == {"csy_ns_per_m", "csay_ns_per_m",
                                                          "conicity"}
    csy = js["data"]["parameters"]["csy_ns_per_m"]
    assert 0.5 < csy["value_rel"] < 1.5 and csy["std"] > 0
    sens = term.json_command("sensors")
    assert sens["data"]["BGN_Lat"]["accepted"] > 1000
    assert term.json_command("status")["data"]["worker"]["alive"] is True
    for name in ("alerts", "history 1", "bus", "config", "version", "log 5"):
        time.sleep(0.1)                        # stay under the console's rate limit
        reply = term.json_command(name)
        assert reply["ok"] is True, reply


def test_writes_after_login_reach_the_service_and_the_audit_log(rig):
    term, service, state = rig
    term.read_prompt(10)                       # the banner, sent when the port opened
    assert term.command("login fitter1") == "" and term.last_prompt == "PIN: "
    assert "logged in" in term.command(PIN)
    reply = term.command("threshold set csy warning 50%")
    assert "error" not in reply.lower(), reply
    pp = service.policy.config.params["csy_ns_per_m"]
    assert pp.low_rel[1] == pytest.approx(0.5)
    reply = term.command("baseline reset lateral-damper")
    assert "error" not in reply.lower(), reply
    time.sleep(1.0)
    baselines = [json.loads(x) for x in (state / "baselines.jsonl").read_text().splitlines()]
    assert baselines[-1]["parameter"] == "csy_ns_per_m"
    audit = (state / "audit.jsonl").read_text()
    assert "threshold" in audit and "baseline" in audit and "login" in audit
    assert service.pipeline.worker.stats.restarts == 0      # the reset did not crash it
