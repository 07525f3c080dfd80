"""The sensor-node simulator: frames decode back to what went in; faults show as designed."""

from __future__ import annotations

import can
import cantools
import numpy as np
import pytest

from dbc import DBC_PATH
from firmware_sim.nodes import MIN_LATENCY_S, NodeClock
from firmware_sim.output import write_log
from firmware_sim.scenarios import SCENARIOS, get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from firmware_sim.truth import DamperCurve, NonlinearDampers, simulate
from gateway.can.codec import default_codec
from gateway.errors import FrameError, InputError
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    IDX,
    NX,
    SENSOR_NOISE_VAR,
    THETA_NOMINAL,
    THETA_SEC42,
    VehicleParams,
    discretize,
    input_matrix,
    system_matrix,
    track_intensity,
)
from gateway.offline.interchange import write_csv

DB = cantools.database.load_file(str(DBC_PATH), strict=True)
SIGNAL_OF = {"acc_w1": ("WSN_Lat", "WSN_Acc1"), "acc_w2": ("WSN_Lat", "WSN_Acc2"),
             "acc_b": ("BGN_Lat", "BGN_Acc"), "gyro_b": ("BGN_Lat", "BGN_YawRate"),
             "acc_bd": ("BDN_Lat", "BDN_Acc"), "speed": ("VEH_Speed", "VEH_Speed")}
NODE_OF = {"acc_w1": "WSN", "acc_w2": "WSN", "acc_b": "BGN", "gyro_b": "BGN", "acc_bd": "BDN",
           "speed": "VEH"}


def _run(name: str, duration_s: float, seed: int = 3, **kw) -> tuple[Simulation, list[can.Message]]:
    sim = Simulation(get_scenario(name), SimConfig(duration_s=duration_s, seed=seed, **kw),
                     record=True)
    return sim, list(sim.messages())


def _decoded(messages, message_name: str) -> list[dict]:
    frame_id = DB.get_message_by_name(message_name).frame_id
    return [DB.decode_message(m.arbitration_id, bytes(m.data), decode_choices=False)
            for m in messages if m.arbitration_id == frame_id]


def _step(message: str, signal: str) -> float:
    return float(DB.get_message_by_name(message).get_signal_by_name(signal).scale)


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
def test_simulated_run_decodes_back_from_a_log(tmp_path, suffix):
    sim, messages = _run("nominal", 2.0)
    path = tmp_path / f"run{suffix}"
    assert write_log(messages, path) == len(messages)
    read = [m for m in can.LogReader(str(path)) if not m.is_error_frame]
    assert len(read) == len(messages)
    assert sim.records is not None
    for sensor, (message, signal) in SIGNAL_OF.items():
        got = np.array([d[signal] for d in _decoded(read, message)])
        sent = sim.records[NODE_OF[sensor]].array(sensor)
        assert got.shape == sent.shape and len(got) > 100
        assert np.abs(got - sent).max() <= _step(message, signal), sensor
    idx = np.array([d["BGN_Lat_SampleIdx"] for d in _decoded(read, "BGN_Lat")])
    np.testing.assert_array_equal(idx, np.concatenate(sim.records["BGN"].sample_idx))


def test_bus_timing_has_jitter_drift_and_all_nodes():
    sim, messages = _run("nominal", 3.0)
    t = np.array([m.timestamp for m in messages])
    assert np.all(np.diff(t) >= 0)
    ids = {m.arbitration_id for m in messages}
    assert ids == {0x101, 0x102, 0x103, 0x110}
    bgn = [m for m in messages if m.arbitration_id == 0x102]
    tb = np.array([m.timestamp for m in bgn])
    idx = np.array([_decoded([m], "BGN_Lat")[0]["BGN_Lat_SampleIdx"] for m in bgn])
    slope, _ = np.polyfit(idx, tb, 1)
    drift_ppm = (slope / 1e-3 - 1) * 1e6
    assert abs(drift_ppm - sim.clocks["BGN"].drift_ppm) < 5
    latency = tb - np.polyval(np.polyfit(idx, tb, 1), idx)
    assert latency.std() > 20e-6            # jittered, not on a perfect grid


def test_same_seed_same_frames_and_other_seed_differs():
    _, a = _run("nominal", 1.0, seed=7)
    _, b = _run("nominal", 1.0, seed=7)
    _, c = _run("nominal", 1.0, seed=8)
    assert [(m.timestamp, bytes(m.data)) for m in a] == [(m.timestamp, bytes(m.data)) for m in b]
    assert [bytes(m.data) for m in a] != [bytes(m.data) for m in c]


