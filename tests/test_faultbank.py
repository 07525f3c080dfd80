"""The fault-hypothesis bank: its CUSUM, and abrupt faults found and tracked by the RBPF.

The campaign's short form (issue 15): simulator truth with a damper step, the service's
filter (fast mode, m = 1000), fresh data seeds (``firmware_sim.studies.detection``).
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.detection import fault_data, fault_row
from firmware_sim.studies.filtering import FS_HZ, V_MPS, FilterOptions, run, service_filter
from gateway.errors import EstimatorError
from gateway.estimator.faultbank import (
    _HOLD,
    _RUNNER,
    LIKELY_NATS,
    Detection,
    FaultBank,
    FaultBankConfig,
    _cusum_path,
)
from gateway.estimator.kalman import from_lanes, to_lanes
from gateway.estimator.noisestart import NoiseCheckedStart
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.coordinates import NZ
from gateway.model.vehicle import AR_PAPER_DEFAULT
from gateway.records import Sample


def test_vectorised_cusum_is_pages_recursion() -> None:
    rng = np.random.default_rng(0)
    d = rng.normal(-0.2, 1.0, size=(500, 4))
    g0 = np.array([0.0, 3.0, 0.5, 7.0])
    got = _cusum_path(g0, d)
    g, want = g0.copy(), np.empty_like(d)
    for t in range(len(d)):
        g = np.maximum(0.0, g + d[t])
        want[t] = g
    np.testing.assert_allclose(got, want, atol=1e-12)


@pytest.mark.parametrize("bad", [dict(factors=(0.5, 1.0)), dict(factors=()),
                                 dict(factors=(0.5, 0.5)), dict(factors=(-0.5,)),
                                 dict(h_nats=0.0), dict(locate_s=-1.0),
                                 dict(locate_cov_scale=0.5), dict(replay_cov_scale=0.9),
                                 dict(locate_max_s=0.5),
                                 dict(replay_s=-1.0), dict(redraw_from="prior"),
                                 dict(runner_by="watch"), dict(located_by="cusum")])
def test_bad_bank_settings_are_refused(bad: dict) -> None:
    with pytest.raises(EstimatorError, match="expected"):
        FaultBankConfig(**bad)


def _samples(Y: np.ndarray) -> list[Sample]:
    return [Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=V_MPS) for k in range(len(Y))]


@pytest.mark.slow
@pytest.mark.parametrize("parameter, factor, sensors, seed",
                         [(0, 0.25, 3, 11), (1, 0.5, 5, 12)])
def test_abrupt_fault_is_found_on_its_parameter_and_tracked(parameter: int, factor: float,
                                                            sensors: int, seed: int) -> None:
    """A damper step at 8 s: the bank decides on the right parameter within 3 s, on no
    other, and the estimate stays within 15 % of the new value from +5 s (the issue's
    target: alert at +3 s median, within 15 % by +10 s)."""
    row = fault_row(parameter, factor, sensors, seed, seconds=14.0, fault_at_s=8.0)
    assert row["detect_s"] is not None and row["detect_s"] <= 3.0, row
    assert row["wrong"] == 0 and row["before"] == 0, row
    assert row["track_s"] is not None and row["track_s"] <= 5.0, row


@pytest.mark.slow
@pytest.mark.parametrize("sensors, seed", [(3, 19), (5, 23)])
def test_conicity_rise_is_located_at_its_value(sensors: int, seed: int) -> None:
    """lambda x 1.6 at 8 s. The step turns the unobservable static yaw set-up into a
    transient; filters that carried an arbitrary amount of it located the rise at
    1.54 x (3 sensors, seed 19) and 1.55 x (5 sensors, seed 23) the truth, and the
    estimate was not within 15 % 4 s later. The located value is within 15 % of the
    truth, and the estimate within 15 % by +3 s."""
    row = fault_row(2, 1.6, sensors, seed, seconds=12.0, fault_at_s=8.0)
    assert row["detect_s"] is not None and row["detect_s"] <= 3.0, row
    assert 0.85 <= row["located_rel"] <= 1.15, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row
    assert row["track_s"] is not None and row["track_s"] <= 3.0, row


@pytest.mark.slow
@pytest.mark.parametrize("factor", [0.25, 0.5])
def test_the_location_is_fair_to_the_new_value(factor: float) -> None:
    """Csy x 0.25 and x 0.5 at 8 s, 3 sensors, seed 42. The location grid used to run
    steady gains from the leading hypothesis's state, estimated under another value; the
    slow mode carried that error through the phase. Here the steady location put
    x 0.25 at 1.93 x the truth (outside its redraw range), and for x 0.5 found no
    change at all (detected only at +4.3 s). With the exact recursion from a widened
    covariance the located value is within 25 % of the truth and decided by +2.5 s."""
    row = fault_row(0, factor, 3, 42, seconds=18.0, fault_at_s=8.0)
    assert row["detect_s"] is not None and row["detect_s"] <= 2.5, row
    assert 0.8 <= row["located_rel"] <= 1.25, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row


@pytest.mark.slow
@pytest.mark.parametrize("fault_at_s", [8.0, 8.025])
def test_the_replay_starts_at_the_changes_sample(fault_at_s: float) -> None:
    """Csy x 0.25 at 42.5 m/s, 5 sensors, seed 4902, the step on a look-back snapshot
    (8.0 s) and half-way between two (8.025 s). A replay started one sample before the
    step reads it as a smaller drop: from the snapshots alone the first location was at
    1.24 x and 1.61 x the truth, its likelihood interval 0.269-0.356 and 0.35-0.465 of
    nominal (the truth 0.25 outside both), and the ALARM came at +1.6 s and +3.7 s.
    Started at the change's sample, the located value is within 12 % of the truth, the
    interval holds it, and the ALARM comes with the first alert."""
    row = fault_row(0, 0.25, 5, 4902, seconds=18.0, fault_at_s=fault_at_s)
    assert 0.9 <= row["located_rel"] <= 1.12, row
    lo, hi = row["located_like"]
    assert lo <= 0.25 <= hi, row
    assert row["alarm_s"] is not None and row["alarm_s"] <= row["alert_s"] + 0.1, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row


@pytest.mark.slow
def test_a_crossing_that_names_the_wrong_parameter_locates_the_runner_up_at_once() -> None:
    """Csy x 0.25 at 8.025 s, 3 sensors, seed 4902. A quarter second after the step the
    conicity's CUSUM leads (lambda x 2.5 at 34.9 nats, Csy x 0.25 at 7.1), and its
    location finds no change after 2.3 s. Watching again from scratch then found Csy at
    +5.2 s, the campaign's one first alert after +5 s (2026-11-29). Locating the
    runner-up, Csy, from the look-back before the first confirmation finds it at the
    end of that location, its interval holding the truth. Both with the confirmation
    locating the crossing's own parameter (``located_by = "crossing"``): since
    2026-11-30's fifteenth session the service's bank asks the look-back's search at the
    confirmation and locates Csy at once (tests/test_located_by_search.py)."""
    old, row = (fault_row(0, 0.25, 3, 4902, seconds=18.0, fault_at_s=8.025,
                          options=FilterOptions(runner_up=r, located_by="crossing"))
                for r in (False, True))
    assert old["detect_s"] is not None and old["detect_s"] > 4.0, old   # the case's premise
    assert row["detect_s"] is not None and row["detect_s"] <= 3.0, row
    lo, hi = row["located_like"]
    assert lo <= 0.25 <= hi and 0.8 <= row["located_rel"] <= 1.25, row
    assert row["alarm_s"] is not None and row["alarm_s"] <= row["detect_s"] + 0.2, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row


@pytest.mark.slow
def test_a_location_runs_once_however_often_the_estimator_rescans_it(monkeypatch) -> None:
    """The estimator scans the bank ahead and rewinds it where a resample stops the
    particles first, so one confirmation reached the location two to four times, each a
    change-time search and replay. Now the replay runs once per distinct state, and the
    run's estimates and detections are the same bits as with every call computed. The
    record's rescan was found with every particle's gains solved at a move, which it
    keeps (``gain_fit`` False: with the fit its Monte Carlo path reaches no rescan)."""
    th, Y = fault_data(0, 0.25, 3, 4902, 18.0, 8.025)
    solved = FilterOptions(gain_fit=False)
    calls: dict[str, int] = {"locate": 0, "computed": 0}
    locate, now = FaultBank._locate, FaultBank._locate_now

    def counted_locate(self, *a, **k):
        calls["locate"] += 1
        return locate(self, *a, **k)

    def counted_now(self, *a, **k):
        calls["computed"] += 1
        return now(self, *a, **k)

    monkeypatch.setattr(FaultBank, "_locate", counted_locate)
    monkeypatch.setattr(FaultBank, "_locate_now", counted_now)
    est, found, _ = run(Y, service_filter(3, 4902, solved))
    assert found and found[0][1] == "csy_ns_per_m", found
    assert calls["computed"] < calls["locate"], calls
    monkeypatch.setattr(FaultBank, "_memo_key", lambda self, *a: object())   # never equal
    calls.update(locate=0, computed=0)
    est2, found2, _ = run(Y, service_filter(3, 4902, solved))
    assert calls["computed"] == calls["locate"], calls
    assert found2 == found
    assert [(e.t_s, e.mean, e.std) for e in est2] == [(e.t_s, e.mean, e.std) for e in est]


@pytest.mark.slow
def test_an_inconclusive_location_sums_on_until_it_decides() -> None:
    """Csy x 0.5 at 8 s, 3 sensors, 2 x the model's sensor noise, seed 93. Its first
    location ends with the best value ahead of the reference by less than h/2; with
    the location phase fixed at 1 s the bank never detects the change in 10 s. Summing
    on (up to ``locate_max_s``) detects it on Csy, inside the redraw range. Both
    located from the confirmation (no replay), the location this rule was built for."""
    fixed, row = (fault_row(0, 0.5, 3, 93, seconds=18.0, fault_at_s=8.0, noise_scale=2.0,
                            options=FilterOptions(locate_max_s=m, replay_s=0.0))
                  for m in (1.0, None))
    assert fixed["detect_s"] is None and fixed["locate_max_s"] == 1.0, fixed
    assert row["detect_s"] is not None and row["detect_s"] <= 5.0, row
    assert row["detect_s"] - row["confirmed_s"] > 1.0, row          # summed on
    assert 1 / 1.52 <= row["located_rel"] <= 1.52, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row


@pytest.mark.slow
def test_the_location_replays_the_change_and_decides_at_the_confirmation() -> None:
    """Csy x 0.5 at 8 s, 3 sensors, 2 x the model's sensor noise, seed 93: the CUSUM
    crosses about 3 s after the change. Located from the confirmation on, the change was
    decided a second later still, and first alerted at +5.8 s. Replaying from the
    change point, the grid has more than ``locate_s`` of data at the confirmation: the
    change is decided there, on Csy, with the truth in the redraw range, and alerted
    within the issue's 5 s."""
    old, new = (fault_row(0, 0.5, 3, 93, seconds=14.0, fault_at_s=8.0, noise_scale=2.0,
                          options=FilterOptions(replay_s=r)) for r in (0.0, None))
    assert new["replay_s"] == 2.0 and old["replay_s"] == 0.0
    assert old["confirmed_s"] == new["confirmed_s"] > 1.0, (old, new)   # same watch phase
    # the rows keep 3 decimals, so compare at that precision (4.18 - 3.18 < 1.0 in floats)
    assert round(old["detect_s"] - old["confirmed_s"], 3) >= 1.0, old
    assert new["detect_s"] == new["confirmed_s"], new
    assert 1 / 1.52 <= new["located_rel"] <= 1.52, new
    assert new["alert_s"] is not None and new["alert_s"] <= 5.0, new
    assert new["wrong"] == 0 and new["before"] == 0 and new["alerts_healthy"] == 0, new


