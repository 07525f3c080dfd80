"""Console acceptance over a real pseudo-terminal: every command, JSON mode, security, cable pull.

The console's port thread opens the pty slave with pyserial (through a symlink, as a
``/dev/serial/by-id`` link); the test is the fitter's laptop on the master side.
Time for lockout and timeouts is an injected clock; waits are select() deadlines.
"""

from __future__ import annotations

import json
import os
import random
from collections.abc import Iterator

import pytest
from fakes.example_view import ExampleView
from fakes.ptyterm import PtyTerminal, console_on_pty

from gateway.cli import build_parser
from gateway.commands.console import ConsoleClient
from gateway.console.commands import COMMANDS
from gateway.console.port import ConsolePort
from gateway.console.session import ConsoleLimits
from gateway.pin import hash_pin

PIN = "2468"


class Clock:
    """Advances ``step_s`` per reading, so the rate limit never bites here."""

    def __init__(self, t: float = 5000.0, step_s: float = 0.05) -> None:
        self.t = t
        self.step_s = step_s

    def __call__(self) -> float:
        self.t += self.step_s
        return self.t


@pytest.fixture()
def rig(tmp_path) -> Iterator[tuple[PtyTerminal, ConsolePort, ExampleView, Clock]]:
    view, clock = ExampleView.example(pin_hash=hash_pin(PIN)), Clock()
    with console_on_pty(view, tmp_path, pin_hash=hash_pin(PIN), clock=clock,
                        wall=lambda: 1.7e9) as (term, port):
        yield term, port, view, clock


def login(term: PtyTerminal, name: str = "ann") -> str:
    assert term.command(f"login {name}") == "" and term.last_prompt == "PIN: "
    return term.command(PIN)


EXPECT: dict[str, tuple[str, list[str]]] = {
    "help": ("help", ["* ack <#seq|component>", "mode json|text", "history [hours|Nd]"]),
    "status": ("status", ["state      Degraded (BDN_Lat timed out)", "uptime     2d 00:05:12",
                          "worker     alive, 0 restarts", "alerts     2 active",
                          "console    not logged in"]),
    "estimates": ("estimates", ["Csy lateral damper       12.9     0.4 kNs/m   32.2  "
                                "<=75/55/35 %    ALARM",
                                "Csay anti-yaw damper   4020.0    90.0 kNs/m   97.7",
                                ">=160/200/267 % ADVISORY ack", "ESS 742 of 1000"]),
    "alerts": ("alerts", ["active alerts: 2", "#3     ALARM    RAISED", "recent events: 5",
                          "low-side ALARM threshold 0.35"]),
    "history": ("history 6", ["history, last 6 h (7 rows)", "48.00", "12.8+-0.2",
                              "0.2475+-0.0111"]),
    "sensors": ("sensors", ["BDN_Lat          0.0/1000.0", "TIMED OUT", "rejected: crc 3",
                            "last: BGN_Acc=0.231 BGN_YawRate=0.0012"]),
    "bus": ("bus", ["socketcan can0 (open)", "load        42.3 %", "7 error frames"]),
    "config": ("config", ["[estimator]", "particles = 1000", 'pin_hash = "<redacted>"']),
    "version": ("version", ["railgw 0.1.0", "pyserial 3."]),
    "log": ("log 2", ["checkpoint 34558 written", "checkpoint 34559 written"]),
    "login": ("help login", ["5 wrong PINs in a row lock login for", "300 s"]),
    "logout": ("logout", ["was not logged in"]),
    "ack": ("ack 3", ["refused: write commands need 'login' first"]),
    "baseline": ("baseline reset csy", ["refused"]),
    "threshold": ("threshold set csy warning 50%", ["refused"]),
    "mode": ("mode text", ["text mode"]),
    "echo": ("echo on", ["echo is on"]),
}


def test_every_command_over_the_pty(rig):
    term, _, _, _ = rig
    assert set(EXPECT) == set(COMMANDS)
    for name, (line, wanted) in EXPECT.items():
        reply = term.command(line)
        for text in wanted:
            assert text in reply, f"{name}: {text!r} not in\n{reply}"
        assert term.last_prompt == "railgw> "
    assert "log 20" not in term.command("log") and len(term.command("log").splitlines()) == 20


