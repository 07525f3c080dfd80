"""CAN-log input to ``identify``: the gateway's front end turns a log into the CSV's Recording.

The same simulated run is written twice: as the CAN log the nodes sent
(``firmware_sim.output.write_log``) and as an interchange CSV of the nodes' own sample
values put on a 1 kHz grid of the vehicle's (true) clock. Both must give the same
identification answer.
"""

import json

import can
import numpy as np
import pytest
from test_identify_cli import _one_line_error, _run

from firmware_sim.output import write_log
from firmware_sim.scenarios import V_PAPER, get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.config import INTERPOLATIONS, Config, with_overrides
from gateway.identify.canlog import read_can_log
from gateway.model.vehicle import SENSOR_NOISE_VAR, SENSORS_3, SENSORS_5
from gateway.offline.grid import interpolate
from gateway.offline.interchange import write_csv

FS_HZ = 1000.0
RESOLUTION = {"acc_w1": 5e-4, "acc_w2": 5e-4, "acc_b": 5e-4, "gyro_b": 5e-5, "acc_bd": 5e-4}
"""The DBC's scale of each sensor signal (docs/can-bus.md)."""


def _interchange_of(sim: Simulation, duration_s: float) -> tuple[np.ndarray, dict]:
    """The nodes' sample values on the grid k / FS_HZ of true time, by the offline tools'
    rule (the resampler's band-limited fractional delay; speed linear)."""
    t = np.arange(int(duration_s * FS_HZ)) / FS_HZ
    signals = {}
    for rec in sim.records.values():
        t_node = np.concatenate(rec.t_true_s)
        for q in (*SENSORS_5, "speed"):
            if rec.values.get(q):
                signals[q] = interpolate(t, t_node, rec.array(q), float(np.median(
                    np.diff(t_node))), bridge=False)
    return t, signals


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    """The paper's Sec. 4.2 scenario, 5 s, 5 sensors: (log path, csv path)."""
    out = tmp_path_factory.mktemp("paper")
    sim = Simulation(get_scenario("paper"), SimConfig(duration_s=5.0, seed=0), record=True)
    write_log(sim.messages(), out / "run.log")
    write_csv(out / "run.csv", *_interchange_of(sim, 5.0))
    return out / "run.log", out / "run.csv"


@pytest.mark.parametrize("interpolation", INTERPOLATIONS)
@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
def test_log_becomes_the_recording_of_its_samples(tmp_path, suffix, interpolation):
    """Any python-can log: all sensors, uniform grid, the nodes' values, the VEH speed."""
    sim = Simulation(get_scenario("paper"), SimConfig(duration_s=1.0, seed=3), record=True)
    write_log(sim.messages(), tmp_path / f"run{suffix}")
    cfg = with_overrides(Config(), {"resampler.interpolation": interpolation,
                                    "estimator.sensor_noise": "model"})
    rec = read_can_log(tmp_path / f"run{suffix}", cfg)
    assert rec.sensors == SENSORS_5
    dt = np.diff(rec.t_s)
    assert np.allclose(dt, 1 / FS_HZ, rtol=1e-9, atol=0)
    assert 0 <= rec.t_s[0] < 0.02 and rec.t_s[-1] > 0.98
    assert np.allclose(rec.signals["speed"], V_PAPER)
    t_csv, csv = _interchange_of(sim, 1.0)
    for s in SENSORS_5:
        if interpolation == "nearest":     # every grid value is one of the node's samples
            assert sim.records is not None
            node = next(r for r in sim.records.values() if r.values.get(s))
            t_node, v = np.concatenate(node.t_true_s), node.array(s)
            for t, x in zip(rec.t_s[5:-5], rec.signals[s][5:-5], strict=True):
                near = v[np.abs(t_node - t) < 4e-3]       # receive time = true + latency
                assert np.min(np.abs(near - x)) <= 0.6 * RESOLUTION[s], (s, t)
            continue
        ref = np.interp(rec.t_s, t_csv, csv[s])      # true time ~ receive time - latency
        err = rec.signals[s][5:-5] - ref[5:-5]   # the sensor noise, interpolated differently
        bound = 0.1 * np.std(ref[5:-5]) + 0.7 * np.sqrt(SENSOR_NOISE_VAR[s])
        assert np.sqrt(np.mean(err**2)) < bound, s


def test_three_sensor_log(tmp_path):
    cfg = SimConfig(duration_s=1.0, seed=1, nodes=("BGN", "BDN", "VEH"))
    write_log(Simulation(get_scenario("paper"), cfg).messages(), tmp_path / "run.log")
    assert read_can_log(tmp_path / "run.log").sensors == SENSORS_3