@pytest.mark.slow
def test_a_replayed_location_at_20_mps_alerts_within_the_targets() -> None:
    """Csy x 0.5 at 8 s, 3 sensors, 20 m/s: the case the replayed location's start
    covariance was changed for (docs/estimator.md, "The replayed location starts from
    10 x its steady covariance"). Four fresh seeds, chosen before the runs: the first
    alert at +3 s median and +5 s at worst, on Csy, with the truth inside every located
    likelihood interval and nothing on a healthy parameter."""
    rows = [fault_row(0, 0.5, 3, seed, seconds=14.0, fault_at_s=8.0, speed_mps=20.0)
            for seed in (3601, 3602, 3603, 3604)]
    assert all(r["replay_cov_scale"] == 10.0 for r in rows)
    alerts = [np.inf if r["alert_s"] is None else r["alert_s"] for r in rows]
    assert np.median(alerts) <= 3.0 and max(alerts) <= 5.0, rows
    for r in rows:
        assert r["located_like"] is not None, r
        assert r["located_like"][0] <= 0.5 <= r["located_like"][1], r
        assert r["wrong"] == 0 and r["before"] == 0 and r["alerts_healthy"] == 0, r


@pytest.mark.slow
def test_checkpoint_while_watching_keeps_the_look_back() -> None:
    """Checkpoint while the bank watches, before a Csy x 0.25 step at 6 s: the restored
    filter holds the same look-back and gives the same estimates and detection, bit for
    bit. A checkpoint from before the look-back (no look-back arrays, no ``replay_s``)
    restores without a replay, as it ran."""
    from gateway.estimator import checkpoint as ckpt

    _, Y = fault_data(0, 0.25, 3, seed=14, seconds=10.0, fault_at_s=6.0)
    a = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=256, sensors=3, seed=14, mode="fast"))
    smp = _samples(Y)
    k = int(5.9 * FS_HZ)
    a.run(smp[:k], output_every=100)
    assert a._bank is not None and a._bank.active and a._bank.lookback.count > 1000
    b = RBPF.restore(a.checkpoint())
    assert b._bank is not None
    for key, arr in a._bank.lookback.arrays().items():
        np.testing.assert_array_equal(b._bank.lookback.arrays()[key], arr, err_msg=key)
    ea, eb = (f.run(smp[k:], output_every=50) for f in (a, b))
    assert a.n_fault_detections == b.n_fault_detections >= 1
    assert a.last_fault() == b.last_fault()
    assert [(e.mean, e.std, e.located) for e in ea] == [(e.mean, e.std, e.located) for e in eb]
    meta, arrays = ckpt.unpack(a.checkpoint())
    for key in [key for key in arrays if key.startswith("bank_lb_")]:
        del arrays[key]
    del meta["config"]["faults"]["replay_s"]
    del meta["config"]["faults"]["redraw_from"]
    c = RBPF.restore(ckpt.pack(meta, arrays))
    assert c.config.faults is not None and c.config.faults.replay_s == 0.0
    assert c.config.faults.redraw_from == "range"
    c.run(smp[k:], output_every=50)