def test_write_commands_after_login_over_the_pty(rig):
    term, _, view, _ = rig
    assert "logged in as ann" in login(term) and term.last_prompt == "railgw# "
    assert term.command("ack 3") == "acknowledged: #6 Csy lateral damper ALARM"
    assert "cleared alert #7" in term.command("baseline reset lateral-damper")
    assert term.command("threshold set csy warning 50%") == (
        "threshold set: Csy lateral damper low-side WARNING at 50 % of nominal")
    assert "<=75/50/35 %    OK" in term.command("estimates")
    assert "** baseline reset csy_ns_per_m" in term.command("history 1")
    assert "logged in as ann" in term.command("status")
    assert term.command("logout") == "logged out" and term.last_prompt == "railgw> "
    audit = [(e["who"], e["command"], e["result"]) for e in view.audit_log
             if e["result"] != "attempt"]
    assert audit == [("ann", "login", "ok"), ("ann", "ack", "ok"), ("ann", "baseline", "ok"),
                     ("ann", "threshold", "ok")]


def test_the_pin_is_not_echoed(rig):
    term, _, _, _ = rig
    term.write(b"login\r")
    assert term.read_prompt().endswith("PIN: ")
    term.write(PIN.encode() + b"\r")
    raw = term.read_prompt()
    assert PIN not in raw and raw.startswith("\r\nlogged in")


def test_json_mode_over_the_pty(rig):
    term, _, _, _ = rig
    term.write(b"mode json\r")
    assert json.loads(term.read_until(lambda b: b.endswith(b"}\r\n")).split(b"\r\n")[1]) == {
        "ok": True, "cmd": "mode", "data": {"mode": "json"}}
    replies = {name: term.json_command(name) for name in
               ("help", "status", "estimates", "alerts", "history 3", "sensors", "bus",
                "config", "version", "log 5", "logout", "echo", "mode")}
    assert all(r["ok"] for r in replies.values())
    csy = replies["estimates"]["data"]["parameters"]["csy_ns_per_m"]
    assert csy["status"] == "ALARM" and csy["value_rel"] == pytest.approx(0.3225)
    assert csy["thresholds"]["low"] == [0.75, 0.55, 0.35]
    assert [a["seq"] for a in replies["alerts"]["data"]["active"]] == [3, 5]
    assert len(replies["history 3"]["data"]["rows"]) == 4
    assert replies["sensors"]["data"]["BDN_Lat"]["timed_out"] is True
    assert replies["bus"]["data"]["load_pct"] == 42.3
    assert replies["log 5"]["data"]["lines"][-1].endswith("(data time 172795.0 s)")
    assert replies["status"]["data"]["console"]["logged_in"] is False
    assert {c["name"] for c in replies["help"]["data"]["commands"]} == set(COMMANDS)
    assert term.json_command("ack 3") == {
        "ok": False, "cmd": "ack", "error": "refused: write commands need 'login' first"}
    assert term.json_command("nonsense")["error"].startswith("unknown command")
    assert term.json_command("x" * 400)["error"].startswith("line too long")
    assert term.json_command("login bo") == {"ok": True, "cmd": "login",
                                             "data": {"pin_required": True}}
    assert term.json_command(PIN)["data"] == {"user": "bo"}
    assert term.json_command("ack conicity")["error"].endswith("already ACKNOWLEDGED")
    assert term.json_command("ack 3")["data"]["alert"]["seq"] == 6


def test_lockout_and_its_expiry_over_the_pty(rig):
    term, _, view, clock = rig
    for _ in range(4):
        term.command("login mallory")
        assert "wrong PIN" in term.command("1234")
    term.command("login mallory")
    assert "console locked for 300 s" in term.command("9999")
    assert "try again in 300 s" in term.command("login mallory")
    assert "locked" in term.command("ack 3")
    clock.t += 301.0
    assert "logged in as mallory" in login(term, "mallory")
    results = [e["result"] for e in view.audit_log if e["command"] == "login"]
    assert results == ["failed"] * 4 + ["locked", "locked", "ok"]
    assert [e["result"] for e in view.audit_log if e["command"] == "ack"] == ["refused"]


