"""Console engine without a port: login, lockout, timeouts, rate limit, audit, bounded replies."""

from __future__ import annotations

import json
from typing import Any

import pytest
from fakes.example_view import ExampleView

from gateway.console.commands import COMMANDS
from gateway.console.engine import PROMPT, PROMPT_LOGGED_IN, PROMPT_PIN, Console
from gateway.console.reply import Reply, encode_json, encode_text
from gateway.console.session import ConsoleLimits
from gateway.errors import InputError
from gateway.pin import hash_pin

PIN = "2468"


class Clock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def make(view: Any = None, *, pin: str = PIN, **limits: Any) -> tuple[Console, Clock, Any]:
    clock = Clock()
    view = view or ExampleView.example()
    console = Console(view, pin_hash=hash_pin(pin) if pin else "",
                      limits=ConsoleLimits(**limits), clock=clock, wall=lambda: 1.7e9,
                      port_name="/dev/ttyTEST")
    console.connect()
    return console, clock, view


def say(console: Console, line: str) -> str:
    return console.feed(line.encode() + b"\r").decode().replace("\r\n", "\n")


def test_prompts_follow_the_login_state():
    console, _, _ = make()
    assert say(console, "").endswith(PROMPT.decode())
    assert say(console, "login ann").endswith(PROMPT_PIN.decode())
    out = say(console, PIN)
    assert "logged in as ann" in out and out.endswith(PROMPT_LOGGED_IN.decode())
    assert PIN not in out
    assert say(console, "logout").endswith(PROMPT.decode())


def test_every_command_has_help_with_its_usage():
    console, _, _ = make()
    listing = say(console, "help")
    for name, cmd in COMMANDS.items():
        assert cmd.usage in listing
        detail = say(console, f"help {name}")
        assert detail.splitlines()[1] == cmd.usage
    out = say(console, "frobnicate")
    reply = out.split("\n", 1)[1]  # after the echoed line
    assert "unknown command" in reply and "frobnicate" not in reply


def test_writes_are_refused_before_login_and_audited():
    console, _, view = make()
    for line in ("ack 3", "baseline reset csy", "threshold set csy warning 50%"):
        assert "refused: write commands need 'login' first" in say(console, line)
    assert [(e["command"], e["result"], e["who"]) for e in view.audit_log] == [
        ("ack", "refused", "-"), ("baseline", "refused", "-"), ("threshold", "refused", "-")]
    assert view.alerts()[0][0].state.name == "RAISED"


def test_five_wrong_pins_lock_until_the_lockout_expires():
    console, clock, view = make()
    for i in range(4):
        say(console, "login eve")
        assert f"wrong PIN ({4 - i} attempt" in say(console, "0000")
    say(console, "login eve")
    assert "console locked for 300 s" in say(console, "0000")
    locked = say(console, "login eve")
    assert "console locked" in locked and "try again in 300 s" in locked
    assert "locked after failed PINs" in say(console, "ack 3")
    clock.t += 299.0
    assert "try again in 1 s" in say(console, "login eve")
    clock.t += 1.5
    say(console, "login eve")
    assert "logged in as eve" in say(console, PIN)
    results = [e["result"] for e in view.audit_log if e["command"] == "login"]
    assert results == ["failed"] * 4 + ["locked", "locked", "locked", "ok"]


def test_lockout_survives_a_reconnect_but_the_login_does_not():
    console, _, _ = make()
    say(console, "login")
    say(console, PIN)
    assert console.session.logged_in
    console.disconnect("cable pulled")
    console.connect()
    assert not console.session.logged_in
    for _ in range(5):
        say(console, "login")
        say(console, "1111")
    console.disconnect()
    console.connect()
    assert "console locked" in say(console, "login")


def test_idle_session_is_logged_out():
    console, clock, _ = make(idle_timeout_s=600)
    say(console, "login")
    say(console, PIN)
    clock.t += 599
    assert "acknowledged" in say(console, "ack 3")
    clock.t += 601
    notice = console.poll().decode()
    assert "logged out" in notice and notice.endswith(PROMPT.decode())
    assert "need 'login' first" in say(console, "ack conicity")


