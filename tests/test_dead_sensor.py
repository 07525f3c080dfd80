"""A dead sensor node: the filters leave its sensors out and run on what is left.

Until 2026-11-27 every sample from a vehicle with a dead node lacked a sensor: fast mode
ran the exact recursion for good, the fault bank never started (it scores full samples
only), and the sensor-noise test never began, so every estimate stayed provisional and
no alert was judged. Now a sensor missing from ``DEAD_AFTER_S`` of samples with data is
left out (a zero row of H) until it has been back ``BACK_AFTER_S``
(:mod:`gateway.estimator.sensormask`).
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.estimator.noisestart import NoiseCheckedStart
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.estimator.sensormask import BACK_AFTER_S, DEAD_AFTER_S, next_mask, tally
from gateway.model.vehicle import THETA_SEC42, sensor_set
from gateway.records import Sample
from gateway.sinks.outputs import estimate_status

V_MPS, FS_HZ = 42.5, 1000.0
NOMINAL = THETA_SEC42.as_array()
DEAD_N, BACK_N = int(DEAD_AFTER_S * FS_HZ), int(BACK_AFTER_S * FS_HZ)
WSN = [0, 1]
"""acc_w1 and acc_w2 in the 5-sensor set: the wheelset node's."""


def _outputs(n: int, seed: int, theta: np.ndarray = NOMINAL) -> np.ndarray:
    rng = np.random.default_rng(seed)
    truth = simulate(np.repeat(theta[None], n, 0), np.full(n, V_MPS), FS_HZ, rng)
    sensors = sensor_set(5)
    return add_sensor_noise(select(truth.outputs, sensors), sensors, rng)


def _samples(Y: np.ndarray) -> list[Sample]:
    return [Sample(t_s=k / FS_HZ, values=Y[k], speed_mps=V_MPS) for k in range(len(Y))]


def test_a_sensor_goes_after_dead_n_and_comes_back_after_back_n() -> None:
    """Counts over samples with data: a lone lost value leaves nothing out; DEAD_N in a row
    do; the last sensor in use is never left out; BACK_N values in a row bring it back."""
    out = np.zeros(3, dtype=bool)
    absent, present = np.zeros(3, np.int64), np.zeros(3, np.int64)
    for k in range(DEAD_N - 1):
        tally(absent, present, np.array([k % 2 == 0, False, True]))
        out = next_mask(out, absent, present, DEAD_N, BACK_N)
    assert not out.any()
    tally(absent, present, np.array([False, False, True]))
    assert next_mask(out, absent, present, DEAD_N, BACK_N).tolist() == [False, True, False]
    out = next_mask(out, absent, present, DEAD_N, BACK_N)
    tally(absent, present, np.array([False, False, False]), n=10 * DEAD_N)
    out = next_mask(out, absent, present, DEAD_N, BACK_N)
    assert np.count_nonzero(~out) == 1            # one stays in use
    tally(absent, present, np.array([True, True, True]), n=BACK_N - 1)
    assert next_mask(out, absent, present, DEAD_N, BACK_N).sum() == out.sum()
    tally(absent, present, np.array([True, True, True]))
    assert not next_mask(out, absent, present, DEAD_N, BACK_N).any()


def test_a_left_out_sensor_is_the_sensor_skipped_exactly() -> None:
    """Exact mode, the same 16 particles: a 5-sensor filter whose wheelset sensors never
    have a value (partial samples for DEAD_AFTER_S, then left out as zero rows of H)
    against a 3-sensor filter on the other three: the same states, bit for bit, and
    per-particle log-likelihoods that differ by one constant (the left-out rows' own
    term) to 1e-9."""
    Y = _outputs(2000, seed=31)
    Y[:, WSN] = np.nan
    rng = np.random.default_rng(5)
    theta = NOMINAL * np.exp(rng.uniform(-0.3, 0.3, (16, 3)))
    runs = {}
    for n in (5, 3):
        cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=n, mode="exact", resample=False,
                         monitor=None, faults=None, seed=0)
        filt = RBPF(cfg)
        filt.set_particles(theta)
        ll = np.zeros(16)
        for k in range(len(Y)):
            filt.advance(Sample(k / FS_HZ, Y[k] if n == 5 else Y[k, 2:], V_MPS))
            ll += filt._ll[:16]
        runs[n] = (filt, ll)
    five, three = runs[5][0], runs[3][0]
    assert five.left_out.tolist() == [True, True, False, False, False]
    assert not three.left_out.any()
    assert np.array_equal(five._X, three._X) and np.array_equal(five._P, three._P)
    d = runs[5][1] - runs[3][1]
    assert np.ptp(d) < 1e-9 and abs(d[0]) > 1.0, d


