"""The one JSON form of estimates and alerts, the places built on it, and the one judge.

Every place that writes an Alert or an Estimate as JSON (console, state directory,
policy snapshot, replay lines) is checked against ``gateway.jsonform``; state files in
the previous version's format (literal lines below, written by the code before the one
form) must still load; console and policy must judge one estimate alike.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from gateway import jsonform
from gateway.alerts import judge
from gateway.alerts.policy import AlertPolicy, ParamPolicy, PolicyConfig
from gateway.console import render
from gateway.console.view import estimates_view, history_row
from gateway.errors import StateError
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL
from gateway.offline.replay import alert_json as replay_alert
from gateway.offline.replay import estimate_json as replay_estimate
from gateway.records import Alert, AlertState, Estimate, Located, Severity
from gateway.sinks.store import codec
from gateway.sinks.store.store import StateStore

NOM = np.array([float(getattr(THETA_NOMINAL, n)) for n in PARAM_NAMES])
NAN_ALERT = Alert(7, 12.5, "node:BGN", Severity.ADVISORY, AlertState.RAISED, 0x30,
                  math.nan, "two senders on BGN")
ALERT = Alert(3, 4.25, "csy_ns_per_m", Severity.ALARM, AlertState.ACKNOWLEDGED, 0x19,
              0.3125, "csy_ns_per_m ALARM acknowledged")
NAN_EST = Estimate(1.5, (40e3, math.nan, 0.15), (1e3, 1e5, math.inf), math.nan,
                   v_sy_mps=0.01, updated=False)

# Written by the version before the one form (the previous store codec and policy).
OLD_ALERT_LINES = [
    '{"seq":1,"t_s":3.0,"wall_time_s":1700000000.0,"parameter":"csy_ns_per_m",'
    '"severity":"WARNING","state":"RAISED","code":18,"value_rel":0.45,'
    '"message":"csy_ns_per_m at 0.450 of nominal, low-side WARNING threshold 0.55"}',
    '{"seq":2,"t_s":6.0,"wall_time_s":1700000000.0,"parameter":"csy_ns_per_m",'
    '"severity":"WARNING","state":"ACKNOWLEDGED","code":18,"value_rel":0.45,'
    '"message":"csy_ns_per_m WARNING acknowledged"}',
    '{"seq":3,"t_s":6.5,"wall_time_s":1700000000.0,"parameter":"node:BGN",'
    '"severity":"ADVISORY","state":"RAISED","code":48,"value_rel":null,'
    '"message":"two senders on BGN (BGN_Lat): its frames are excluded from the estimator"}',
]
OLD_ESTIMATE_LINE = ('{"t_s":6.0,"wall_time_s":1700000000.0,"ess":500.0,"params":'
                     '{"csy_ns_per_m":[18000.0,800.0],"csay_ns_per_m":[4114000.0,82280.0],'
                     '"conicity":[0.15,0.003]}}')
_TRACK0 = ('"value_rel":1.0,"last_t_s":5.9,"release_since":null,"baseline_t_s":null,'
           '"since":{"low":[null,null,null],"high":[null,null,null]}')
OLD_POLICY_V1 = (
    '{"version":1,"next_seq":4,"overrides":[],"params":{"csy_ns_per_m":{"severity":2,'
    '"side":"low","acknowledged":true,"raised_seq":1,"last":{"seq":2,"t_s":6.0,'
    '"parameter":"csy_ns_per_m","severity":2,"state":2,"code":18,"value_rel":0.45,'
    '"message":"csy_ns_per_m WARNING acknowledged"},"value_rel":0.45,"last_t_s":5.9,'
    '"release_since":null,"baseline_t_s":null,"since":{"low":[0.0,0.0,null],'
    '"high":[null,null,null]}},"csay_ns_per_m":{"severity":0,"side":"",'
    '"acknowledged":false,"raised_seq":0,"last":null,' + _TRACK0 + '},"conicity":'
    '{"severity":0,"side":"","acknowledged":false,"raised_seq":0,"last":null,' + _TRACK0 +
    '}},"senders":{"node:BGN":[3,{"seq":3,"t_s":6.5,"parameter":"node:BGN","severity":1,'
    '"state":0,"code":48,"value_rel":null,"message":"two senders on BGN (BGN_Lat): its '
    'frames are excluded from the estimator"}]}}')


def strict(obj: object) -> object:
    """``obj`` through strict JSON (no NaN/Infinity allowed) and back."""
    return json.loads(json.dumps(obj, allow_nan=False))


def test_alert_form_round_trips_with_nan_as_null():
    for alert in (ALERT, NAN_ALERT):
        form = strict(jsonform.alert_json(alert))
        assert list(form) == ["seq", "t_s", "parameter", "severity", "state", "code",
                              "value_rel", "message"]
        back = jsonform.alert_from_json(form)
        assert dataclasses.replace(back, value_rel=0.0) == dataclasses.replace(alert,
                                                                               value_rel=0.0)
        assert back.value_rel == alert.value_rel or math.isnan(back.value_rel)
    assert jsonform.alert_json(NAN_ALERT)["value_rel"] is None
    assert jsonform.alert_json(ALERT)["severity"] == "ALARM"


@pytest.mark.parametrize("bad, match", [
    ({"seq": True}, "expected integer seq"), ({"code": 1.5}, "expected integer seq"),
    ({"severity": 3}, "expected severity from"), ({"state": "raised"}, "expected severity"),
    ({"t_s": "4.25"}, "expected a number or null"),
])
def test_alert_from_json_refuses_malformed(bad, match):
    with pytest.raises((TypeError, ValueError), match=match):
        jsonform.alert_from_json({**jsonform.alert_json(ALERT), **bad})


def test_estimate_form_is_strict_json():
    form = strict(jsonform.estimate_json(NAN_EST))
    assert form == {"t_s": 1.5, "ess": None, "updated": False, "provisional": False,
                    "v_sy_mps": 0.01,
                    "v_say_mps": None, "params": {
                        "csy_ns_per_m": {"mean": 40e3, "std": 1e3},
                        "csay_ns_per_m": {"mean": None, "std": 1e5},
                        "conicity": {"mean": 0.15, "std": None}},
                    "located": None, "left_out": [], "unresolved": []}
    dead = strict(jsonform.estimate_json(dataclasses.replace(NAN_EST, left_out=("acc_bd",))))
    assert dead["left_out"] == ["acc_bd"]
    loc = Located(1.4, "csy_ns_per_m", 0.5, 0.33, math.nan, 0.0, math.inf)
    form = strict(jsonform.estimate_json(dataclasses.replace(NAN_EST, located=loc)))
    assert form["located"] == {"t_s": 1.4, "parameter": "csy_ns_per_m", "rel": 0.5,
                               "rel_lo": 0.33, "rel_hi": None, "like_lo": 0.0,
                               "like_hi": None}


def test_every_alert_writer_uses_the_one_form():
    for alert in (ALERT, NAN_ALERT):
        form = jsonform.alert_json(alert)
        line = strict(codec.alert_to_json(alert, 1.7e9))                  # state directory
        assert line == {**form, "wall_time_s": 1.7e9}
        replay = strict(replay_alert(alert))                              # replay lines
        assert set(replay) == set(form) | {"type"}
        assert replay["severity"] == form["severity"].lower()
        assert replay["value_rel"] == (None if form["value_rel"] is None
                                       else float(f"{form['value_rel']:.6g}"))
    raised = Alert(1, 1.0, "csy_ns_per_m", Severity.ALARM, AlertState.RAISED, 0x19, 0.3, "r")
    policy = AlertPolicy.restore(None, history=[raised, NAN_ALERT])
    snap = strict(policy.snapshot())                                      # policy snapshot
    assert snap["params"]["csy_ns_per_m"]["last"] == jsonform.alert_json(policy.active[0])
    assert snap["senders"]["node:BGN"][1] == jsonform.alert_json(NAN_ALERT)


def test_every_estimate_writer_uses_the_one_form():
    form = jsonform.estimate_json(NAN_EST)
    line = strict(codec.estimate_to_json(NAN_EST, 1.7e9))
    assert line == {"t_s": form["t_s"], "wall_time_s": 1.7e9, "ess": form["ess"],
                    "params": {n: [p["mean"], p["std"]] for n, p in form["params"].items()}}
    assert strict(history_row(1.5, NAN_EST))["estimates"] == form["params"]
    view = strict(estimates_view(NAN_EST, thresholds={}))
    assert {k: view[k] for k in ("t_s", "ess", "updated")} == {
        k: form[k] for k in ("t_s", "ess", "updated")}
    for name, p in form["params"].items():
        assert {k: view["parameters"][name][k] for k in ("mean", "std")} == p
    replay = strict(replay_estimate(NAN_EST))
    assert replay["csay_ns_per_m"] == {"mean": None, "std": 1e5}
    assert replay["conicity"]["std"] is None and replay["ess"] is None
    assert "left_out" not in replay and view["left_out"] == form["left_out"] == []
    dead = dataclasses.replace(NAN_EST, left_out=("acc_w1", "acc_w2"))
    assert strict(replay_estimate(dead))["left_out"] == ["acc_w1", "acc_w2"]
    view = strict(estimates_view(dead, thresholds={}))
    assert view["left_out"] == ["acc_w1", "acc_w2"]
    text = render.estimates(view).splitlines()
    assert text[1] == ("without sensors acc_w1, acc_w2 (no data: left out); what only they "
                       "show is not in these values")
    assert not any("without sensors" in line
                   for line in render.estimates(estimates_view(NAN_EST, thresholds={}))
                   .splitlines())
    weak = dataclasses.replace(dead, unresolved=("csy_ns_per_m",))
    assert strict(replay_estimate(weak))["unresolved"] == ["csy_ns_per_m"]
    assert "unresolved" not in strict(replay_estimate(dead))
    view = strict(estimates_view(weak, thresholds={}))
    assert view["unresolved"] == strict(jsonform.estimate_json(weak))["unresolved"]
    assert render.estimates(view).splitlines()[2] == (
        "unresolved by the sensors in use: csy_ns_per_m (its value is mostly what was "
        "known before)")


def test_state_directory_of_the_previous_version_loads(tmp_path: Path):
    (tmp_path / "alerts.jsonl").write_text("\n".join(OLD_ALERT_LINES) + "\n")
    (tmp_path / "estimates.jsonl").write_text(OLD_ESTIMATE_LINE + "\n")
    (tmp_path / "alert_policy.json").write_text(OLD_POLICY_V1)
    with StateStore(tmp_path, clock=lambda: 1.7e9 + 60.0) as st:
        alerts = st.read_alerts()
        estimates = st.read_estimates()
        snap = st.load_policy()
        assert not st.quarantined
    assert [(e.alert.seq, e.alert.state, e.wall_time_s) for e in alerts] == [
        (1, AlertState.RAISED, 1.7e9), (2, AlertState.ACKNOWLEDGED, 1.7e9),
        (3, AlertState.RAISED, 1.7e9)]
    assert math.isnan(alerts[2].alert.value_rel) and alerts[0].alert.value_rel == 0.45
    assert [(e.t_s, e.mean, e.std, e.ess) for e in estimates] == [
        (6.0, (18000.0, 4114000.0, 0.15), (800.0, 82280.0, 0.003), 500.0)]
    policy = AlertPolicy.restore(snap, history=[e.alert for e in alerts])
    assert [(a.seq, a.parameter, a.state) for a in policy.active] == [
        (2, "csy_ns_per_m", AlertState.ACKNOWLEDGED), (3, "node:BGN", AlertState.RAISED)]
    assert policy.next_seq == 4
    # written again in the new form (version 2), it restores to the same state
    again = AlertPolicy.restore(strict(policy.snapshot()))
    assert again.active == policy.active and again.snapshot()["version"] == 2
    # each old line is a line the current codec reads to the same records
    for line in OLD_ALERT_LINES:
        entry = codec.alert_from_json(json.loads(line))
        assert strict(codec.alert_to_json(entry.alert, entry.wall_time_s)) == json.loads(line)


def test_snapshot_with_a_nan_alert_value_is_saved(tmp_path: Path):
    """An alert restored from history with value_rel null (NaN) used to reach the
    snapshot as NaN, which the store's strict JSON refused; now it is null."""
    raised = Alert(1, 1.0, "csy_ns_per_m", Severity.WARNING, AlertState.RAISED, 0x12,
                   math.nan, "")
    policy = AlertPolicy.restore(None, history=[raised])
    with StateStore(tmp_path) as st:
        assert st.save_policy(policy.snapshot())
        back = AlertPolicy.restore(st.load_policy())
    assert back.active[0].seq == 1 and math.isnan(back.active[0].value_rel)


