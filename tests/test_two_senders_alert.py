"""Two senders on one sensor id raise an alert through the one alert path (issue 12 #8).

The front end flags two interleaved counter/SampleIdx sequences on one id; the alert
policy turns the flag into an ADVISORY event with code 0x30 ("two senders on BGN"),
once per episode, cleared when the stream is single again, never mistaken for a
suspension parameter (parameter ``node:BGN``, GW_Alert_Param NotAvailable). Checked on
the policy (seqs, snapshot, restore, ack), through a replay's JSON Lines, and off a
virtual bus from the live service.
"""

from __future__ import annotations

import io
import json
import math
import threading
from pathlib import Path

import pytest
from test_service import Running, _wait

from firmware_sim.output import send_live, write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.alerts.policy import CODE_TWO_SENDERS, SENDERS_SIDE, AlertPolicy, decode_code
from gateway.can.bus import open_node_bus
from gateway.config import Config, with_overrides
from gateway.errors import InputError
from gateway.offline.replay import replay
from gateway.records import AlertState, Severity


def test_policy_raises_once_per_episode_and_clears() -> None:
    reserved: list[int] = []
    pol = AlertPolicy(reserve=lambda upto: reserved.append(upto) or True)
    assert pol.two_senders("BGN_Lat", False, 1.0) == []          # single: nothing
    [raised] = pol.two_senders("BGN_Lat", True, 2.0)
    assert (raised.seq, raised.parameter, raised.severity, raised.state, raised.code) == (
        1, "node:BGN", Severity.ADVISORY, AlertState.RAISED, CODE_TWO_SENDERS)
    assert "two senders on BGN" in raised.message
    assert reserved == [17]                       # the seq ledger reserved before use
    assert pol.two_senders("BGN_Lat", True, 2.5) == []           # same episode
    assert pol.active == (raised,) and pol.two_senders_active("BGN_Lat")
    [cleared] = pol.two_senders("BGN_Lat", False, 5.0)
    assert (cleared.seq, cleared.state, cleared.code) == (2, AlertState.CLEARED, 0x30)
    assert pol.active == () and not pol.two_senders_active("BGN_Lat")
    [again] = pol.two_senders("BGN_Lat", True, 9.0)              # a new episode
    assert again.seq == 3 and again.state == AlertState.RAISED
    assert decode_code(0x30) == ("node", Severity.ADVISORY, SENDERS_SIDE)
    with pytest.raises(InputError, match="finite data time"):
        pol.two_senders("BGN_Lat", False, float("nan"))


def test_policy_snapshot_restore_and_ack() -> None:
    pol = AlertPolicy()
    [raised] = pol.two_senders("BGN_Lat", True, 2.0)
    snap = json.loads(json.dumps(pol.snapshot(), allow_nan=False))
    back = AlertPolicy.restore(snap)
    assert back.two_senders_active("BGN_Lat") and back.next_seq == 2
    from_history = AlertPolicy.restore(None, history=[raised])   # crash before snapshot
    assert from_history.two_senders_active("BGN_Lat") and from_history.next_seq == 2
    ack = back.acknowledge(raised.seq, 3.0)
    assert (ack.seq, ack.state, ack.code, ack.parameter) == (
        2, AlertState.ACKNOWLEDGED, 0x30, "node:BGN")
    with pytest.raises(InputError, match="already ACKNOWLEDGED"):
        back.acknowledge(raised.seq, 3.5)
    [cleared] = back.two_senders("BGN_Lat", False, 4.0)
    assert cleared.seq == 3 and back.active == ()
    # the cleared episode restores as cleared; suspension tracks are untouched
    again = AlertPolicy.restore(back.snapshot(), history=[raised, ack, cleared])
    assert again.active == () and again.next_seq == 4


def _rogue_log(path: Path, duration_s: float, window_s: tuple[float, float]) -> Path:
    cfg = SimConfig(duration_s=duration_s, seed=1, second_sender="BGN",
                    second_sender_window_s=window_s)
    write_log(list(Simulation(get_scenario("nominal"), cfg).messages()), path)
    return path


def test_replay_jsonl_has_the_two_senders_alert(tmp_path: Path) -> None:
    log = _rogue_log(tmp_path / "rogue.log", 8.0, (2.0, 4.0))
    cfg = with_overrides(Config(), {"estimator.particles": 32})
    out = io.StringIO()
    result = replay(log, cfg, jsonl=out)
    def strict(token: str) -> None:      # NaN/Infinity are not JSON: depot tools reject them
        raise AssertionError(f"non-JSON number {token} in the replay JSONL")

    lines = [json.loads(x, parse_constant=strict) for x in out.getvalue().splitlines()]
    alerts = [x for x in lines if x["type"] == "alert"]
    ours = [a for a in alerts if a["code"] == CODE_TWO_SENDERS]
    assert [(a["state"], a["parameter"], a["severity"]) for a in ours] == [
        ("raised", "node:BGN", "advisory"), ("cleared", "node:BGN", "advisory")], alerts
    assert ours[0]["message"].startswith("two senders on BGN")
    assert ours[0]["value_rel"] is None            # a node alert has no parameter value
    assert 2.0 <= ours[0]["t_s"] < 4.0 < ours[1]["t_s"] <= 8.0
    assert [a.seq for a in result.alerts] == sorted({a.seq for a in result.alerts})
    assert all(a["code"] != CODE_TWO_SENDERS or a["parameter"].startswith("node:")
               for a in alerts)
    assert result.front_end is not None
    assert result.front_end.two_sender_events["BGN_Lat"] == 1


def test_live_service_sends_a_two_senders_alert_frame(tmp_path: Path) -> None:
    sim = Simulation(get_scenario("nominal"), SimConfig(
        duration_s=5.0, seed=5, second_sender="BGN", second_sender_window_s=(1.0, 5.0)))
    with Running(tmp_path, "senders", particles=64) as run:
        def go() -> None:
            with open_node_bus(f"virtual:{run.channel}") as tx:
                send_live(sim.messages(), tx)
        player = threading.Thread(target=go, daemon=True)
        player.start()

        def alert_frames() -> list[dict[str, float]]:
            return [v for v in run.decoded("GW_Alert") if v["GW_Alert_Code"] == 0x30]
        assert _wait(lambda: alert_frames(), 30), run.decoded("GW_Alert")
        player.join(timeout=30)
    frame = alert_frames()[0]
    assert frame["GW_Alert_State"] == int(AlertState.RAISED)
    assert frame["GW_Alert_Severity"] == int(Severity.ADVISORY)
    # not a suspension parameter: Param and ValueRel NotAvailable (not 0..2)
    assert math.isnan(frame["GW_Alert_Param"]) and math.isnan(frame["GW_Alert_ValueRel"])
    persisted = (tmp_path / "state").rglob("alerts*.jsonl")
    text = "".join(p.read_text() for p in persisted)
    assert '"code": 48' in text or '"code":48' in text
