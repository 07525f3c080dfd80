"""``python -m gateway estimate`` and ``bench`` end to end, and the CSV grid rule."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.studies.accuracy import make_data
from gateway.cli import main
from gateway.model.vehicle import THETA_SEC42
from gateway.offline.grid import to_grid
from gateway.offline.interchange import read_csv, write_csv


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 s of Sec. 4.2 data, uneven times, a dropout and a gap, speed column."""
    Y = make_data(np.repeat(THETA_SEC42.as_array()[None], 2000, 0), 5, seed=3)
    rng = np.random.default_rng(0)
    t = np.arange(2000) / 1000.0 + rng.uniform(-1e-4, 1e-4, 2000)
    Y[500:520, 2] = np.nan                                  # acc_b dropout
    keep = np.ones(2000, dtype=bool)
    keep[1200:1210] = False                                 # 10 ms gap
    names = ("acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd")
    signals = {n: Y[keep, i] for i, n in enumerate(names)}
    signals["speed"] = np.full(keep.sum(), 42.5)
    path = tmp_path_factory.mktemp("rec") / "run.csv"
    write_csv(path, t[keep], signals)
    return path


def test_grid_rule(recording: Path) -> None:
    grid = to_grid(read_csv(recording), ("acc_b", "gyro_b", "acc_bd"), 42.5)
    assert abs(grid.fs_hz - 1000.0) < 10.0              # median of jittered steps
    at = int(np.argmin(np.abs(grid.t_s - 0.510)))
    assert np.isnan(grid.values[at, 0]) and np.isfinite(grid.values[at, 1])
    gap = (grid.t_s > 1.2012) & (grid.t_s < 1.2088)
    assert gap.sum() >= 6 and not grid.update[gap].any()  # no row at all: predict only
    assert grid.update[grid.t_s < 0.49].all()
    assert np.all(grid.speed_mps == 42.5)


def test_estimate_cli_end_to_end(recording: Path, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    out, png = tmp_path / "r.json", tmp_path / "r.png"
    code = main(["estimate", str(recording), "--report", str(out), "--particles", "64",
                 "--seed", "1", "--sensors", "5", "--plot", str(png)])
    assert code == 0
    doc = json.loads(out.read_text())
    for key in ("csy_ns_per_m", "csay_ns_per_m", "conicity"):
        assert set(doc["estimates"][key]) == {"mean", "std"}
        assert doc["estimates"][key]["mean"] > 0
    hist = doc["history"]
    assert len(hist) >= 150 and hist[1]["t_s"] - hist[0]["t_s"] == pytest.approx(0.01, 1e-2)
    assert {"t_s", "csy_ns_per_m_mean", "conicity_std", "ess"} <= set(hist[0])
    assert doc["settings"]["sensors"] == ["acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd"]
    assert doc["diagnostics"]["predict_only_samples"] >= 8
    assert png.stat().st_size > 10_000
    assert "csy_ns_per_m" in capsys.readouterr().out


def test_estimate_ar_option(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "ar.json"
    assert main(["estimate", str(recording), "--report", str(out), "--particles", "16",
                 "--estimate-ar", "--track-roughness", "1e-3"]) == 0
    doc = json.loads(out.read_text())
    assert "ar_paper" in doc["estimates"]
    assert doc["settings"]["track_roughness_ar_paper"] == 1e-3


@pytest.mark.parametrize("args, message", [
    (["missing.csv"], "expected a readable file"),
    (["--sensors", "5", "{three}"], "expected columns"),
    (["{bad}"], "expected a number"),
    (["{empty}"], "got none for ['gyro_b']"),
])
def test_estimate_bad_input_is_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    three = tmp_path / "three.csv"
    write_csv(three, np.arange(10) / 1000.0,
              {n: np.zeros(10) for n in ("acc_b", "gyro_b", "acc_bd")})
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,bogie_lat_acc_mps2,bogie_yaw_rate_radps,body_lat_acc_mps2\n"
                   "0.0,1,2,3\n0.001,x,2,3\n")
    empty = tmp_path / "empty.csv"
    write_csv(empty, np.arange(10) / 1000.0,
              {"acc_b": np.zeros(10), "gyro_b": np.full(10, np.nan), "acc_bd": np.zeros(10)})
    argv = [a.format(three=three, bad=bad, empty=empty) for a in args]
    proc = subprocess.run([sys.executable, "-m", "gateway", "estimate", *argv, "--report",
                           str(tmp_path / "o.json")], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr


def test_bench_json_small(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--json", "--particles", "16", "--seconds", "0.3",
                 "--steady-after-s", "0.1", "--naive-steps", "2"]) == 0
    r = json.loads(capsys.readouterr().out)["estimator"]
    for key in ("exact_rtf_steady", "naive_rtf", "ratio_steady", "available_cores"):
        assert r[key] > 0