def _locating_bank(seed: int) -> tuple[RBPF, list[Sample], int]:
    """A 256-particle filter on a Csy x 0.25 step at 6 s, stepped until its bank
    locates; the filter, the samples and the index of the next sample."""
    _, Y = fault_data(0, 0.25, 3, seed=seed, seconds=12.0, fault_at_s=6.0)
    a = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=256, sensors=3, seed=seed, mode="fast"))
    smp = _samples(Y)
    k = 0
    while not (a._bank is not None and a._bank.locating):
        a.step(smp[k])
        k += 1
        assert k < len(smp), "the bank never started locating"
    return a, smp, k


@pytest.mark.slow
def test_a_location_that_finds_nothing_restarts_the_filters_from_the_reference() -> None:
    """A location phase whose best value does not beat the reference (its sums set
    below h/2 here) ends without a detection, and every filter continues from the
    reference's state: the grid's states fit only their own values. No runner-up is
    pending here (set so: whether the watch left one depends on the record's path;
    with one, the bank locates it next, :meth:`FaultBank._runner_up`)."""
    a, _, _ = _locating_bank(14)
    bank = a._bank
    assert bank is not None
    bank.g[:] = np.linspace(-5.0, 5.0, bank.n_hyp)
    bank.vec[_RUNNER] = 0.0
    ref_state = bank._state_of(0)
    assert bank._located(10.0) is None and not bank.locating and bank.active
    x = from_lanes(bank.x, bank.m, (NZ,))
    np.testing.assert_array_equal(x, np.repeat(ref_state[None], bank.m, 0))
    assert np.all(bank.g == 0.0) and bank.count == 0