def _unit_noise(noise_by_sample: bool, clock: NodeClock) -> dict[str, dict[int, float]]:
    """Per lateral sensor, sample number -> its noise in units of the sensor's std: a
    4 s nominal run (seed 9) with the lateral nodes on ``clock``, less the same run with
    no noise."""
    recs = []
    for scale in (1.0, 0.0):
        sim = Simulation(get_scenario("nominal"), SimConfig(
            duration_s=4.0, seed=9, noise_scale=scale, noise_by_sample=noise_by_sample),
            record=True)
        for node in ("WSN", "BGN", "BDN"):
            sim.clocks[node] = clock
        list(sim.messages())
        assert sim.records is not None
        recs.append(sim.records)
    noisy, clean = recs
    out = {}
    for sensor in ("acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd"):
        node = NODE_OF[sensor]
        k = np.concatenate(noisy[node].sample_idx)
        e = (noisy[node].array(sensor) - clean[node].array(sensor)) / np.sqrt(
            SENSOR_NOISE_VAR[sensor])
        out[sensor] = dict(zip(k.tolist(), e.tolist(), strict=True))
    return out


def test_noise_by_sample_gives_each_sample_its_noise_whatever_the_node_clocks():
    """Issue 15, node phase: the timing study compares runs that differ only in their
    node clocks. With ``noise_by_sample`` a sample carries the same noise on aligned
    and on drifting clocks (-50 ppm from 0.02 ms: the first 1 s block holds 1001
    samples instead of 1000); with the shared stream the drift draws other noise."""
    aligned = NodeClock(0.0, 1e-3 - MIN_LATENCY_S)
    drifting = NodeClock(-50.0, 2e-5)
    for by_sample in (True, False):
        a = _unit_noise(by_sample, aligned)
        d = _unit_noise(by_sample, drifting)
        for sensor in a:
            common = sorted(set(a[sensor]) & set(d[sensor]))
            assert len(common) > 3990
            ea = np.array([a[sensor][k] for k in common])
            ed = np.array([d[sensor][k] for k in common])
            assert 0.9 < ea.std() < 1.1 and 0.9 < ed.std() < 1.1    # unit noise, both
            if by_sample:
                np.testing.assert_allclose(ed, ea, rtol=0, atol=1e-6, err_msg=sensor)
            else:
                assert np.abs(ed - ea).max() > 1.0, sensor


def test_noise_by_sample_keeps_the_truth_and_the_bus_of_the_shared_stream():
    """The option changes the sensor noise only: the same seed's truth (the clean
    values), sample instants and bus timestamps are those of the default."""
    runs = {}
    for by_sample in (False, True):
        sim = Simulation(get_scenario("nominal"), SimConfig(
            duration_s=2.0, seed=5, noise_scale=0.0, noise_by_sample=by_sample), record=True)
        runs[by_sample] = (sim, list(sim.messages()))
    (s0, m0), (s1, m1) = runs[False], runs[True]
    assert [(m.timestamp, m.arbitration_id) for m in m0] == [
        (m.timestamp, m.arbitration_id) for m in m1]
    assert s0.records is not None and s1.records is not None
    for sensor, node in NODE_OF.items():
        np.testing.assert_array_equal(s0.records[node].array(sensor),
                                      s1.records[node].array(sensor))


def _window(messages, node_id: int, duration_s: float):
    """Frames well inside the fault window (40-60 %) and well before it."""
    ms = [m for m in messages if m.arbitration_id == node_id]
    inside = [m for m in ms if 0.41 * duration_s <= m.timestamp < 0.59 * duration_s]
    before = [m for m in ms if m.timestamp < 0.39 * duration_s]
    return inside, before


def test_dropout_stops_the_node_inside_its_window():
    _, messages = _run("dropout", 10.0)
    t = np.array([m.timestamp for m in messages if m.arbitration_id == 0x103])
    assert not np.any((t > 4.001) & (t < 5.999))
    assert np.any(t < 4.0) and np.any(t > 6.0)


def test_bad_crc_is_rejected_only_inside_its_window():
    _, messages = _run("bad-crc", 10.0)
    codec = default_codec()
    inside, outside = _window(messages, 0x102, 10.0)
    for m in inside:
        with pytest.raises(FrameError) as info:
            codec.decode_message(m)
        assert info.value.reason == "crc"
    for m in outside:
        codec.decode_message(m)