def test_a_malformed_snapshot_alert_is_refused():
    snap = json.loads(OLD_POLICY_V1)
    snap["params"]["csy_ns_per_m"]["last"]["severity"] = 9
    with pytest.raises(StateError, match="expected an alert object.*9 is not a valid"):
        AlertPolicy.restore(snap)
    snap = {**json.loads(OLD_POLICY_V1), "version": 2}      # version 2 has names, not ints
    with pytest.raises(StateError, match="expected an alert object.*expected severity"):
        AlertPolicy.restore(snap)


def test_judge_values():
    assert judge.value_rel(20e3, 40e3) == 0.5 and judge.value_rel(1.0, None) is None
    assert judge.sigma_rel(20e3, 2e3, 40e3) == 0.05          # max(|mean|, nominal)
    assert judge.sigma_rel(80e3, 2e3, 40e3) == 0.025
    assert judge.sigma_rel(0.0, 1.0, None) is None and judge.sigma_rel(-2.0, 1.0, None) == 0.5
    assert judge.confident(0.05, 0.05) and not judge.confident(0.0501, 0.05)
    assert not judge.confident(math.nan, 0.05) and not judge.confident(None, 0.05)
    assert judge.beyond("low", 0.55, 0.55) and not judge.beyond("low", 0.56, 0.55)
    assert judge.beyond("high", 2.0, 2.0) and not judge.beyond("high", 1.99, 2.0)