@pytest.mark.slow
def test_a_checkpoint_without_the_location_covariances_restarts_them() -> None:
    """A checkpoint written while locating by a version without ``bank_P``: the grid's
    covariances start again from the widened steady ones, and the filter runs on."""
    from gateway.estimator import checkpoint as ckpt

    a, smp, k = _locating_bank(14)
    meta, arrays = ckpt.unpack(a.checkpoint())
    del arrays["bank_P"]
    b = RBPF.restore(ckpt.pack(meta, arrays))
    assert b._bank is not None and b._bank.locating
    np.testing.assert_array_equal(b._bank.P, b._bank._start_cov())
    b.run(smp[k:], output_every=50)
    assert b.n_fault_detections >= 1


@pytest.mark.slow
def test_healthy_data_raise_no_detection() -> None:
    """30 s of nominal data, 3 and 5 sensors: the bank starts and never decides."""
    for sensors in (3, 5):
        _, Y = fault_data(None, 1.0, sensors, seed=13, seconds=30.0, fault_at_s=0.0)
        filt = service_filter(sensors, 13)
        filt.run(_samples(Y), output_every=100)
        assert isinstance(filt, NoiseCheckedStart) and filt.result is not None
        assert not any(filt.result.replaced)          # the simulator's noise is the model's
        bank = filt.inner._bank
        assert bank is not None and bank.active
        assert filt.n_fault_detections == 0 and filt.n_detections == 0


@pytest.mark.slow
def test_checkpoint_while_locating_restores_bit_exact() -> None:
    """Checkpoint in the middle of the location phase; both filters then give the same
    estimates, bit for bit, through the detection and after it."""
    a, smp, k = _locating_bank(14)
    b = RBPF.restore(a.checkpoint())
    ea = a.run(smp[k:], output_every=50)
    eb = b.run(smp[k:], output_every=50)
    assert a.n_fault_detections == b.n_fault_detections >= 1
    assert [(e.mean, e.std, e.located) for e in ea] == [(e.mean, e.std, e.located) for e in eb]


@pytest.mark.slow
def test_block_path_equals_per_sample_path_through_a_detection() -> None:
    _, Y = fault_data(1, 0.3, 3, seed=15, seconds=11.0, fault_at_s=6.0)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=128, sensors=3, seed=15, mode="fast")
    a, b = RBPF(cfg), RBPF(cfg)
    smp = _samples(Y)
    ea = a.run(smp, output_every=100)
    eb_all = [b.step(s) for s in smp]
    eb = eb_all[99::100]
    assert a.n_fault_detections == b.n_fault_detections >= 1
    assert a.last_fault() == b.last_fault()
    assert [e.mean for e in ea] == [e.mean for e in eb]
    # every estimate within 2 s of data after a detection (or a refinement's look that
    # moved its interval) carries it, whichever path
    la = [e.located for e in ea if e.located is not None]
    lb = [e.located for e in eb if e.located is not None]
    assert la == lb
    t_det = a.last_fault()
    assert t_det is not None and a.n_fault_detections == 1
    times = sorted({loc.t_s for loc in la})
    assert times[0] == t_det[0]
    refine_s = cfg.faults.refine_s if cfg.faults is not None else 0.0
    assert all(0.0 < t - t_det[0] <= refine_s + 1e-9 for t in times[1:])
    first = [e for e in eb_all if e.located is not None and e.located.t_s == times[0]]
    assert 0.0 <= first[0].t_s - times[0] <= 1.5e-3         # from the next sample on
    assert first[-1].t_s - times[0] <= 2.0 + 1.5e-3
    last = la[0]
    assert last.parameter == "csay_ns_per_m" and last.rel_lo < last.rel < last.rel_hi
    assert last.rel / last.rel_lo == pytest.approx(last.rel_hi / last.rel)


