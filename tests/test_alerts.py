"""Tests of gateway.alerts.policy: thresholds, gate, holds, hysteresis, lifecycle, restore."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from gateway.alerts.policy import (
    AlertPolicy,
    ParamPolicy,
    PolicyConfig,
    alert_code,
    decode_code,
    default_params,
)
from gateway.errors import ConfigError, InputError, StateError
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL
from gateway.records import AlertState, Estimate, Located, Severity

NOM = THETA_NOMINAL.as_array()
FS_HZ = 10.0
HOLD_ONLY = PolicyConfig(sure_sigmas=1e9)
"""The noise hold alone: the tests below pin it; the sure path has its own tests."""


def est(t_s: float, csy: float = 1.0, csay: float = 1.0, con: float = 1.0,
        std_rel: float = 0.02) -> Estimate:
    """An estimate at data time t_s with means given relative to nominal."""
    mean = NOM * np.array([csy, csay, con])
    return Estimate(t_s, tuple(float(m) for m in mean),
                    tuple(float(s) for s in std_rel * np.maximum(mean, NOM)), ess=500.0)


def run(policy: AlertPolicy, t0_s: float, t1_s: float, **kw: float) -> list:
    """Feed 10 Hz estimates for t in [t0_s, t1_s) with constant relative means."""
    events = []
    for k in range(round(t0_s * FS_HZ), round(t1_s * FS_HZ)):
        events += policy.step(est(k / FS_HZ, **kw))
    return events


def brief(events: list) -> list[tuple]:
    return [(e.t_s, e.parameter, e.severity.name, e.state.name) for e in events]


def test_codes_table_and_round_trip():
    assert alert_code("csy_ns_per_m", Severity.ADVISORY, "low") == 0x11
    assert alert_code("csay_ns_per_m", Severity.ALARM, "low") == 0x16
    assert alert_code("conicity", Severity.WARNING, "high") == 0x28
    for side in ("low", "high"):
        for name in PARAM_NAMES:
            for sev in Severity:
                assert decode_code(alert_code(name, sev, side)) == (name, sev, side)
    with pytest.raises(InputError, match="expected an alert code"):
        decode_code(0x31)           # 0x30 is two senders (tests/test_two_senders_alert.py)


def test_csy_drop_warning_then_alarm_then_clear():
    p = AlertPolicy(HOLD_ONLY)
    assert run(p, 0, 10) == []
    ev = run(p, 10, 20, csy=18e3 / 40e3)       # 0.45: below advisory and warning
    assert brief(ev) == [(13.0, "csy_ns_per_m", "WARNING", "RAISED")]
    assert ev[0].code == 0x12 and ev[0].value_rel == pytest.approx(0.45) and ev[0].seq == 1
    ev = run(p, 20, 30, csy=8e3 / 40e3)        # 0.2: failed
    assert brief(ev) == [(23.0, "csy_ns_per_m", "ALARM", "RAISED")]
    assert ev[0].code == 0x13 and ev[0].seq == 2
    assert [a.severity for a in p.active] == [Severity.ALARM]
    ev = run(p, 30, 60)                         # replaced: back to nominal
    assert brief(ev) == [(35.0, "csy_ns_per_m", "ALARM", "CLEARED")]
    assert p.active == ()


def test_deescalation_clears_then_raises_lower_severity():
    p = AlertPolicy(HOLD_ONLY)
    run(p, 0, 10, csy=0.2)
    ev = run(p, 10, 30, csy=0.5)               # 0.5: inside the warning band
    assert brief(ev) == [(15.0, "csy_ns_per_m", "ALARM", "CLEARED"),
                         (15.0, "csy_ns_per_m", "WARNING", "RAISED")]
    ev = run(p, 30, 60, csy=0.58)              # within warning hysteresis (0.55 + 0.05)
    assert ev == []
    ev = run(p, 60, 80, csy=0.62)              # released from warning, still advisory
    assert brief(ev) == [(65.0, "csy_ns_per_m", "WARNING", "CLEARED"),
                         (65.0, "csy_ns_per_m", "ADVISORY", "RAISED")]


def test_minimum_duration_must_hold_continuously():
    p = AlertPolicy(HOLD_ONLY)
    for t0 in np.arange(0.0, 60.0, 3.0):       # 2.9 s low, 0.1 s nominal, repeated
        assert run(p, t0, t0 + 2.9, csy=0.45) == []
        assert run(p, t0 + 2.9, t0 + 3.0) == []


def test_hysteresis_no_flapping_around_threshold():
    """10 min hovering at the warning threshold (AR(1) wander, sd 1.5 %): raised once
    (perhaps via ADVISORY), never cleared and raised again."""
    rng = np.random.default_rng(1)
    p = AlertPolicy(HOLD_ONLY)
    events = []
    dev = 0.0
    for k in range(6000):
        dev = 0.98 * dev + math.sqrt(1 - 0.98**2) * 0.015 * rng.standard_normal()
        events += p.step(est(k / FS_HZ, csy=0.55 + dev))
    states = [(e.severity.name, e.state.name) for e in events]
    assert states[-1] == ("WARNING", "RAISED")
    assert all(s == "RAISED" for _, s in states) and len(states) <= 2


def test_confidence_gate_blocks_and_resets_hold():
    p = AlertPolicy(HOLD_ONLY)
    assert run(p, 0, 60, csy=0.45, std_rel=0.10) == []
    assert run(p, 60, 62, csy=0.45) == []
    assert run(p, 62, 62.5, csy=0.45, std_rel=0.10) == []   # gate closes mid-hold
    ev = run(p, 62.5, 70, csy=0.45)
    assert brief(ev) == [(65.5, "csy_ns_per_m", "WARNING", "RAISED")]


def test_provisional_estimates_are_not_judged_and_restart_the_hold():
    """The estimator's sensor-noise test window: however far past a threshold and
    however sure, a provisional estimate raises nothing, and the hold starts again at
    the first estimate after it."""
    p = AlertPolicy(HOLD_ONLY)
    events = [e for k in range(50) for e in p.step(dataclasses.replace(
        est(k / FS_HZ, csy=0.2, con=3.0, std_rel=0.001), provisional=True))]
    assert events == []
    ev = run(p, 5.0, 12.0, csy=0.45)
    assert brief(ev) == [(8.0, "csy_ns_per_m", "WARNING", "RAISED")]


def test_gate_uses_nominal_for_low_estimates():
    """A failed damper at 8 kNs/m with sigma 0.8 kNs/m (10 % of itself, 2 % of nominal)."""
    p = AlertPolicy(HOLD_ONLY)
    ev = []
    for k in range(100):
        e = est(k / FS_HZ, csy=0.2)
        ev += p.step(Estimate(e.t_s, e.mean, (800.0, *e.std[1:]), e.ess))
    assert brief(ev) == [(3.0, "csy_ns_per_m", "ALARM", "RAISED")]


def test_nan_and_gaps_break_continuity():
    p = AlertPolicy(HOLD_ONLY)
    assert run(p, 0, 2, csy=0.45) == []
    assert run(p, 5, 7, csy=0.45) == []        # 3 s gap: the hold restarts at 5 s
    nan = Estimate(7.0, (math.nan, *est(7).mean[1:]), est(7).std, 1.0)
    assert p.step(nan) == []
    assert p.step(est(math.nan, csy=0.45)) == []
    json.dumps(p.snapshot(), allow_nan=False)
    assert brief(run(p, 7.1, 11, csy=0.45)) == [(10.1, "csy_ns_per_m", "WARNING", "RAISED")]


def test_conicity_high_side():
    p = AlertPolicy(HOLD_ONLY)
    ev = run(p, 0, 10, con=0.32 / 0.15)
    assert brief(ev) == [(3.0, "conicity", "WARNING", "RAISED")] and ev[0].code == 0x28
    assert brief(run(p, 10, 20, con=0.41 / 0.15)) == [(13.0, "conicity", "ALARM", "RAISED")]


def test_nominal_ten_minutes_with_correlated_noise_raises_nothing():
    """600 s at 10 Hz; means wander (AR(1), 3 % sd dampers, 8 % conicity plus a +40 % Ar
    bias on conicity), std/theta 2 %, and 20 s of unconverged start (std 30 %)."""
    rng = np.random.default_rng(7)
    p = AlertPolicy(HOLD_ONLY)
    dev = np.zeros(3)
    sd = np.array([0.03, 0.03, 0.08])
    phi = 0.98
    events = []
    for k in range(6000):
        dev = phi * dev + math.sqrt(1 - phi**2) * sd * rng.standard_normal(3)
        t = k / FS_HZ
        events += p.step(est(t, 1 + dev[0], 1 + dev[1], 1.4 + dev[2],
                             std_rel=0.3 if t < 20 else 0.02))
    assert events == []


def test_iid_nominal_noise_raises_nothing():
    rng = np.random.default_rng(3)
    p = AlertPolicy(HOLD_ONLY)
    events = []
    for k in range(6000):
        r = 1 + 0.02 * rng.standard_normal(3)
        events += p.step(est(k / FS_HZ, *r))
    assert events == []


def test_failed_damper_alarmed_within_15_s_of_step():
    """An estimate converging from 1.0 to 0.25 with a 3 s time constant, unsure (std 15 %)
    for the first 4 s after the step: the issue's estimator target (15 % in 10 s)."""
    p = AlertPolicy(HOLD_ONLY)
    run(p, 0, 30)
    ev = []
    for k in range(300, 600):
        t = k / FS_HZ
        rel = 0.25 + 0.75 * math.exp(-(t - 30.0) / 3.0)
        ev += p.step(est(t, csy=rel, std_rel=0.15 if t < 34 else 0.03))
    alarms = [e for e in ev if e.severity == Severity.ALARM and e.state == AlertState.RAISED]
    assert alarms and alarms[0].t_s - 30.0 <= 15.0