def test_fast_mode_and_the_fault_bank_run_on_the_sensors_left() -> None:
    """The service's filter (fast mode, fault bank) on 5 sensors whose wheelset node dies
    at 3 s and comes back at 9 s: its sensors are left out from 3.5 s, fast mode is back
    on steady gains after its warm-up (it stayed on the exact recursion for good), the
    fault bank runs again, and from 9.5 s the wheelset sensors are used again (exact
    recursion for the warm-up, ``fast_warmup_s``, then steady gains for all five; the
    windows follow the filter's warm-up, 2 s until 2026-11-30's sixteenth session)."""
    Y = _outputs(13000, seed=32)
    Y[3000:9000, WSN] = np.nan
    S = _samples(Y)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=200, sensors=5, seed=3, mode="fast")
    filt = RBPF(cfg)
    seen: dict[str, list[int]] = {"steady": [], "left_out": [], "bank": []}
    for k, smp in enumerate(S):
        filt.advance(smp)
        if k % 100 == 99:
            seen["steady"].append(int(filt._steady))
            seen["left_out"].append(int(filt.left_out.sum()))
            seen["bank"].append(int(filt._bank is not None and filt._bank.active))
    t = np.arange(100, 13001, 100) / FS_HZ      # after each 100th sample
    warm_s = cfg.fast_warmup_s                  # the exact recursion after a change
    assert all(n == (2 if 3.0 + DEAD_AFTER_S <= s < 9.0 + BACK_AFTER_S else 0)
               for s, n in zip(t, seen["left_out"], strict=True)), seen["left_out"]
    steady, bank = np.array(seen["steady"]), np.array(seen["bank"])
    assert steady[(t > 3.0) & (t < 3.0 + DEAD_AFTER_S)].sum() == 0     # a lost frame's way
    assert steady[(t > 3.0 + DEAD_AFTER_S + warm_s + 0.1) & (t < 9.0)].all()  # on three
    assert bank[(t > 3.0 + DEAD_AFTER_S + warm_s + 0.1) & (t < 9.0)].any()
    assert steady[(t > 9.0 + BACK_AFTER_S) & (t < 9.0 + BACK_AFTER_S + warm_s)].sum() == 0
    assert steady[t > 9.0 + BACK_AFTER_S + warm_s + 0.1].all()               # on five


def test_the_estimates_name_the_sensors_left_out() -> None:
    """Each estimate names the sensors its filters did without (``Estimate.left_out``):
    none while the wheelset node sends, both of its sensors from ``DEAD_AFTER_S`` after
    it falls silent until ``BACK_AFTER_S`` after it is back."""
    Y = _outputs(6000, seed=33)
    Y[1500:3500, WSN] = np.nan
    filt = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=32, sensors=5, seed=3, mode="fast"))
    ests = filt.run(_samples(Y), output_every=100)
    said = {round(e.t_s, 3): e.left_out for e in ests}
    said_unresolved = {round(e.t_s, 3): e.unresolved for e in ests}
    wsn = ("acc_w1", "acc_w2")
    for t_s, left in said.items():
        k = round(t_s * FS_HZ)            # the sample: its own value counts in the runs
        dead = 1500 + DEAD_N - 1 <= k < 3500 + BACK_N - 1
        assert left == (wsn if dead else ()), (t_s, left)
        assert said_unresolved[t_s] == (), (t_s, said_unresolved[t_s])
    assert sum(1 for left in said.values() if left) >= 20


def test_the_estimates_name_what_the_sensors_left_cannot_resolve() -> None:
    """With the body node out of a 3-sensor vehicle the estimates call Csy unresolved
    (gateway.estimator.observability), and the estimate frame's status for it says
    Unresolved instead of Valid, only while the node is out; a filter restored in that
    time says the same. With the wheelset node out of a 5-sensor one nothing is
    unresolved (the test above)."""
    Y = _outputs(6000, seed=38)[:, 2:]        # acc_b, gyro_b, acc_bd: the 3-sensor set
    Y[1500:3500, 2] = np.nan
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=32, sensors=3, seed=3, mode="fast")
    S = _samples(Y)
    filt = RBPF(cfg)
    said = {round(e.t_s * FS_HZ): e for e in filt.run(S, output_every=100)}
    for k, est in said.items():
        dead = 1500 + DEAD_N - 1 <= k < 3500 + BACK_N - 1
        assert est.unresolved == (("csy_ns_per_m",) if dead else ()), (k, est.unresolved)
        assert (estimate_status(est, 0) == "Unresolved") == dead, k
        assert "Unresolved" not in (estimate_status(est, 1), estimate_status(est, 2))
    cut = RBPF(cfg)
    cut.run(S[:2500])
    restored = RBPF.restore(cut.checkpoint())
    assert restored.run(S[2500:2600])[-1].unresolved == ("csy_ns_per_m",)