def _peak_after_refresh(bank: FaultBank, seg: np.ndarray, t0_s: float, null_units: float) -> float:
    """The largest CUSUM over ``seg`` after the bank's filters were given ``null_units``
    of their static-yaw null vector and the reference moved lambda by +3 %; inf if it
    crossed into the location phase."""
    assert bank._model is not None
    x = from_lanes(bank.x, bank.m, (NZ,))
    v0 = bank._model[1](bank.hypotheses()[:, :3])
    bank.x = to_lanes(x + null_units * v0)   # unobservable: no likelihood moves
    bank.refresh(bank.ref * np.array([1.0, 1.0, 1.03]))
    bank.g[:] = 0.0
    peak = 0.0
    for j in range(0, len(seg), 10):
        assert bank.scan(seg[j:j + 10], np.ones(10, dtype=bool), t0_s + j / FS_HZ,
                         1.0 / FS_HZ) is None
        peak = max(peak, np.inf if bank.locating else float(bank.g.max()))
    return peak


@pytest.mark.parametrize("sensors", [3, 5])
def test_a_moved_reference_does_not_turn_the_static_yaw_into_a_cusum_rise(sensors: int
                                                                          ) -> None:
    """Healthy data. Between resample-moves the bank's filters pick up some of the
    unobservable static-yaw set-up (it random-walks: up to 16 units on a 600 s healthy
    run), then the cloud's mean moves and the reference with it. Kept into the new
    thetas, that component was a transient the data never had: on a 600 s healthy run
    (seed 4, 3 sensors) refreshes lifted a CUSUM to 33 nats, and one crossed and located
    lambda x 1.39; here 8 units and lambda +3 % lifted it past the 25-nat threshold.
    The CUSUMs' peak over the next second is that of filters without the component."""
    _, Y = fault_data(None, 1.0, sensors, seed=16, seconds=9.0, fault_at_s=0.0)
    filt = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=256, sensors=sensors, seed=16,
                           mode="fast"))
    smp = _samples(Y)
    k = 0
    while not (filt._bank is not None and filt._bank.active and not filt._bank.vec[_HOLD]):
        filt.step(smp[k])             # until the bank runs and its start hold is over
        k += 1
        assert k < 7000, "the bank never started"
    bank = filt._bank
    assert bank is not None and bank._model is not None
    seg = np.array([s.values for s in smp[k:k + int(FS_HZ)]])
    snap = bank.snapshot()
    clean = _peak_after_refresh(bank, seg, smp[k].t_s, 0.0)
    bank.rewind(snap)
    carried = _peak_after_refresh(bank, seg, smp[k].t_s, 8.0)
    assert clean < bank.config.h_nats / 2, clean
    assert abs(carried - clean) < 0.5, (carried, clean)


def _first_decisive_row(g_sum: np.ndarray, left: int, n_max: int, n_min: int, n_loc: int,
                        half: float) -> int | None:
    """The location phase's end, sample by sample (what ``_located_row`` vectorises)."""
    for r in range(min(left, len(g_sum))):
        n = n_max - left + r + 1
        row = g_sum[r]
        best = int(np.argmax(row))
        lead = row[best]
        far = [row[i] for i in range(len(row)) if abs(i - best) >= 3]
        if n >= n_min and lead > half and lead - max(far) >= half:
            return r                                   # the early stop
        if n >= n_loc and (lead > half or not lead > 0.0):
            return r                                   # decided: a change, or none
    return left - 1 if left <= len(g_sum) else None


@pytest.mark.parametrize("left, min_s, peak", [
    (3000, 1.0, 0.04), (3000, 1.0, 0.008), (3000, 1.0, 0.002), (3000, 1.0, -0.01),
    (3000, 0.1, 0.04), (2500, 1.0, 0.04), (1700, 1.0, 0.008), (3000, 2.0, 0.04),
    (300, 1.0, 0.002)])
def test_location_ends_at_the_first_decisive_sample(left: int, min_s: float, peak: float
                                                    ) -> None:
    """The location sums stop at the first sample where, after ``locate_min_s``, the
    best grid value beats the reference and every value three or more grid steps away
    by h/2 (the early stop); or, after ``locate_s``, the best value beats the reference
    by h/2 or not at all; else at ``locate_max_s``. A block that starts inside the phase
    counts the samples already summed."""
    cfg = FaultBankConfig(locate_min_s=min_s)
    bank = FaultBank(cfg, n_params=3, fs_hz=FS_HZ, ar_paper=1.0)
    rng = np.random.default_rng(3)
    k, J = 3000, bank.n_hyp
    slope = np.abs(7 - np.arange(J)) * -0.02 + peak           # nats per sample, peak at 7
    d = slope[None] + rng.normal(0.0, 0.05, (k, J))         # per-sample ratios
    n_max, n_loc = round(cfg.locate_max_s * FS_HZ), round(cfg.locate_s * FS_HZ)
    want = _first_decisive_row(np.cumsum(d, axis=0), left, n_max, round(min_s * FS_HZ),
                               n_loc, 12.5)
    assert bank._located_row(d, left) == want
    if left == n_max and min_s >= 1.0:
        if peak == 0.04 or peak < 0:
            assert want == n_loc - 1            # decided at locate_s, either way
        elif peak == 0.008:
            assert want is not None and n_loc - 1 < want < n_max - 1   # decided later
        else:
            assert want == n_max - 1            # never decisive: the longest phase
    if min_s == 0.1:
        assert want is not None and 100 <= want < n_loc - 1    # the early stop