def test_lifecycle_ack_escalate_clear():
    p = AlertPolicy(HOLD_ONLY)
    (raised,) = run(p, 0, 5, csy=0.7)
    assert raised.severity == Severity.ADVISORY
    ack = p.acknowledge(raised.seq, t_s=5.0)
    assert (ack.seq, ack.state, ack.severity, ack.code) == (
        raised.seq + 1, AlertState.ACKNOWLEDGED, Severity.ADVISORY, raised.code)
    assert p.active == (ack,)
    with pytest.raises(InputError, match="already ACKNOWLEDGED"):
        p.acknowledge("csy_ns_per_m", 5.0)
    with pytest.raises(InputError, match="expected the seq of an active alert"):
        p.acknowledge(999, 5.0)
    with pytest.raises(InputError, match="expected an active alert for conicity"):
        p.acknowledge("conicity", 5.0)
    with pytest.raises(InputError, match="expected a parameter"):
        p.acknowledge("nope", 5.0)
    with pytest.raises(InputError, match="expected a finite data time"):
        p.acknowledge(raised.seq, math.nan)
    with pytest.raises(InputError, match="expected a finite data time"):
        p.reset_baseline("csy_ns_per_m", math.inf)
    (esc,) = run(p, 5, 10, csy=0.3)             # escalation: new RAISED, unacknowledged
    assert (esc.severity, esc.state) == (Severity.ALARM, AlertState.RAISED)
    assert p.acknowledge("csy_ns_per_m", 10.0).state == AlertState.ACKNOWLEDGED
    ev = run(p, 10, 20)
    assert brief(ev) == [(15.0, "csy_ns_per_m", "ALARM", "CLEARED")]
    assert p.active == ()
    assert [e.seq for e in (raised, ack, esc, *ev)] == [1, 2, 3, 5]