def test_cable_pull_mid_session_is_survived(rig):
    term, port, view, _ = rig
    login(term)
    term.write(b"estim")  # half a command, then the cable goes
    term.replug()
    assert port.wait_for(lambda s: s.opens >= 2, 5.0)
    assert "maintenance console" in term.read_prompt()
    assert term.command("ack 3") == "error: refused: write commands need 'login' first"
    assert "Csy lateral damper" in term.command("estimates")
    for n in range(3, 6):
        term.replug()
        assert port.wait_for(lambda s, n=n: s.opens >= n, 5.0)
        assert term.read_prompt().endswith("railgw> ")
    assert "logged in as ann" in login(term)
    assert port.alive and port.stats.losses == 4 and port.stats.errors == 0
    assert [e["result"] for e in view.audit_log if e["command"] == "ack"] == ["refused"]


def test_a_vanished_device_node_is_noticed_and_reopened(rig):
    term, port, _, _ = rig
    target = os.readlink(term.path)
    os.unlink(term.path)  # the node goes, the pty itself stays open
    assert port.wait_for(lambda s: s.losses >= 1, 5.0)
    assert port.wait_for(lambda s: s.open_failures >= 1, 5.0)
    os.symlink(target, term.path)
    assert port.wait_for(lambda s: s.opens >= 2, 5.0)
    assert "maintenance console" in term.read_prompt()
    assert "uptime" in term.command("status")


def test_a_device_that_appears_later_is_opened(tmp_path):
    view = ExampleView.example()
    from gateway.console.engine import Console
    path = tmp_path / "ttyRAILGW0"
    port = ConsolePort(Console(view, port_name=str(path)), str(path), reopen_min_s=0.01,
                       reopen_max_s=0.05)
    with port:
        assert port.wait_for(lambda s: s.open_failures >= 2, 5.0)
        with PtyTerminal(tmp_path) as term:
            assert port.wait_for(lambda s: s.opens >= 1, 5.0)
            assert term.read_prompt().endswith("railgw> ")
    port.close()  # idempotent


def test_garbage_at_speed_does_not_crash_the_port(rig):
    term, port, _, _ = rig
    assert term.command("echo off") == "echo is off"
    noise = random.Random(7).randbytes(64 * 1024)
    term.write(noise)
    term.write(b"\x03\rstatus\r")
    out = term.read_until(lambda b: b"uptime" in b and b.endswith(b"railgw> "), 10.0)
    assert b"state      Degraded" in out
    assert port.alive and port.stats.errors == 0 and port.console.internal_errors == 0


def test_host_client_over_the_pty(rig):
    term, _, _, _ = rig
    client = ConsoleClient(term, timeout_s=5.0)
    assert client.exchange("version").startswith("railgw 0.1.0")
    assert client.prompt == "railgw> "
    assert client.exchange("login ann") == "" and client.prompt == "PIN: "
    assert client.exchange(PIN).startswith("logged in as ann")
    assert client.prompt == "railgw# "
    assert client.exchange("mode json") == '{"ok":true,"cmd":"mode","data":{"mode":"json"}}'
    assert client.prompt == ""
    assert json.loads(client.exchange("ack 3"))["data"]["alert"]["state"] == "ACKNOWLEDGED"


def test_alert_events_reach_a_connected_terminal(rig):
    from gateway.records import Alert, AlertState, Severity

    term, port, _, _ = rig
    port.notify_alert(Alert(9, 100.0, "conicity", Severity.ALARM, AlertState.RAISED, 0x29,
                            2.7))
    out = term.read_prompt()
    assert "** alert: #9     ALARM    RAISED       lambda wheelset" in out
    assert "uptime" in term.command("status")


def test_console_subcommand_is_registered():
    args = build_parser().parse_args(["console", "/dev/ttyUSB0", "--baud", "9600"])
    assert args.port == "/dev/ttyUSB0" and args.baud == 9600 and callable(args.func)


def test_limits_are_checked():
    with pytest.raises(ValueError, match="rate_per_s"):
        ConsoleLimits(rate_per_s=0)
    with pytest.raises(ValueError, match="reply_max_bytes"):
        ConsoleLimits(reply_max_bytes=10)