@pytest.mark.parametrize("std_rel", [0.02, 0.049, 0.051, 0.2])
def test_console_and_policy_judge_alike(std_rel):
    """A weak lateral damper (0.3 of nominal, past ALARM) with spread ``std_rel``: the
    console calls it confident exactly when the policy judges (and so raises) it."""
    config = PolicyConfig(params={"csy_ns_per_m": ParamPolicy(
        NOM[0], low_rel=(0.75, 0.55, 0.35), max_std_rel=0.05)})
    policy = AlertPolicy(config)
    mean = NOM * np.array([0.3, 1.0, 1.0])
    events = []
    for k in range(50):
        e = Estimate(k / 10, tuple(map(float, mean)),
                     (std_rel * NOM[0], 0.01 * NOM[1], 0.01 * NOM[2]), 500.0)
        events += policy.step(e)
    view = estimates_view(e, thresholds={}, max_std_rel={"csy_ns_per_m": 0.05})
    csy = view["parameters"]["csy_ns_per_m"]
    assert csy["value_rel"] == pytest.approx(0.3)
    assert csy["sigma_rel"] == pytest.approx(std_rel)
    assert csy["confident"] is (std_rel <= 0.05)
    assert bool(events) is csy["confident"]
    if events:       # a sure WARNING may come first (4 sigma past 0.55), the ALARM by 3 s
        assert max(ev.severity for ev in events) == Severity.ALARM
        assert all(ev.value_rel == csy["value_rel"] for ev in events)