@pytest.mark.slow
def test_log_and_csv_of_one_run_give_the_same_prediction_error_answer(paper_run, capsys):
    """No track: Csy, Csay and lambda from the log agree with those from the CSV."""
    docs = []
    for data in paper_run:
        rep = data.parent / f"rep-{data.suffix[1:]}"
        code, out, err = _run(["identify", "run", str(data), "--out", str(rep)], capsys)
        assert code == 0, err
        docs.append(json.loads((rep / "report.json").read_text())["estimates"])
    from_log, from_csv = docs
    truth = {"csy_ns_per_m": 20e3, "csay_ns_per_m": 3000e3, "conicity": 0.15}
    for name, value in truth.items():
        a, b = from_log[name], from_csv[name]
        assert abs(a["value"] - b["value"]) <= 0.5 * b["std"], (name, a, b)
        assert abs(a["std"] / b["std"] - 1) < 0.05, (name, a, b)
        assert abs(a["value"] / value - 1) < 0.10, (name, a)


def test_empty_log(tmp_path, capsys):
    (tmp_path / "run.log").write_text("")
    code, _, err = _run(["identify", "run", str(tmp_path / "run.log")], capsys)
    _one_line_error(code, err, "run.log: expected CAN frames, got an empty log")


def test_unreadable_blf(tmp_path, capsys):
    (tmp_path / "run.blf").write_bytes(b"")
    code, _, err = _run(["identify", "run", str(tmp_path / "run.blf")], capsys)
    _one_line_error(code, err, "expected a CAN log python-can can read")


def test_log_without_sensor_frames(tmp_path, capsys):
    frames = [can.Message(timestamp=k * 1e-3, arbitration_id=0x7F0, is_extended_id=False,
                          data=bytes(8)) for k in range(50)]
    write_log(frames, tmp_path / "run.asc")
    code, _, err = _run(["identify", "run", str(tmp_path / "run.asc")], capsys)
    _one_line_error(code, err, "expected valid sensor frames", "got none in 50 frames",
                    "unknown_id 50")


def test_log_the_gate_refuses(tmp_path, capsys):
    """A speed below the gate's window: no grid point is usable, and the reason is named."""
    write_log(Simulation(get_scenario("paper"), SimConfig(duration_s=0.5, seed=2)).messages(),
              tmp_path / "run.log")
    code, _, err = _run(["identify", "run", str(tmp_path / "run.log"), "--speed-mps", "5"],
                        capsys)
    _one_line_error(code, err, "expected grid points the gate passes", "speed_low")


def test_unknown_extension(tmp_path, capsys):
    (tmp_path / "run.dat").write_text("x")
    code, _, err = _run(["identify", "run", str(tmp_path / "run.dat")], capsys)
    _one_line_error(code, err, "expected an interchange CSV (.csv) or a CAN log "
                    "(.log, .asc, .blf, .trc, .mf4), got")


@pytest.mark.slow
def test_node_phase_does_not_move_the_maximum_likelihood_answer(tmp_path, capsys):
    """Issue 15, node timing, without particle noise: the paper run (5 sensors, 5 s) with
    every lateral node on the grid, half-way between grid points, and at its own phase
    and drift (+-50 ppm), the same truth and the same noise on each sample
    (``noise_by_sample``). The prediction-error answer moved λ by -7.3 % with linear
    interpolation half-way (docs/resampler.md "Node timing"); with the fractional delay
    every case must stay within 1 % of the aligned one, the dampers too."""
    from firmware_sim.studies.timing import set_clocks

    answers = {}
    for case in ("aligned", "half", "drift"):
        sim = Simulation(get_scenario("paper"),
                         SimConfig(duration_s=5.0, seed=0, noise_by_sample=True))
        set_clocks(sim, case, np.random.default_rng(0))
        write_log(sim.messages(), tmp_path / f"{case}.log")
        for interpolation in ("sinc", "linear") if case != "drift" else ("sinc",):
            conf = tmp_path / f"{interpolation}.toml"
            conf.write_text(f'[resampler]\ninterpolation = "{interpolation}"\n'
                            f'[estimator]\nsensor_noise = "model"\n')
            rep = tmp_path / f"rep-{case}-{interpolation}"
            code, _, err = _run(["identify", "run", str(tmp_path / f"{case}.log"), "--out",
                                 str(rep), "--config", str(conf)], capsys)
            assert code == 0, err
            est = json.loads((rep / "report.json").read_text())["estimates"]
            answers[case, interpolation] = {k: v["value"] for k, v in est.items()}
    for case in ("half", "drift"):
        for name in ("csy_ns_per_m", "csay_ns_per_m", "conicity"):
            moved = answers[case, "sinc"][name] / answers["aligned", "sinc"][name] - 1
            assert abs(moved) < 0.01, (case, name, answers)
    lam_linear = answers["half", "linear"]["conicity"] / answers["aligned", "linear"]["conicity"]
    assert lam_linear < 0.97, answers           # the defect the fractional delay removes