@pytest.mark.slow
@pytest.mark.parametrize("parameter, factor, sensors", [(0, 0.25, 5), (0, 0.5, 3)])
def test_early_location_keeps_the_truth_in_the_redraw_range(parameter: int, factor: float,
                                                            sensors: int) -> None:
    """A damper step at 8 s, fresh seed 41, the service's filter with the early stop
    (an option, off by default) and with the full 1 s location phase, both located
    from the confirmation (no replay): the early one decides sooner, on the same
    parameter, and the new value lies inside its redraw range (three grid steps, a
    factor 1.52 either side of the located value); the estimate is within 15 % by +5 s."""
    rows = [fault_row(parameter, factor, sensors, 41, seconds=14.0, fault_at_s=8.0,
                      options=FilterOptions(locate_min_s=m, replay_s=0.0))
            for m in (0.1, None)]
    early, full = rows
    assert early["locate_min_s"] < early["locate_s"] <= full["locate_min_s"]
    for row in rows:
        assert row["detect_s"] is not None and row["wrong"] == 0 and row["before"] == 0, row
    assert early["detect_s"] - early["confirmed_s"] < full["detect_s"] - full["confirmed_s"]
    assert 1 / 1.52 <= early["located_rel"] <= 1.52, early
    assert early["track_s"] is not None and early["track_s"] <= 5.0, early


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["fast", "exact"])
def test_a_hold_raises_no_false_detection(mode: str) -> None:
    """A 3 s hold of the updates (a curve and the gate's straight hold) in a healthy run
    (paper scenario, 5 sensors, data seed 7003, filter seed 3): before 2026-11-27 the bank
    predicted through it with steady gains, scored the returning data too sharply and
    located a Csy drop to 0.37 x nominal 1.25 s after it, in both modes, and fast mode's
    cloud stood 7.6 sigma off at 13 s. Now the bank stops at the hold and starts again
    after ``after_hold_s`` of data (here at 12 s; its CUSUMs watch from 13 s); to 16 s
    nothing is detected and the estimate stays within 3 sigma."""
    from firmware_sim.studies.calibration import record
    from firmware_sim.studies.holds import holds
    from gateway.model.vehicle import THETA_SEC42

    truth = THETA_SEC42.as_array()
    Y = record(truth, 5, 7003, 16.0)
    est, found, filt = run(Y, service_filter(5, 3, FilterOptions(mode=mode)), every=500,
                           held=holds(len(Y), FS_HZ, [8.0], 3.0))
    assert found == []
    assert filt.n_detections == 0
    bank = filt.inner._bank if isinstance(filt, NoiseCheckedStart) else filt._bank
    assert bank is not None and bank.active
    mean, std = np.array(est[-1].mean[:3]), np.array(est[-1].std[:3])
    assert est[-1].t_s == 16.0
    assert np.all(np.abs(mean - truth) <= 3 * std), (mean - truth) / std


def _detection(llr: np.ndarray, reference: float = 40e3) -> Detection:
    """A Csy drop located by a grid of the default bank with summed ratios ``llr`` (J,)."""
    bank = FaultBank(FaultBankConfig(), 3, FS_HZ, AR_PAPER_DEFAULT)
    grid = bank.locate_grid(side=-1.0)
    best = int(np.argmax(llr))
    return Detection(parameter=0, factor=float(grid[best]), t_s=10.0, reference=reference,
                     state=np.zeros(NZ), confirmed_s=9.0, step=float(grid[1] / grid[0]),
                     grid=grid, llr=llr)


@pytest.mark.parametrize("peak_nats", [2.0, 40.0])
def test_the_redraw_follows_the_location_likelihood(peak_nats: float) -> None:
    """The weighted redraw is the grid's likelihood as a density in log theta, constant
    over each value's cell: its weighted cell shares match exp(llr) normalised, each cell
    is spread evenly, and a tenth of the points still cover the redraw range."""
    bank = FaultBank(FaultBankConfig(), 3, FS_HZ, AR_PAPER_DEFAULT)
    grid = bank.locate_grid(side=-1.0)
    llr = -peak_nats * (np.arange(len(grid)) - 6.3) ** 2 / 4.0
    det = _detection(llr)
    z, logw = bank.redraw(det, np.random.default_rng(5), 20000)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    half = 0.5 * np.log(det.step)
    mid = np.log(grid * det.reference)
    cell = np.clip(np.searchsorted(mid[:-1] + half, z), 0, len(grid) - 1)
    want = np.exp(llr - llr.max())
    want /= want.sum()
    got = np.bincount(cell, weights=w, minlength=len(grid))
    np.testing.assert_allclose(got, want, atol=0.01)
    lo, hi = FaultBank.redraw_range(det)
    wide = (z >= np.log(lo)) & (z <= np.log(hi))
    assert wide.mean() >= 0.1 and np.all(np.isfinite(logw))
    # inside the best cell the points are spread evenly (the density is flat there)
    inner = z[cell == 6] - (mid[6] - half)
    assert abs(np.mean(inner) / (2 * half) - 0.5) < 0.02


