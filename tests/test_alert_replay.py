"""Alerts through the whole pipeline under replay: a failed damper alarms, nominal does not."""

from __future__ import annotations

import json

import pytest

from firmware_sim.output import write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation


def _replay_alerts(cli, tmp_path, scenario: str, duration_s: float,
                   particles: int | None) -> dict:
    """Simulate ``scenario`` to a CAN log and replay it; ``particles`` None: the service's
    default (m = 1000, fast mode, fault bank)."""
    log = tmp_path / f"{scenario}.log"
    write_log(Simulation(get_scenario(scenario), SimConfig(duration_s=duration_s, seed=21))
              .messages(), log)
    extra = [] if particles is None else ["--particles", str(particles)]
    proc = cli("gateway", "replay", str(log), "--report", str(tmp_path / "r.json"),
               "--no-progress", *extra, timeout=1500)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads((tmp_path / "r.json").read_text())


@pytest.mark.slow
def test_failed_lateral_damper_alerts_within_5_s_and_alarms_within_10_s(cli, tmp_path):
    """Csy 40 -> 10 kNs/m at half-time, through the whole replay path at the service's
    defaults: the first alert on Csy within 5 s of the step and the ALARM within 10 s
    (issue 15's worst-case targets; before the fault bank: an ALARM within 15 s), nothing
    before the fault, nothing on another parameter. The fault bank's located change is
    carried by the estimates from the worker to the policy and to the JSON Lines, its
    likelihood interval holds the truth, and the first alert is that change, raised at
    once, exactly when the interval lies wholly below the ADVISORY threshold
    (docs/alerts.md "Located changes")."""
    report = _replay_alerts(cli, tmp_path, "lateral-failing", 50.0, None)
    t_fail = 25.0                                     # the step is at half-time
    t0 = report["history"][0]["t_s"]                  # data time of the first grid point
    raised = [a for a in report["alerts"] if a["state"] == "raised"]
    assert raised and all(a["parameter"] == "csy_ns_per_m" for a in raised), raised
    assert all(a["t_s"] - t0 > t_fail for a in report["alerts"])   # nothing before the fault
    assert raised[0]["t_s"] - t0 - t_fail <= 5.0, raised[0]
    lines = [json.loads(x) for x in (tmp_path / "r.jsonl").read_text().splitlines()]
    located = [x["located"] for x in lines if x["type"] == "estimate" and "located" in x]
    assert located and located[0]["parameter"] == "csy_ns_per_m", located[:1]
    first = located[0]
    assert first["like_lo"] <= 0.25 <= first["like_hi"], first
    assert ("located by the fault bank" in raised[0]["message"]) == (first["like_hi"] <= 0.75), (
        first, raised[0])
    alarms = [a for a in raised if a["severity"] == "alarm"]
    assert alarms and alarms[0]["t_s"] - t0 - t_fail <= 10.0, alarms
    final = report["estimates"]["csy_ns_per_m"]["mean"]
    assert abs(final / 10e3 - 1) < 0.15


@pytest.mark.slow
def test_a_damper_failing_while_the_train_accelerates_is_alerted(cli, tmp_path):
    """Csy 40 -> 10 kNs/m at half-time while the speed ramps 25 -> 40 m/s, so the model,
    the steady gains and the fault bank's look-back restart at every 0.2 % of speed: the
    first alert on Csy within 5 s, the ALARM within 10 s, nothing before the fault or on
    another parameter, and Csy within 15 % of its new value at the end."""
    report = _replay_alerts(cli, tmp_path, "lateral-failing-accelerating", 30.0, None)
    t_fail = 15.0
    t0 = report["history"][0]["t_s"]
    raised = [a for a in report["alerts"] if a["state"] == "raised"]
    assert raised and all(a["parameter"] == "csy_ns_per_m" for a in raised), raised
    assert all(a["t_s"] - t0 > t_fail for a in report["alerts"])
    assert raised[0]["t_s"] - t0 - t_fail <= 5.0, raised[0]
    alarms = [a for a in raised if a["severity"] == "alarm"]
    assert alarms and alarms[0]["t_s"] - t0 - t_fail <= 10.0, alarms
    assert abs(report["estimates"]["csy_ns_per_m"]["mean"] / 10e3 - 1) < 0.15


@pytest.mark.slow
def test_ten_nominal_minutes_raise_no_alert(cli, tmp_path):
    report = _replay_alerts(cli, tmp_path, "nominal", 600.0, 250)
    assert report["alerts"] == []
    assert report["history"][-1]["t_s"] - report["history"][0]["t_s"] > 595


@pytest.mark.slow
def test_pipeline_reaches_the_estimator_accuracy_on_the_paper_scenario(cli, tmp_path):
    """Simulator -> CAN log -> the service pipeline: the paper's Sec. 4.2 vehicle, 3 sensors,
    within 10 % after 5 s (the estimator issue's 3-sensor target)."""
    log = tmp_path / "paper.log"
    write_log(Simulation(get_scenario("paper"), SimConfig(duration_s=5.0, seed=0)).messages(),
              log)
    proc = cli("gateway", "replay", str(log), "--report", str(tmp_path / "r.json"),
               "--particles", "1000", "--no-progress", timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    est = json.loads((tmp_path / "r.json").read_text())["estimates"]
    truth = {"csy_ns_per_m": 20e3, "csay_ns_per_m": 3000e3, "conicity": 0.15}
    for name, value in truth.items():
        assert abs(est[name]["mean"] / value - 1) < 0.10, (name, est[name])