def test_baseline_reset_clears_and_records_time():
    p = AlertPolicy(HOLD_ONLY)
    run(p, 0, 5, csay=0.3)
    (cleared,) = p.reset_baseline("csay_ns_per_m", 5.0)
    assert (cleared.state, cleared.severity, cleared.parameter) == (
        AlertState.CLEARED, Severity.ALARM, "csay_ns_per_m")
    assert p.active == () and p.baseline_times()["csay_ns_per_m"] == 5.0
    assert p.reset_baseline("csy_ns_per_m", 6.0) == []
    assert run(p, 5, 7.9, csay=0.3) == []      # the hold restarts after a reset


def test_set_threshold_validation_and_effect():
    p = AlertPolicy(HOLD_ONLY)
    p.set_threshold("csy_ns_per_m", "warning", 0.6)
    assert p.config.params["csy_ns_per_m"].low_rel == (0.75, 0.6, 0.35)
    assert brief(run(p, 0, 5, csy=0.58)) == [(3.0, "csy_ns_per_m", "WARNING", "RAISED")]
    bad = [
        (("nope", "warning", 0.5), "expected a parameter"),
        (("csy_ns_per_m", "severe", 0.5), "expected a severity"),
        (("csy_ns_per_m", Severity.WARNING, math.nan), "expected a finite"),
        (("csy_ns_per_m", Severity.WARNING, 1.0), "expected side"),
        (("csy_ns_per_m", Severity.WARNING, 0.8), "strictly decreasing"),
        (("csy_ns_per_m", Severity.ADVISORY, 0.97), "below 1 - hysteresis"),
        (("conicity", Severity.ALARM, 1.9), "strictly increasing"),
    ]
    for args, match in bad:
        with pytest.raises(InputError, match=match):
            p.set_threshold(*args)
    with pytest.raises(InputError, match="expected side"):
        p.set_threshold("csy_ns_per_m", 1, 0.5, side="high")
    p.set_threshold("conicity", Severity.ADVISORY, None, side="high")
    assert p.config.params["conicity"].high_rel == (None, 2.0, 2.67)