def test_the_likelihood_interval_ends_where_the_sum_trails_by_8_nats() -> None:
    """Values whose sum is within LIKELY_NATS = 8 of the best grid value's are inside.
    An end lies where the secant through the last two grid values inside, extended,
    reaches that level: exactly there for a sum linear in log theta, at the next grid
    value where the secant does not fall (a lone peak). A set that reaches the grid's
    old-value end ends at the old value, one that reaches the far end is open (0 for a
    drop)."""
    assert LIKELY_NATS == 8.0
    bank = FaultBank(FaultBankConfig(), 3, FS_HZ, AR_PAPER_DEFAULT)
    grid = bank.locate_grid(side=-1.0) * 40e3
    u, step = np.log(grid), float(np.log(grid[1] / grid[0]))
    rising = np.linspace(0.0, 29.4, 15)              # 2.1 nats a step; level 21.4
    lo, hi = bank.likely_range(_detection(rising))
    assert hi == 40e3 and grid[10] < lo < grid[11]
    assert lo == pytest.approx(np.exp(u[11] - (23.1 - 21.4) / 2.1 * step), rel=1e-12)
    lo, hi = bank.likely_range(_detection(rising[::-1].copy()))
    assert lo == 0.0 and hi == pytest.approx(np.exp(u[3] + (23.1 - 21.4) / 2.1 * step),
                                             rel=1e-12)
    lone = 30.0 - 20.0 * (np.arange(15) - 6.0) ** 2  # only the best inside
    assert bank.likely_range(_detection(lone)) == (grid[5], grid[7])


def test_the_likelihood_interval_holds_a_gaussian_likelihoods_8_nat_set() -> None:
    """For sums Gaussian in log theta (concave), at any peak and width on the grid, the
    interval holds every value within 8 nats of the best grid value's sum and lies
    within the grid values next outside that set (the interval before 2026-11-28's
    sixth session), nearer to the set's true ends than they are. (Where the set reaches
    the grid's old-value end the old value ends it: on data the location beat it by
    h / 2.)"""
    bank = FaultBank(FaultBankConfig(), 3, FS_HZ, AR_PAPER_DEFAULT)
    grid = bank.locate_grid(side=-1.0) * 40e3
    u, step = np.log(grid), float(np.log(grid[1] / grid[0]))
    rng = np.random.default_rng(2611)
    over_new, over_old = [], []
    for _ in range(300):
        u0, sd = rng.uniform(u[3], u[11]), rng.uniform(0.4, 3.0) * step
        llr = 40.0 - (u - u0) ** 2 / (2.0 * sd**2)
        level = llr.max() - LIKELY_NATS
        half = sd * np.sqrt(2.0 * (40.0 - level))    # the true set: |u - u0| <= half
        inside = np.nonzero(llr >= level)[0]
        old_lo = grid[inside[0] - 1] if inside[0] > 0 else 0.0
        old_hi = grid[inside[-1] + 1] if inside[-1] + 1 < len(grid) else 40e3
        lo, hi = bank.likely_range(_detection(llr))
        assert old_lo <= lo <= np.exp(u0 - half) * (1 + 1e-9), (u0, sd)
        if inside[-1] + 1 < len(grid):     # else the old value ends it (beaten by h / 2)
            assert np.exp(u0 + half) * (1 - 1e-9) <= hi <= old_hi, (u0, sd)
            over_new.append(np.log(hi) - u0 - half)
            over_old.append(np.log(old_hi) - u0 - half)
    assert np.mean(over_new) < 0.5 * np.mean(over_old), (np.mean(over_new), np.mean(over_old))


@pytest.mark.slow
def test_the_located_interval_holds_the_truth_and_survives_an_old_checkpoint() -> None:
    """A Csay x 0.3 step, 3 sensors: the estimates after the detection carry a likelihood
    interval around the located value that holds the truth. A checkpoint from before
    the interval (a 13-value scalar vector) restores with the redraw range as the
    interval, the rule it ran with."""
    from gateway.estimator import checkpoint as ckpt

    _, Y = fault_data(1, 0.3, 3, seed=16, seconds=10.0, fault_at_s=6.0)
    a = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=256, sensors=3, seed=16, mode="fast"))
    est = a.run(_samples(Y), output_every=100)
    loc = next(e.located for e in est if e.located is not None)
    assert loc.parameter == "csay_ns_per_m"
    assert loc.like_lo < 0.3 < loc.like_hi and loc.like_lo < loc.rel < loc.like_hi
    meta, arrays = ckpt.unpack(a.checkpoint())
    arrays["bank_vec"] = arrays["bank_vec"][:13]
    b = RBPF.restore(ckpt.pack(meta, arrays))
    assert b._bank is not None
    assert b._bank.last_likely() == b._bank.last_range() == a._bank.last_range()