@pytest.mark.parametrize("mode", ["fast", "exact"])
def test_run_step_and_checkpoints_agree_through_a_dead_sensor(mode: str) -> None:
    """The block path equals the per-sample path through a node that dies and comes back
    (bit for bit: estimates and the final checkpoint), and checkpoints cut while the
    sensors are missing, left out (exact warm-up, steady) and back continue bit for
    bit."""
    Y = _outputs(8000, seed=33)
    Y[1500:5500, WSN] = np.nan
    S = _samples(Y)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=200, sensors=5, seed=3, mode=mode,
                     fast_warmup_s=0.5)
    a = RBPF(cfg).run(S, output_every=37)
    one = RBPF(cfg)
    b = [e for k, s in enumerate(S) if (e := one.step(s)) and (k + 1) % 37 == 0]
    assert [(e.t_s, e.mean, e.std) for e in a[:-1]] == [(e.t_s, e.mean, e.std) for e in b]
    twin = RBPF(cfg)
    twin.run(S, output_every=37)
    assert twin.checkpoint() == one.checkpoint()
    for cut in (1800, 2300, 4000, 5800, 7000):
        filt = RBPF(cfg)
        filt.run(S[:cut])
        assert filt.left_out.any() == (2000 <= cut < 6000), cut
        restored = RBPF.restore(filt.checkpoint())
        assert [e.mean for e in filt.run(S[cut:])] == [e.mean for e in restored.run(S[cut:])]
        assert filt.checkpoint() == restored.checkpoint()


def test_the_noise_test_measures_the_sensors_in_use() -> None:
    """With the wheelset node dead from the start, the sensor-noise test is made after its
    window on the three sensors in use (before, it never began and every estimate stayed
    provisional: no alert was ever judged); the two left out are reported unmeasured."""
    Y = _outputs(7000, seed=34)
    Y[:, WSN] = np.nan
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=200, sensors=5, seed=3, mode="fast")
    filt = NoiseCheckedStart(cfg)
    est = filt.run(_samples(Y), output_every=500)
    res = filt.result
    assert res is not None and res.t_s < 5.1, res
    assert np.isnan(res.band_var[:2]).all() and np.isfinite(res.band_var[2:]).all()
    assert res.note == "not measured: acc_w1, acc_w2 (no values: left out)"
    assert not any(res.replaced[:2]) and res.used_var[:2] == res.model_var[:2]
    assert not est[-1].provisional


@pytest.mark.slow
@pytest.mark.parametrize("parameter, factor, seed", [(0, 0.25, 35), (1, 0.5, 36)])
def test_a_fault_is_found_with_the_wheelset_node_dead(parameter: int, factor: float,
                                                      seed: int) -> None:
    """The service's filter on 5 sensors with the wheelset node dead throughout: a damper
    step at 8 s is found on its parameter within 3 s, on no other, tracked within 15 %
    by +5 s, and alerted within 3 s (before: the bank never ran and no alert was judged:
    no detection at all)."""
    from firmware_sim.studies.detection import fault_row

    row = fault_row(parameter, factor, 5, seed, seconds=14.0, fault_at_s=8.0,
                    dead=("acc_w1", "acc_w2"))
    assert row["detect_s"] is not None and row["detect_s"] <= 3.0, row
    assert row["wrong"] == 0 and row["before"] == 0 and row["alerts_healthy"] == 0, row
    assert row["track_s"] is not None and row["track_s"] <= 5.0, row
    assert row["alert_s"] is not None and row["alert_s"] <= 3.0, row


def test_a_healthy_vehicle_with_a_dead_node_raises_nothing() -> None:
    """60 s of healthy data, 5 sensors, the wheelset node dead: no detection, no alert,
    and the truth within 3σ at the end."""
    from firmware_sim.studies.detection import nominal_row

    row = nominal_row(5, 37, seconds=60.0, dead=("acc_w1", "acc_w2"))
    assert row["detections"] == 0 and row["alerts"] == 0 and row["monitor_alarms"] == 0, row
    assert max(abs(z) for z in row["final_z"]) < 3.0, row


@pytest.mark.slow
def test_gateway_replay_alerts_a_failed_damper_with_the_wheelset_node_dead(tmp_path) -> None:
    """Through ``gateway replay`` (front end, worker process, alert policy), 5 sensors, a
    CAN log of the lateral damper failing at 12 s (Csy 40 -> 10 kNs/m) with no wheelset
    frame at all: a Csy alert within 3 s, none on another parameter, and the report's
    sensor-noise test names the two sensors left out. Before 2026-11-27 the same log
    gave no alert at all (every estimate provisional, the fault bank never ran)."""
    import json
    import subprocess
    import sys

    from firmware_sim.output import write_log
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation
    from gateway.can.codec import default_codec

    wsn = default_codec().message("WSN_Lat").frame_id
    sim = Simulation(get_scenario("lateral-failing"), SimConfig(duration_s=24.0, seed=41))
    log = tmp_path / "dead-wsn.log"
    write_log((m for m in sim.messages() if m.arbitration_id != wsn), log)
    report = tmp_path / "report.json"
    proc = subprocess.run([sys.executable, "-m", "gateway", "replay", str(log), "--sensors",
                           "5", "--report", str(report), "--no-progress"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rep = json.loads(report.read_text())
    raised = [(a["t_s"], a["parameter"]) for a in rep["alerts"] if a["state"] == "raised"]
    assert raised and all(p == "csy_ns_per_m" for _, p in raised), raised
    assert 12.0 < raised[0][0] <= 15.0, raised
    note = rep["diagnostics"]["sensor_noise"]["note"]
    assert note == "not measured: acc_w1, acc_w2 (no values: left out)", note