def test_config_validation():
    with pytest.raises(ConfigError, match="expected parameters"):
        PolicyConfig(params={"ar": ParamPolicy(1.0)})
    with pytest.raises(ConfigError, match="strictly decreasing"):
        ParamPolicy(40e3, low_rel=(0.5, 0.6, 0.3))
    with pytest.raises(ConfigError, match="raise_hold_s"):
        PolicyConfig(raise_hold_s=-1.0)
    with pytest.raises(InputError, match="expected estimate names"):
        AlertPolicy().step(Estimate(0.0, (1.0,), (0.1,), 1.0, names=("ar",)))
    assert set(default_params()) == set(PARAM_NAMES)


def test_snapshot_restore_continues_identically():
    rng = np.random.default_rng(5)
    rels = np.clip(1 - np.linspace(0, 0.9, 900) + 0.02 * rng.standard_normal(900), 0.05, 2)
    a = AlertPolicy()
    a.set_threshold("csy_ns_per_m", "advisory", 0.8)
    for k in range(450):
        a.step(est(k / FS_HZ, csy=rels[k]))
    snap = json.loads(json.dumps(a.snapshot()))   # must survive JSON
    b = AlertPolicy.restore(snap)
    assert b.config == a.config and b.next_seq == a.next_seq
    for k in range(450, 900):
        e = est(k / FS_HZ, csy=rels[k])
        assert a.step(e) == b.step(e)
    assert a.snapshot() == b.snapshot()


def test_restore_replays_history_newer_than_snapshot():
    p = AlertPolicy(HOLD_ONLY)
    snap = p.snapshot()
    history = run(p, 0, 5, csy=0.3)
    history.append(p.acknowledge("csy_ns_per_m", 5.0))
    q = AlertPolicy.restore(snap, history=history)   # crashed before saving a snapshot
    assert q.active == p.active and q.next_seq == p.next_seq == 3
    fresh = AlertPolicy.restore(None, history=history)
    assert fresh.active == p.active
    with pytest.raises(StateError, match="expected an alert-policy snapshot"):
        AlertPolicy.restore({"version": 1})
    with pytest.raises(StateError, match="expected an alert-policy snapshot"):
        AlertPolicy.restore({**snap, "version": 99})
    bad = dataclasses.replace(history[0], seq=10, code=0x99)
    with pytest.raises(StateError, match="seq 10: expected an alert code"):
        AlertPolicy.restore(snap, history=[bad])


def test_a_sure_condition_raises_after_the_short_hold() -> None:
    """Csy found at 0.2 of nominal with sigma 2 % of nominal: 7.5 sigma past the ALARM
    threshold, so the ALARM comes after ``sure_hold_s`` (0.5 s), not the 3 s hold."""
    p = AlertPolicy()
    assert run(p, 0, 10) == []
    ev = run(p, 10, 12, csy=0.2)
    assert brief(ev) == [(10.5, "csy_ns_per_m", "ALARM", "RAISED")]


