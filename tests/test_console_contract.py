"""One console contract: every command against the live service and the example view.

The parametrised ``term`` fixture gives a real pty talking to a console that serves
either the example view (tests/fakes/example_view.py, on the real AlertPolicy) or the
live service view: a real :class:`gateway.service.daemon.Service` on a python-can ``virtual``
bus, fed 16 s of the simulator's ``paper`` scenario (Csy at half nominal raises alerts),
with its worker process, alert policy and state directory. Every check below runs
unchanged against both, so the two views cannot drift apart again; the text replies
are the ones ``docs/console.md`` shows.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fakes.example_view import ExampleView
from fakes.ptyterm import PtyTerminal, console_on_pty

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import open_node_bus
from gateway.config import Config, with_overrides
from gateway.console.view import PARAMS
from gateway.pin import hash_pin
from gateway.service.daemon import Service

PIN = "482913"
PIN_HASH = hash_pin(PIN, n=2 ** 10)
ALERT_KEYS = {"seq", "t_s", "parameter", "severity", "state", "code", "value_rel", "message"}
PARAM_KEYS = {"mean", "std", "nominal", "value_rel", "sigma_rel", "thresholds", "status",
              "alert_state", "alert_seq", "confident"}
SENSOR_KEYS = {"rate_hz", "expected_hz", "accepted", "rejected", "lost_frames", "timeouts",
               "timed_out", "last_values"}
BUS_KEYS = {"interface", "channel", "state", "open", "load_pct", "error_frames",
            "frames_rx", "frames_tx", "reopens", "dropped", "last_error"}
STATUS_KEYS = {"state", "uptime_s", "version", "data_time_s", "worker", "bus",
               "active_alerts", "console", "front_end", "state_dir"}
FRONT_END_KEYS = {"late", "gaps", "resyncs", "clock_steps", "horizon", "two_senders",
                  "two_sender_events", "nodes"}
ROW_KEYS = {"t_s", "time", "estimates", "event"}


def _wait(pred: Any, timeout_s: float, what: str) -> Any:
    end = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.1)


@pytest.fixture(scope="module")
def live_rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[PtyTerminal, Service]]:
    tmp = tmp_path_factory.mktemp("live")
    with PtyTerminal(tmp) as term:
        channel = f"contract-{time.monotonic_ns()}"
        cfg = with_overrides(Config(), {
            "bus.interface": "virtual", "bus.channel": channel,
            "state.directory": str(tmp / "state"), "estimator.particles": 200,
            "serial.device": str(term.path), "serial.pin_hash": PIN_HASH})
        service = Service(cfg)
        thread = threading.Thread(target=service.run, daemon=True)
        thread.start()
        stop = threading.Event()
        sender = None
        try:
            _wait(lambda: service.pipeline and service.pipeline.worker.stats.ready, 180,
                  "the worker")
            sim = Simulation(get_scenario("paper"), SimConfig(duration_s=16.0, seed=4))

            def play() -> None:
                with open_node_bus(f"virtual:{channel}") as tx:
                    send_live(sim.messages(), tx, stop=stop.is_set)
            sender = threading.Thread(target=play, daemon=True)
            sender.start()
            sender.join(timeout=60)               # all data in: no new alerts during tests
            _wait(lambda: any(a.state.name == "RAISED" for a in service.policy.active), 30,
                  "a raised alert from the paper scenario")
            _wait(lambda: service.console is not None and service.console.stats.opens >= 1,
                  10, "the console port")
            _wait(lambda: service.view.status().get("active_alerts"), 5, "a view publish")
            term.read_prompt(10)                  # the banner
            yield term, service
        finally:
            stop.set()
            if sender is not None:
                sender.join(timeout=10)
            service.flags.stop = True
            thread.join(timeout=15)


@pytest.fixture(params=["example", "live"])
def term(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[PtyTerminal]:
    if request.param == "example":
        with console_on_pty(ExampleView.example(pin_hash=PIN_HASH), tmp_path,
                            pin_hash=PIN_HASH) as (t, _port):
            yield t
        return
    t, _service = request.getfixturevalue("live_rig")
    _cmd(t, "")
    yield t
    _text_mode(t)
    _cmd(t, "logout")


def _cmd(t: PtyTerminal, line: str) -> str:
    time.sleep(0.06)           # pacing (not synchronisation): below the 20 lines/s limit
    return t.command(line)


def _json(t: PtyTerminal, line: str) -> dict[str, Any]:
    time.sleep(0.06)
    return t.json_command(line)


def _json_mode(t: PtyTerminal) -> None:
    time.sleep(0.06)
    t.write(b"mode json\r")
    got = t.read_until(lambda b: b.endswith(b"}\r\n"))
    assert json.loads(got.split(b"\r\n")[-2]) == {"ok": True, "cmd": "mode",
                                                  "data": {"mode": "json"}}


def _text_mode(t: PtyTerminal) -> None:
    time.sleep(0.06)
    t.write(b"mode text\r")
    t.read_prompt()


def _login(t: PtyTerminal) -> None:
    assert _cmd(t, "login fitter") == "" and t.last_prompt == "PIN: "
    assert _cmd(t, PIN) == "logged in as fitter; write commands enabled ('logout' to end)"


def test_read_commands_have_one_shape(term: PtyTerminal):
    text = {name: _cmd(term, name) for name in
            ("status", "estimates", "alerts", "history 1", "sensors", "bus", "version")}
    assert re.match(r"state +(Running|Degraded|Fault|Starting)", text["status"])
    assert re.search(r"^console +not logged in$", text["status"], re.M)
    assert re.search(r"^front end +late \d+.*, gaps \d+", text["status"], re.M)
    assert re.search(r"^ +resyncs \d+, clock steps \d+, two senders", text["status"], re.M)
    assert text["estimates"].startswith("estimates at data time ")
    for label in ("Csy lateral damper", "Csay anti-yaw damper", "lambda wheelset"):
        assert label in text["estimates"]
    assert re.match(r"active alerts: [1-9]", text["alerts"])
    assert "acknowledge with: ack <#seq> or ack <component>" in text["alerts"]
    assert text["history 1"].startswith("history, last 1 h (")
    assert text["sensors"].startswith("message      rate/expected Hz")
    assert text["bus"].startswith("interface   ")
    assert text["version"].startswith("railgw 0.1.0 (console 0.1.0")
    _json_mode(term)
    status = _json(term, "status")["data"]
    assert set(status) >= STATUS_KEYS
    assert set(status["front_end"]) == FRONT_END_KEYS
    assert status["state_dir"] == {"write_failures": 0, "set_aside": []}
    est = _json(term, "estimates")["data"]
    assert {"t_s", "ess", "particles", "updated", "parameters"} <= set(est)
    assert set(est["parameters"]) == set(PARAMS)
    for p in est["parameters"].values():
        assert set(p) == PARAM_KEYS
        assert set(p["thresholds"]) == {"low", "high"}
    alerts = _json(term, "alerts")["data"]
    assert set(alerts) == {"active", "recent"} and alerts["active"]
    assert all(set(a) == ALERT_KEYS for a in alerts["active"] + alerts["recent"])
    hist = _json(term, "history 1")["data"]
    assert set(hist) == {"hours", "rows_total", "rows"} and hist["rows"]
    assert all(set(r) == ROW_KEYS for r in hist["rows"])
    sensors = _json(term, "sensors")["data"]
    assert set(sensors) == {"WSN_Lat", "BGN_Lat", "BDN_Lat", "VEH_Speed"}
    assert all(set(m) == SENSOR_KEYS for m in sensors.values())
    assert set(_json(term, "bus")["data"]) >= BUS_KEYS
    assert 'pin_hash = "<redacted>"' in _json(term, "config")["data"]["text"]
    assert PIN_HASH.split("$")[4] not in json.dumps(_json(term, "config"))
    assert set(_json(term, "log 5")["data"]) == {"lines"}


def test_write_commands_print_what_the_docs_show(term: PtyTerminal):
    _json_mode(term)
    raised = [a for a in _json(term, "alerts")["data"]["active"] if a["state"] == "RAISED"]
    assert raised, "the view should have a raised alert"
    alert = raised[0]
    label = f"{PARAMS[alert['parameter']].label} {PARAMS[alert['parameter']].component}"
    component = PARAMS[alert["parameter"]].aliases[1]       # e.g. lateral-damper
    _text_mode(term)
    assert _cmd(term, f"ack {alert['seq']}") == \
        "error: refused: write commands need 'login' first"
    _login(term)
    reply = _cmd(term, f"ack {alert['seq']}")
    m = re.fullmatch(rf"acknowledged: #(\d+) {label} {alert['severity']}", reply)
    assert m and int(m.group(1)) > alert["seq"], reply
    reply = _cmd(term, f"baseline reset {component}")
    m = re.fullmatch(rf"baseline reset: {label} re-learns from its prior; "
                     rf"cleared alert #(\d+)", reply)
    assert m and int(m.group(1)) > alert["seq"], reply
    assert _cmd(term, "threshold set csy warning 50%") == \
        "threshold set: Csy lateral damper low-side WARNING at 50 % of nominal"
    assert f"** baseline reset {alert['parameter']}" in _cmd(term, "history 1")
    _json_mode(term)
    th = _json(term, "threshold set csy advisory 0.8")
    assert th["ok"] and th["data"] == {
        "parameter": "csy_ns_per_m", "side": "low", "severity": "ADVISORY", "value_rel": 0.8,
        "thresholds": {"low": [0.8, 0.5, 0.35], "high": [None, None, None]}}
    base = _json(term, f"baseline reset {component}")
    assert base["ok"] and set(base["data"]) == {"parameter", "t_s", "events", "estimator"}
    assert base["data"]["events"] == []                   # nothing left to clear
    assert all(a["parameter"] != alert["parameter"]
               for a in _json(term, "alerts")["data"]["active"])
    err = _json(term, "ack 99999")
    assert err["ok"] is False and err["error"].startswith("expected the seq of an active")


@pytest.mark.parametrize("value", ["1e-320%", "100", "0.05", "501%", "nan"])
def test_threshold_outside_physical_bounds_is_refused(term: PtyTerminal, value: str):
    _login(term)
    _json_mode(term)
    before = _json(term, "estimates")["data"]["parameters"]["csy_ns_per_m"]["thresholds"]
    _text_mode(term)
    reply = _cmd(term, f"threshold set csy alarm {value}")
    assert reply.startswith("error: expected a threshold from 10 % to 500 % of nominal "
                            "(0.1 to 5), got") and "\n" not in reply, reply
    _json_mode(term)
    after = _json(term, "estimates")["data"]["parameters"]["csy_ns_per_m"]["thresholds"]
    assert after == before


def test_unknown_words_are_never_repeated(term: PtyTerminal):
    reply = _cmd(term, "482913")
    assert "482913" not in reply and reply.startswith("error: unknown command")
    _json_mode(term)
    obj = _json(term, "482913")
    assert obj["cmd"] == "?" and "482913" not in json.dumps(obj)