def test_pin_prompt_expires():
    console, clock, _ = make(pin_entry_timeout_s=60)
    say(console, "login")
    clock.t += 61
    assert "PIN entry timed out" in console.poll().decode()
    out = say(console, PIN)  # may be the PIN: not echoed, not repeated, not run
    assert "line discarded" in out and PIN not in out
    say(console, "login")
    clock.t += 61
    assert "PIN entry timed out" in say(console, PIN)
    assert not console.session.logged_in


def test_empty_pin_cancels_without_counting_a_failure():
    console, _, _ = make()
    say(console, "login")
    assert "login cancelled" in say(console, "")
    assert console.guard.failures == 0


def test_no_pin_configured_disables_writes():
    console, _, _ = make(pin="")
    assert "login disabled" in say(console, "login")
    assert "no PIN configured" in say(console, "ack 3")


def test_rate_limit_drops_a_burst_and_recovers():
    console, clock, _ = make(rate_per_s=20, burst=20)
    out = console.feed(b"version\r" * 30).decode()
    assert out.count("railgw 0.1.0") == 20
    assert out.count("rate limit") == 1
    assert console.lines_dropped == 10
    clock.t += 1.0
    assert "railgw 0.1.0" in say(console, "version")


def test_overlong_line_gets_an_error_and_the_next_line_works():
    console, _, _ = make(max_line_bytes=256)
    out = say(console, "x" * 1000)
    assert "line too long: expected at most 256 bytes, got 1000" in out
    assert "railgw 0.1.0" in say(console, "version")


def test_config_never_shows_the_pin_hash():
    stored = hash_pin(PIN)
    view = ExampleView.example(pin_hash=stored)
    assert stored in view.config_text()
    console, _, _ = make(view)
    out = say(console, "config")
    assert 'pin_hash = "<redacted>"' in out and stored.split("$")[4] not in out
    assert "[serial]" in out and 'device = "/dev/ttyS1"' in out


def test_write_commands_with_aliases_reach_the_view():
    console, _, view = make()
    say(console, "login")
    say(console, PIN)
    assert "acknowledged: #6 Csy lateral damper ALARM" in say(console, "ack #3")
    assert "already ACKNOWLEDGED" in say(console, "ack wheelset")
    assert "cleared alert #7" in say(console, "baseline reset lateral-damper")
    assert "low-side WARNING at 50 % of nominal" in say(console,
                                                        "threshold set csy warn 50%")
    assert "high-side ALARM at 300 % of nominal" in say(console,
                                                        "threshold set wheels alarm 3.0")
    out = say(console, "threshold set csay alarm 0.9")
    assert "strictly decreasing" in out
    assert "expected a component" in say(console, "baseline reset bogie")
    assert "usage: baseline reset <component>" in say(console, "baseline reset bogie")
    results = [(e["command"], e["result"]) for e in view.audit_log
               if e["command"] != "login" and e["result"] != "attempt"]
    attempts = [e["command"] for e in view.audit_log if e["result"] == "attempt"]
    assert attempts == [c for c, _ in results]  # each write audited before it runs
    assert results == [("ack", "ok"), ("ack", "rejected"), ("baseline", "ok"),
                       ("threshold", "ok"), ("threshold", "ok"), ("threshold", "rejected"),
                       ("baseline", "rejected"), ("baseline", "rejected")]
    entry = view.audit_log[2]
    assert entry["who"] == "fitter" and entry["port"] == "/dev/ttyTEST"
    assert entry["args"] == ["#3"] and entry["detail"]["alert"]["state"] == "ACKNOWLEDGED"
    assert entry["time"].startswith("2023-11-14T22:13:20")


class BrokenView(ExampleView):
    def estimates(self) -> dict[str, Any]:
        raise RuntimeError("boom")

    def baseline_reset(self, component: str) -> Any:
        raise ZeroDivisionError


def test_a_failing_service_gives_an_error_reply_not_a_dead_console():
    example = ExampleView.example()
    view = BrokenView(estimate=example._estimate)
    console, _, _ = make(view)
    assert "internal error (RuntimeError; logged)" in say(console, "estimates")
    say(console, "login")
    say(console, PIN)
    assert "internal error (ZeroDivisionError" in say(console, "baseline reset csy")
    assert view.audit_log[-1]["result"] == "error"
    assert "railgw 0.1.0" in say(console, "version")


