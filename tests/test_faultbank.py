"""The fault-hypothesis bank: its CUSUM, and abrupt faults found and tracked by the RBPF.

The campaign's short form (issue 15): simulator truth with a damper step, the service's
filter (fast mode, m = 1000), fresh data seeds (``firmware_sim.studies.detection``).
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.detection import FS_HZ, V_MPS, fault_data, fault_row, service_filter
from gateway.errors import EstimatorError
from gateway.estimator.faultbank import _HOLD, FaultBank, FaultBankConfig, _cusum_path
from gateway.estimator.kalman import from_lanes, to_lanes
from gateway.estimator.noisestart import NoiseCheckedStart
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.coordinates import NZ
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
                                 dict(h_nats=0.0), dict(locate_s=-1.0)])
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
    row = fault_row(parameter, factor, sensors, seed, seconds=14.0, fault_at_s=8.0,
                    particles=1000, mode="fast")
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
    row = fault_row(2, 1.6, sensors, seed, seconds=12.0, fault_at_s=8.0,
                    particles=1000, mode="fast")
    assert row["detect_s"] is not None and row["detect_s"] <= 3.0, row
    assert 0.85 <= row["located_rel"] <= 1.15, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row
    assert row["track_s"] is not None and row["track_s"] <= 3.0, row


@pytest.mark.slow
def test_healthy_data_raise_no_detection() -> None:
    """30 s of nominal data, 3 and 5 sensors: the bank starts and never decides."""
    for sensors in (3, 5):
        _, Y = fault_data(None, 1.0, sensors, seed=13, seconds=30.0, fault_at_s=0.0)
        filt = service_filter(sensors, 13, 1000, "fast")
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
    _, Y = fault_data(0, 0.25, 3, seed=14, seconds=12.0, fault_at_s=6.0)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=256, sensors=3, seed=14, mode="fast")
    a = RBPF(cfg)
    smp = _samples(Y)
    k = 0
    while not (a._bank is not None and a._bank.locating):
        a.step(smp[k])
        k += 1
        assert k < len(smp), "the bank never started locating"
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
    # every estimate within 2 s of data after a detection carries it, whichever path
    la = [e.located for e in ea if e.located is not None]
    lb = [e.located for e in eb if e.located is not None]
    assert la == lb and len({loc.t_s for loc in la}) == a.n_fault_detections
    near = [e for e in eb_all if e.located is not None and e.located == la[-1]]
    assert 0.0 <= near[0].t_s - la[-1].t_s <= 1.5e-3        # from the next sample on
    assert near[-1].t_s - la[-1].t_s == pytest.approx(2.0, abs=1.5e-3)
    last = la[-1]
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


def _first_decisive_row(g_sum: np.ndarray, left: int, total: int, min_n: int,
                        half: float) -> int | None:
    """The location phase's end, sample by sample (what ``_located_row`` vectorises)."""
    for r in range(min(left, len(g_sum))):
        row = g_sum[r]
        best = int(np.argmax(row))
        far = [row[i] for i in range(len(row)) if abs(i - best) >= 3]
        if total - left + r + 1 >= min_n and row[best] > half \
                and row[best] - max(far) >= half:
            return r
    return left - 1 if left <= len(g_sum) else None


@pytest.mark.parametrize("left, min_s", [(1000, 0.1), (700, 0.1), (1000, 0.5),
                                         (950, 0.1), (300, 1.0), (1000, 2.0)])
def test_location_ends_at_the_first_decisive_sample(left: int, min_s: float) -> None:
    """The location sums stop at the first sample, after ``locate_min_s``, where the best
    grid value beats the reference by h/2 and every value three or more grid steps away
    by h/2 (else after ``locate_s``); a block that starts inside the phase counts the
    samples already summed."""
    bank = FaultBank(FaultBankConfig(locate_min_s=min_s), n_params=3, fs_hz=FS_HZ,
                     ar_paper=1.0)
    rng = np.random.default_rng(3)
    k, J = 400, bank.n_hyp
    slope = np.abs(7 - np.arange(J)) * -0.02 + 0.04          # nats per sample, peak at 7
    d = slope[None] + rng.normal(0.0, 0.05, (k, J))         # per-sample ratios
    g_sum = np.cumsum(d, axis=0)
    total = round(FaultBankConfig().locate_s * FS_HZ)
    want = _first_decisive_row(g_sum, left, total, round(min_s * FS_HZ), 12.5)
    assert bank._located_row(d, left) == want
    if left == 1000 and min_s == 0.1:
        assert want is not None and 100 <= want < 399      # decisive inside the block
    if min_s >= 1.0:
        assert want == (left - 1 if left <= k else None)    # always the full phase


@pytest.mark.slow
@pytest.mark.parametrize("parameter, factor, sensors", [(0, 0.25, 5), (0, 0.5, 3)])
def test_early_location_keeps_the_truth_in_the_redraw_range(parameter: int, factor: float,
                                                            sensors: int) -> None:
    """A damper step at 8 s, fresh seed 41, the service's filter with the early stop
    (an option, off by default) and with the full 1 s location phase: the early one
    decides sooner, on the same parameter, and the new value lies inside its redraw
    range (three grid steps, a factor 1.52 either side of the located value); the
    estimate is within 15 % by +5 s."""
    rows = [fault_row(parameter, factor, sensors, 41, seconds=14.0, fault_at_s=8.0,
                      particles=1000, mode="fast", locate_min_s=m) for m in (0.1, None)]
    early, full = rows
    assert early["locate_min_s"] < early["locate_s"] <= full["locate_min_s"]
    for row in rows:
        assert row["detect_s"] is not None and row["wrong"] == 0 and row["before"] == 0, row
    assert early["detect_s"] - early["confirmed_s"] < full["detect_s"] - full["confirmed_s"]
    assert 1 / 1.52 <= early["located_rel"] <= 1.52, early
    assert early["track_s"] is not None and early["track_s"] <= 5.0, early