def test_a_value_near_its_threshold_still_waits_the_noise_hold() -> None:
    """0.70 against the 0.75 ADVISORY threshold with sigma 2 %: 2.5 sigma, not sure."""
    p = AlertPolicy()
    ev = run(p, 0, 10, csy=0.70)
    assert brief(ev) == [(3.0, "csy_ns_per_m", "ADVISORY", "RAISED")]


def test_a_sure_run_broken_by_one_unsure_estimate_starts_again() -> None:
    """0.2 of nominal, once 0.3 (2.5 sigma past ALARM 0.35: not sure of an ALARM, still
    sure of a WARNING): the WARNING comes at 0.5 s, the ALARM 0.5 s after the break."""
    p = AlertPolicy()
    ev = run(p, 0, 0.3, csy=0.2) + run(p, 0.3, 0.4, csy=0.3) + run(p, 0.4, 1.0, csy=0.2)
    assert brief(ev) == [(0.5, "csy_ns_per_m", "WARNING", "RAISED"),
                         (0.9, "csy_ns_per_m", "ALARM", "RAISED")]


def located(t_s: float, parameter: str, rel: float, like_lo: float, like_hi: float,
            rel_lo: float | None = None, rel_hi: float | None = None,
            **kw: float) -> Estimate:
    """An estimate (wide: 25 % of nominal, never sure) that reports a fault-bank change
    with likelihood interval ``like_lo``..``like_hi`` (its redraw range: the same, or
    ``rel_lo``..``rel_hi``)."""
    return dataclasses.replace(est(t_s, std_rel=0.25, **kw), located=Located(
        t_s, parameter, rel, like_lo if rel_lo is None else rel_lo,
        like_hi if rel_hi is None else rel_hi, like_lo, like_hi))


def test_a_located_change_past_a_threshold_raises_with_its_estimate() -> None:
    """The bank located Csy at 0.49 of nominal, likely within 0.32-0.74: that whole
    interval is below the ADVISORY threshold (0.75), not the WARNING one (0.55), so an ADVISORY at
    once, though the estimate's own std (25 %) would never be sure; the next estimates
    carry the same change and raise nothing more. Judged on the estimates alone, it
    waits."""
    for act, want in ((True, [(10.0, "csy_ns_per_m", "ADVISORY", "RAISED")]), (False, [])):
        p = AlertPolicy(PolicyConfig(act_on_located=act))
        assert run(p, 0, 10) == []
        ev = p.step(located(10.0, "csy_ns_per_m", 0.49, 0.32, 0.74, csy=0.49))
        for k in range(1, 10):                      # the next estimates carry it too
            ev += p.step(dataclasses.replace(
                located(10.0, "csy_ns_per_m", 0.49, 0.32, 0.74, csy=0.49), t_s=10 + k / 10))
        assert brief(ev) == want
        if act:
            assert "located by the fault bank" in ev[0].message
            assert ev[0].value_rel == pytest.approx(0.49)


@pytest.mark.parametrize("parameter, lo, hi, want", [
    ("csy_ns_per_m", 0.16, 0.37, "WARNING"),        # below 0.55, not all below 0.35
    ("csy_ns_per_m", 0.10, 0.30, "ALARM"),
    ("csay_ns_per_m", 0.50, 0.80, None),            # straddles 0.75: the estimate decides
    ("conicity", 1.65, 3.1, "ADVISORY"),            # a rise: the lower end past 1.6
    ("conicity", 1.0, 1.9, None),                   # the healthy-data detection of 2026-11-25
])
def test_a_located_change_raises_the_level_its_whole_interval_is_past(
        parameter: str, lo: float, hi: float, want: str | None) -> None:
    p = AlertPolicy()
    ev = p.step(located(5.0, parameter, (lo * hi) ** 0.5, lo, hi))
    assert [a.severity.name for a in ev] == ([want] if want else [])
    assert all(a.parameter == parameter for a in ev)