def test_frozen_counter_and_stuck_values():
    _, messages = _run("frozen-counter", 10.0)
    inside, outside = _window(messages, 0x101, 10.0)
    assert len({m.data[1] & 0xF for m in inside}) == 1
    assert len({m.data[1] & 0xF for m in outside}) == 15
    _, messages = _run("stuck", 10.0)
    inside, outside = _window(messages, 0x102, 10.0)
    assert len({bytes(m.data[4:8]) for m in inside}) == 1
    assert len({bytes(m.data[4:8]) for m in outside}) > 100


def test_noise_burst_raises_the_noise_inside_its_window():
    _, messages = _run("noise-burst", 10.0)
    inside, outside = _window(messages, 0x102, 10.0)
    yaw_in = np.std([d["BGN_YawRate"] for d in _decoded(inside, "BGN_Lat")])
    yaw_out = np.std([d["BGN_YawRate"] for d in _decoded(outside, "BGN_Lat")])
    assert yaw_in > 2.5 * yaw_out


def test_out_of_order_frames_only_inside_the_window():
    _, messages = _run("out-of-order", 10.0)
    inside, outside = _window(messages, 0x103, 10.0)

    def backwards(ms):
        idx = np.array([_decoded([m], "BDN_Lat")[0]["BDN_Lat_SampleIdx"] for m in ms])
        return int(np.sum(np.diff(idx.astype(int)) % 65536 > 60000))

    assert backwards(inside) > 100
    assert backwards(outside) == 0


def test_scenario_parameter_profiles():
    lf = get_scenario("lateral-failing")
    th = lf.theta(np.array([0.0, 29.9, 30.0, 59.0]), 60.0)
    np.testing.assert_allclose(th[:, 0], [40e3, 40e3, 10e3, 10e3])
    ld = get_scenario("lateral-degrading").theta(np.array([0.0, 60.0, 120.0]), 120.0)
    assert ld[0, 0] == 40e3 and ld[1, 0] < 40e3 and np.isclose(ld[2, 0], 16e3)
    cr = get_scenario("conicity-rising").theta(np.array([120.0]), 120.0)
    assert np.isclose(cr[0, 2], 0.40)
    v = get_scenario("speed-profile").speed(np.array([0.0, 60.0, 120.0]), 120.0)
    np.testing.assert_allclose(v, [20.0, 42.5, 30.0])
    assert {"nominal", "lateral-degrading", "lateral-failing", "antiyaw-failing",
            "conicity-rising", "speed-profile"} <= set(SCENARIOS)


def test_nonlinear_dampers_change_the_response():
    sim_l, lin = _run("nominal", 3.0, seed=4)
    sim_n, nonlin = _run("nominal", 3.0, seed=4, nonlinear_dampers=True)
    assert sim_l.records is not None and sim_n.records is not None
    yaw_l = sim_l.records["BGN"].array("gyro_b").std()
    yaw_n = sim_n.records["BGN"].array("gyro_b").std()
    assert yaw_n > 1.3 * yaw_l      # saturated anti-yaw dampers let the bogie yaw more


def test_play_csv_round_trip(tmp_path, cli):
    rng = np.random.default_rng(0)
    t = np.arange(2000) * 1e-3 + rng.uniform(-1e-4, 1e-4, 2000)    # uneven times
    sig = {"acc_b": rng.normal(0, 0.4, 2000), "gyro_b": rng.normal(0, 3e-3, 2000),
           "acc_bd": rng.normal(0, 0.15, 2000), "speed": np.full(2000, 40.0)}
    sig["acc_bd"][100] = np.nan
    write_csv(tmp_path / "in.csv", t, sig)
    proc = cli("firmware_sim", "play-csv", str(tmp_path / "in.csv"), "--out",
               str(tmp_path / "run.log"))
    assert proc.returncode == 0, proc.stderr
    read = list(can.LogReader(str(tmp_path / "run.log")))
    codec = default_codec()
    for sensor in ("acc_b", "gyro_b", "acc_bd"):
        message, signal = SIGNAL_OF[sensor]
        frames = [codec.decode_message(m) for m in read
                  if m.arbitration_id == DB.get_message_by_name(message).frame_id]
        got = np.array([f.values[signal] for f in frames])
        assert len(got) == 2000
        ok = ~np.isnan(sig[sensor])
        assert np.abs(got[ok] - sig[sensor][ok]).max() <= _step(message, signal)
        assert np.isnan(got[~ok]).all()
        idx = np.array([f.sample_idx for f in frames])
        np.testing.assert_array_equal(idx, np.arange(2000))
    speeds = [m for m in read if m.arbitration_id == 0x110]
    assert len(speeds) == len(np.unique(np.rint((t - t[0]) / 0.01)))


