"""``python -m gateway identify``: bad input gives one line and a non-zero exit."""

import json

import numpy as np
import pytest

from gateway.cli import main
from gateway.identify.track import random_track, write_track_csv
from gateway.offline.interchange import write_csv


def _run(argv, capsys):
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _write_run(path, n=2000, fs=200.0, constant=None, drop=None):
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    signals = {s: 0.1 * rng.standard_normal(n) for s in ("acc_b", "gyro_b", "acc_bd")}
    if constant:
        signals[constant] = np.full(n, 0.25)
    if drop:
        del signals[drop]
    signals["speed"] = np.full(n, 42.5)
    write_csv(path, t, signals)
    return path


def _one_line_error(code, err, *fragments):
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ")
    assert "Traceback" not in err
    for f in fragments:
        assert f in lines[0]


def test_missing_column(tmp_path, capsys):
    data = _write_run(tmp_path / "d.csv", drop="acc_bd")
    code, _, err = _run(["identify", "run", str(data)], capsys)
    _one_line_error(code, err, "body_lat_acc_mps2", "expected header columns")


def test_missing_requested_sensor(tmp_path, capsys):
    data = _write_run(tmp_path / "d.csv")
    code, _, err = _run(["identify", "run", str(data), "--sensors", "acc_w1,acc_b"], capsys)
    _one_line_error(code, err, "wheelset1_lat_acc_mps2", "expected columns")


def test_constant_signal(tmp_path, capsys):
    data = _write_run(tmp_path / "d.csv", constant="gyro_b")
    code, _, err = _run(["identify", "run", str(data)], capsys)
    _one_line_error(code, err, "bogie_yaw_rate_radps", "expected a varying signal",
                    "got the constant value 0.25")


def test_section_outside_the_data(tmp_path, capsys):
    data = _write_run(tmp_path / "d.csv")
    code, _, err = _run(["identify", "run", str(data), "--section", "5:30"], capsys)
    _one_line_error(code, err, "learn section 5-30 s", "expected a range within the recording")


def test_track_csv_without_alignment_column(tmp_path, capsys):
    data = _write_run(tmp_path / "d.csv")
    track = tmp_path / "t.csv"
    track.write_text("position_m,alignment\n0,0\n1,0\n")
    code, _, err = _run(["identify", "run", str(data), "--track", str(track)], capsys)
    _one_line_error(code, err, "lateral_alignment_m", "expected header columns")


def test_no_speed(tmp_path, capsys):
    rng = np.random.default_rng(0)
    n = 500
    write_csv(tmp_path / "d.csv", np.arange(n) / 200.0,
              {s: rng.standard_normal(n) for s in ("acc_b", "gyro_b", "acc_bd")})
    code, _, err = _run(["identify", "run", str(tmp_path / "d.csv")], capsys)
    _one_line_error(code, err, "expected a speed_mps column or a --speed-mps value")


def test_synth_then_run_end_to_end(tmp_path, capsys):
    """A short known-track run through the command line, report and figures included."""
    out = tmp_path / "syn"
    code, _, _ = _run(["identify", "synth", "--out", str(out), "--duration-s", "14",
                       "--perturb", "Kx=+20,Csay=-20", "--seed", "2"], capsys)
    assert code == 0
    rep = tmp_path / "rep"
    code, stdout, _ = _run(["identify", "run", str(out / "data.csv"), "--track",
                            str(out / "track.csv"), "--track-offset-m", "500",
                            "--section", "2:12", "--params", "Kx,Csay", "--methods", "nm,ps",
                            "--local-maxfev", "120", "--workers", "1", "--truth",
                            str(out / "truth.json"), "--out", str(rep)], capsys)
    assert code == 0, stdout
    doc = json.loads((rep / "report.json").read_text())
    assert [r["key"] for r in doc["table1"]] == ["nm", "ps"]
    assert doc["synchronisation"][0]["lag_samples"] == 0
    for f in ("signals.png", "parameters.png", "convergence.png"):
        assert (rep / f).stat().st_size > 1000
    errs = [abs(v["error_vs_truth"]) for v in doc["parameters"]["ps"].values()]
    assert max(errs) < 0.05


@pytest.mark.parametrize("bad", ["Kx=abc", "Zz=+5"])
def test_synth_bad_perturbation(tmp_path, capsys, bad):
    code, _, err = _run(["identify", "synth", "--out", str(tmp_path), "--perturb", bad],
                        capsys)
    _one_line_error(code, err, "expected")


def test_track_helper_round_trip(tmp_path):
    from gateway.identify.track import read_track_csv
    tr = random_track(100.0, 0.5, 1e-3, np.random.default_rng(0))
    write_track_csv(tmp_path / "t.csv", tr)
    back = read_track_csv(tmp_path / "t.csv")
    assert np.array_equal(back.position_m, tr.position_m)
    assert np.array_equal(back.alignment_m, tr.alignment_m)


def test_no_track_uses_the_prediction_error_path(tmp_path, capsys):
    from firmware_sim.truth import add_sensor_noise, select, simulate
    from gateway.model.vehicle import SENSORS_3, THETA_SEC42

    n, fs = 6000, 200.0
    rng = np.random.default_rng(8)
    run = simulate(np.repeat(THETA_SEC42.as_array()[None], n, 0), np.full(n, 42.5), fs, rng)
    y = add_sensor_noise(select(run.outputs, SENSORS_3), SENSORS_3, rng)
    signals = {s: y[:, i] for i, s in enumerate(SENSORS_3)}
    write_csv(tmp_path / "d.csv", run.t_s, signals)
    code, out, _ = _run(["identify", "run", str(tmp_path / "d.csv"), "--speed-mps", "42.5",
                         "--out", str(tmp_path / "rep")], capsys)
    assert code == 0
    doc = json.loads((tmp_path / "rep" / "report.json").read_text())
    est = doc["estimates"]
    truth = THETA_SEC42.as_array()
    for name, t in zip(("csy_ns_per_m", "csay_ns_per_m", "conicity"), truth, strict=True):
        assert abs(est[name]["value"] / t - 1) < 0.08, (name, est[name])
        assert abs(est[name]["value"] - t) < 4 * est[name]["std"] + 1e-12
    assert "csy_ns_per_m" in out