@pytest.mark.parametrize("like, redraw, want", [
    ((0.16, 0.86), (0.33, 0.74), None),             # 2 x noise, seed 707: the range claims
    ((0.43, 0.66), (0.33, 0.76), "ADVISORY"),       # 5 sensors: the likelihood is narrower
])
def test_a_located_change_is_judged_on_its_likelihood_interval_not_its_redraw_range(
        like: tuple[float, float], redraw: tuple[float, float], want: str | None) -> None:
    """The redraw range is a fixed three grid steps; what the data allow is the likelihood
    interval, which can be wider (noisy data, 3 sensors) or narrower (5 sensors)."""
    p = AlertPolicy()
    ev = p.step(located(5.0, "csy_ns_per_m", 0.5, *like, *redraw))
    assert [a.severity.name for a in ev] == ([want] if want else [])
    if want:
        assert f"likely {like[0]:.3f}-{like[1]:.3f}" in ev[0].message


def test_a_refined_location_raises_once_its_interval_has_passed_the_threshold() -> None:
    """The fault bank's refinement publishes the same change again, later, with a
    narrower interval (a new ``Located.t_s``): the first straddles the ADVISORY threshold
    (0.75) and raises nothing; the refined one lies below it and raises with its own
    estimate; a third, narrower still but past no further threshold, raises nothing."""
    p = AlertPolicy()
    assert run(p, 0, 10) == []
    ev = p.step(located(10.0, "csy_ns_per_m", 0.49, 0.25, 0.85, csy=0.8))
    assert ev == []
    ev = p.step(located(10.25, "csy_ns_per_m", 0.5, 0.36, 0.70, csy=0.78))
    assert brief(ev) == [(10.25, "csy_ns_per_m", "ADVISORY", "RAISED")]
    assert "likely 0.360-0.700" in ev[0].message
    assert p.step(located(10.5, "csy_ns_per_m", 0.5, 0.40, 0.66, csy=0.75)) == []


def test_a_located_change_on_another_parameter_raises_nothing_here() -> None:
    p = AlertPolicy()
    ev = p.step(located(5.0, "csay_ns_per_m", 0.2, 0.13, 0.30))
    assert [(a.parameter, a.severity.name) for a in ev] == [("csay_ns_per_m", "ALARM")]


def unresolved_run(policy: AlertPolicy, t0_s: float, t1_s: float, names: tuple[str, ...],
                   **kw: float) -> list:
    """:func:`run` with every estimate naming ``names`` unresolved."""
    events = []
    for k in range(round(t0_s * FS_HZ), round(t1_s * FS_HZ)):
        events += policy.step(dataclasses.replace(est(k / FS_HZ, **kw), unresolved=names))
    return events


def test_an_unresolved_parameter_is_neither_raised_nor_cleared() -> None:
    """With the body node out of a 3-sensor set Csy is unresolved: its mean is what the
    filters knew before, so a Csy at 0.2 of nominal with a narrow sigma raises nothing
    while Csay, resolved, raises its ALARM beside it. Once Csy is resolved again its
    value is judged with fresh hold timers. An ALARM raised before stays while Csy is
    unresolved, even where the stale mean is back at nominal, and clears once a
    resolved estimate says so."""
    p = AlertPolicy(HOLD_ONLY)
    csy = ("csy_ns_per_m",)
    ev = unresolved_run(p, 0, 20, csy, csy=0.2, csay=0.2)
    assert {(e.parameter, e.severity.name) for e in ev} == {("csay_ns_per_m", "ALARM")}
    ev = run(p, 20, 30, csy=0.2, csay=0.2)
    assert [(e.parameter, e.severity.name, e.state.name) for e in ev] == [
        ("csy_ns_per_m", "ALARM", "RAISED")]
    assert ev[0].t_s >= 20.0 + p.config.raise_hold_s - 1e-9
    assert unresolved_run(p, 30, 60, csy, csy=1.0, csay=0.2) == []
    ev = run(p, 60, 80, csy=1.0, csay=0.2)
    assert [(e.parameter, e.state.name) for e in ev] == [("csy_ns_per_m", "CLEARED")]


def test_a_located_change_of_an_unresolved_parameter_still_raises() -> None:
    """The bank's location is evidence from the data themselves: a Csy change located
    well below the ALARM threshold raises though the estimate calls Csy unresolved."""
    p = AlertPolicy()
    e = dataclasses.replace(located(5.0, "csy_ns_per_m", 0.2, 0.1, 0.3, csy=0.2),
                            unresolved=("csy_ns_per_m",))
    assert [a.severity.name for a in p.step(e)] == ["ALARM"]