def test_missing_keys_render_as_dashes():
    class Sparse(ExampleView):
        def status(self) -> dict[str, Any]:
            return {}

        def estimates(self) -> dict[str, Any]:
            return {"parameters": {"csy_ns_per_m": {"mean": None}, "odd": {}}}

    console, _, _ = make(Sparse(estimate=None))
    assert "uptime     -" in say(console, "status")
    out = say(console, "estimates")
    assert "Csy lateral damper" in out and "odd" in out
    for cmd in ("sensors", "bus", "history", "log", "alerts", "config"):
        assert "error" not in say(console, cmd)


def test_text_replies_are_cut_with_a_marker():
    text = "\n".join(f"line {i:04d} " + "x" * 50 for i in range(400))
    wire = encode_text(Reply(True, "log", text=text), 1024)
    assert len(wire) <= 1024
    assert wire.endswith(b"-byte limit]\r\n") and b"reply truncated" in wire


def test_json_replies_shrink_but_still_parse():
    data = {"lines": [f"INFO {i} " + "y" * 80 for i in range(500)], "note": "z" * 5000}
    wire = encode_json(Reply(True, "log", data=data), 2048)
    assert len(wire) <= 2048
    obj = json.loads(wire)
    assert obj["ok"] and obj["truncated"] and obj["data"]["lines"][-1].startswith("INFO 499")


def test_json_mode_replies_are_one_object_per_line():
    console, _, _ = make()
    echo, reply = say(console, "mode json").splitlines()  # typed while still in text mode
    assert echo == "mode json"
    assert json.loads(reply) == {"ok": True, "cmd": "mode", "data": {"mode": "json"}}
    err = json.loads(say(console, "ack 3"))
    assert err == {"ok": False, "cmd": "ack",
                   "error": "refused: write commands need 'login' first"}
    assert say(console, "") == ""
    assert json.loads(say(console, "login")) == {"ok": True, "cmd": "login",
                                                 "data": {"pin_required": True}}
    assert json.loads(say(console, PIN))["data"] == {"user": "fitter"}
    assert say(console, "mode text").startswith("text mode")


def test_resolve_parameter_errors_are_input_errors():
    from gateway.console.view import resolve_parameter
    assert resolve_parameter("Anti_Yaw_Damper") == "csay_ns_per_m"
    with pytest.raises(InputError, match="expected a component"):
        resolve_parameter("bogie")


def test_long_history_is_thinned_but_keeps_events_and_the_latest_row():
    from gateway.console.view import history_row
    from gateway.records import Estimate

    rows = [history_row(60.0 * i, Estimate(60.0 * i, (40e3, 4.1e6, 0.15), (1e3, 1e5, 0.01),
                                           500.0)) for i in range(10_000)]
    rows.insert(5000, history_row(300_000.0, event="baseline reset csy_ns_per_m"))

    class Long(ExampleView):
        def history(self, hours: float) -> list[dict[str, Any]]:
            return rows

    console, _, _ = make(Long(estimate=None))
    text = say(console, "history 7d")
    assert "(10000 rows, 48 shown)" in text and "** baseline reset csy_ns_per_m" in text
    assert "166.65" in text  # the last row, t = 599940 s
    say(console, "mode json")
    obj = json.loads(say(console, "history 7d"))
    assert "truncated" not in obj
    assert obj["data"]["rows_total"] == 10_001 and len(obj["data"]["rows"]) == 73
    assert obj["data"]["rows"][-1]["t_s"] == 599_940.0


def test_alert_notice_redraws_the_prompt_and_the_partial_line():
    from gateway.records import Alert, AlertState, Severity

    console, _, _ = make()
    alert = Alert(9, 100.0, "csay_ns_per_m", Severity.WARNING, AlertState.RAISED, 0x15, 0.5)
    assert console.feed(b"esti") == b"esti"
    out = console.notify_alert(alert).decode()
    assert out.startswith("\r\n** alert: #9     WARNING  RAISED       Csay anti-yaw damper")
    assert out.endswith("\r\nrailgw> esti")
    assert "estimates at data time" in say(console, "mates")
    say(console, "mode json")
    assert console.notify_alert(alert) == b""