def test_bad_inputs_give_one_line_errors(tmp_path, cli):
    proc = cli("firmware_sim", "run", "--scenario", "derailment", "--out", str(tmp_path / "x.log"))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and "expected a scenario from" in proc.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,bogie_lat_acc_mps2,bogie_yaw_rate_radps,body_lat_acc_mps2\n"
                   "0,0.1,0.001,0.01\n0.001,0.2,oops,0.02\n")
    proc = cli("firmware_sim", "play-csv", str(bad), "--out", str(tmp_path / "x.log"))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1
    assert "bad.csv:3" in proc.stderr and "bogie_yaw_rate_radps" in proc.stderr
    with pytest.raises(InputError):
        get_scenario("nope")


def test_dampers_whose_knees_are_never_reached_give_the_linear_truth():
    """The saturating truth's compiled sub-steps, with knees beyond any velocity, are the
    linear model: from the same state, without track input, the two runs agree sample for
    sample. With the paper's knees the same start is another motion: the anti-yaw damper
    is past its knee, so the bogie's yaw rate decays more slowly."""
    n = 400
    th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
    v = np.full(n, 42.5)
    x0 = np.zeros(NX)
    x0[IDX["dpsi_b"]] = 0.02                      # 20 mrad/s of bogie yaw: 24 mm/s at l_bw
    far = NonlinearDampers(lateral=DamperCurve(1e3, 0.25), antiyaw=DamperCurve(1e3, 0.025))
    quiet = {"ar_paper": 1e-30, "x0": x0}
    lin = simulate(th, v, 1000.0, np.random.default_rng(0), **quiet)
    nl_far = simulate(th, v, 1000.0, np.random.default_rng(0), dampers=far, **quiet)
    nl = simulate(th, v, 1000.0, np.random.default_rng(0), dampers=NonlinearDampers(), **quiet)
    assert np.abs(nl_far.states - lin.states).max() <= 1e-9 * np.abs(lin.states).max()
    yaw = lin.states[:, IDX["dpsi_b"]], nl.states[:, IDX["dpsi_b"]]
    assert np.sum(yaw[1] ** 2) > 1.2 * np.sum(yaw[0] ** 2)
    assert np.abs(yaw[1][200:]).max() > 2.0 * np.abs(yaw[0][200:]).max()


def test_a_held_track_input_enters_through_gamma_with_the_white_inputs_spectrum():
    """``track_input="held"`` (the paper's literal eqs. (6)-(7), an independent
    implementation's likely convention): each step's state noise lies in the span of the
    zero-order-hold Gamma (two held track velocities), and each held value has variance
    q fs, so the track's spectrum below fs / 2 is the white input's (whose state noise
    has full rank: Van Loan). With saturating dampers it is refused in one line."""
    fs, v, n = 1000.0, 42.5, 20_000
    theta = np.repeat(THETA_SEC42.as_array()[None], n, 0)
    A = system_matrix(VehicleParams(), THETA_SEC42, v)
    q = track_intensity(AR_PAPER_DEFAULT, v)
    d = discretize(A, input_matrix(), q, 1 / fs)
    for track_input in ("held", "white"):
        x = simulate(theta, np.full(n, v), fs, np.random.default_rng(2),
                     track_input=track_input).states
        w = x[1:] - x[:-1] @ d.phi.T                                   # (n - 1, 17)
        b, *_ = np.linalg.lstsq(d.gamma, w.T, rcond=None)             # (2, n - 1)
        off_span = np.linalg.norm(w.T - d.gamma @ b) / np.linalg.norm(w)
        if track_input == "held":
            assert off_span < 1e-9
            assert abs(b.var(axis=1) / (q * fs) - 1).max() < 0.03, b.var(axis=1) / (q * fs)
        else:
            assert off_span > 0.1
    with pytest.raises(InputError, match="expected track_input from"):
        simulate(theta[:10], np.full(10, v), fs, np.random.default_rng(2),
                 track_input="held", dampers=NonlinearDampers())
    with pytest.raises(InputError, match="got 'zoh'"):
        simulate(theta[:10], np.full(10, v), fs, np.random.default_rng(2), track_input="zoh")