@pytest.mark.slow
def test_the_refinement_narrows_the_located_interval_around_the_truth() -> None:
    """Csy x 0.5 at 20 m/s, 3 sensors (fresh seeds 3621-3622): after the detection the
    location grid sums on for ``refine_s`` and publishes its interval again every 0.25 s
    where it moved. The last interval holds the truth and lies inside the detection's;
    without the refinement the detection's is the only one."""
    for seed in (3621, 3622):
        _, Y = fault_data(0, 0.5, 3, seed, 14.0, 8.0, speed_mps=20.0)
        runs = {}
        for refine in (0.0, None):
            est, found, filt = run(Y, service_filter(3, seed, FilterOptions(refine_s=refine)),
                                   speed_mps=20.0)
            assert [f[1] for f in found] == ["csy_ns_per_m"] and found[0][0] > 8.0
            runs[refine] = sorted({(e.located.t_s, e.located.like_lo, e.located.like_hi)
                                   for e in est if e.located is not None})
        assert len(runs[0.0]) == 1
        first, *later = runs[None]
        assert first == runs[0.0][0] and later, runs[None]
        assert all(round((t - first[0]) * 4, 6).is_integer() for t, _, _ in later)
        t_last, lo, hi = later[-1]
        assert lo < 0.5 < hi, runs[None]
        assert first[1] <= lo and hi <= first[2], runs[None]


def _refining_bank(seed: int) -> tuple[RBPF, list[Sample], int]:
    """:func:`_locating_bank`, stepped on until its bank refines a detection."""
    a, smp, k = _locating_bank(seed)
    while not (a._bank is not None and a._bank.refining):
        a.step(smp[k])
        k += 1
        assert k < len(smp), "the bank never refined"
    for _ in range(300):                        # past the refinement's first look
        a.step(smp[k])
        k += 1
    return a, smp, k


@pytest.mark.slow
def test_checkpoint_while_refining_restores_bit_exact_and_an_old_one_does_not_refine(
        ) -> None:
    """Checkpoint in the middle of a refinement; both filters then give the same
    estimates and located changes, bit for bit, through its end and after. A checkpoint
    from before the refinement (a 15-value scalar vector, no ``refine_s``) restores
    without one, with the detection's own interval."""
    from gateway.estimator import checkpoint as ckpt

    a, smp, k = _refining_bank(14)
    b = RBPF.restore(a.checkpoint())
    assert b._bank is not None and b._bank.refining
    ea, eb = (f.run(smp[k:], output_every=50) for f in (a, b))
    assert [(e.mean, e.std, e.located) for e in ea] == [(e.mean, e.std, e.located) for e in eb]
    assert a._bank is not None and not a._bank.refining and a._bank.active
    meta, arrays = ckpt.unpack(a.checkpoint())
    arrays["bank_vec"] = arrays["bank_vec"][:15]
    del meta["config"]["faults"]["refine_s"]
    c = RBPF.restore(ckpt.pack(meta, arrays))
    assert c.config.faults is not None and c.config.faults.refine_s == 0.0
    assert c._bank is not None and not c._bank.refining
    last = c._bank.last()
    assert last is not None and c._bank.last_likely() is not None
    assert c._bank.located_before(last[0] + 1.0) == (last[0], last[2], *c._bank.last_likely())
    c.run(smp[k:k + 500], output_every=50)


@pytest.mark.slow
@pytest.mark.parametrize("missing, restored", [
    (("runner_by", "located_by"), {"runner_by": "cusum", "located_by": "crossing"}),
    (("located_by",), {"located_by": "crossing"})])
def test_a_checkpoint_from_before_a_bank_setting_keeps_the_filter_it_was_made_with(
        missing: tuple[str, ...], restored: dict[str, str]) -> None:
    """A checkpoint written before ``runner_by`` (its bank's settings without it, nor
    ``located_by``), or before ``located_by`` alone, restores with the rules it was made
    with (the watch's CUSUMs name the runner-up; a confirmation locates the parameter and
    side its crossing named) and runs on; the service's settings check names each difference (and so
    sets it aside)."""
    import dataclasses

    from gateway.estimator import checkpoint as ckpt
    from gateway.runtime.pipeline import _differences

    a, smp, k = _locating_bank(14)
    meta, arrays = ckpt.unpack(a.checkpoint())
    now = {"runner_by": "replay", "located_by": "search"}      # the service's bank
    assert {n: meta["config"]["faults"][n] for n in now} == now
    for name in missing:
        del meta["config"]["faults"][name]
    c = RBPF.restore(ckpt.pack(meta, arrays))
    assert c.config.faults is not None
    assert {n: getattr(c.config.faults, n) for n in restored} == restored
    c.run(smp[k:k + 500], output_every=50)
    assert _differences(c.config, a.config, set()) == [      # in the bank's field order
        f"faults.{n} {restored[n]!r} -> {now[n]!r}" for n in now if n in restored]
    assert dataclasses.replace(c.config.faults, **{n: now[n] for n in restored}) \
        == a.config.faults


def test_a_range_redraw_is_log_uniform_with_equal_weights() -> None:
    bank = FaultBank(FaultBankConfig(redraw_from="range"), 3, FS_HZ, AR_PAPER_DEFAULT)
    det = _detection(np.linspace(0.0, 30.0, 15))
    z, logw = bank.redraw(det, np.random.default_rng(6), 4000)
    lo, hi = FaultBank.redraw_range(det)
    assert np.all(logw == 0.0) and z.min() >= np.log(lo) and z.max() <= np.log(hi)
    assert abs(np.mean(z) - 0.5 * np.log(lo * hi)) < 0.01 * np.log(hi / lo)
