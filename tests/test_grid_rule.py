"""The offline tools' one recording -> grid rule (gateway.offline.grid): estimate and identify."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.errors import InputError
from gateway.identify.data import dataset_from_recording
from gateway.offline.grid import interpolate, to_grid
from gateway.offline.interchange import Recording

FS_HZ = 200.0
SENSORS = ("acc_b", "gyro_b")


def _record(t_s: np.ndarray, dropout: int | None = None) -> Recording:
    acc = np.sin(2 * np.pi * 1.3 * t_s)
    gyro = np.cos(2 * np.pi * 0.7 * t_s)
    if dropout is not None:
        acc = acc.copy()
        acc[dropout] = np.nan
    return Recording(t_s=t_s, signals={"acc_b": acc, "gyro_b": gyro,
                                       "speed": np.full(len(t_s), 40.0)}, source="run.csv")


def test_a_dropout_is_missing_for_estimate_and_bridged_for_identify() -> None:
    t = np.arange(400) / FS_HZ
    rec = _record(t, dropout=150)
    grid = to_grid(rec, SENSORS, 40.0)
    data = dataset_from_recording(rec, SENSORS)
    assert grid.fs_hz == data.fs_hz == pytest.approx(FS_HZ, rel=1e-12)
    assert np.isnan(grid.values[150, 0]) and grid.update[150]      # gyro still there
    acc = rec.signals["acc_b"]
    assert data.measured[150, 0] == pytest.approx(0.5 * (acc[149] + acc[151]), rel=1e-12)
    keep = np.isfinite(grid.values)
    assert np.allclose(grid.values[keep], data.measured[keep], rtol=0, atol=1e-12)


def test_the_gap_threshold_is_one_and_a_half_periods() -> None:
    t = np.array([0.0, 1.0, 2.0, 3.5, 4.0, 6.0])
    x = t * 2.0
    grid = np.array([0.5, 2.5, 3.0, 5.0])
    got = interpolate(grid, t, x, 1.0, bridge=False)
    assert got[0] == 1.0 and got[1] == 5.0                 # neighbours 1 and 1.5 apart
    assert np.isnan(got[3])                                # 2.0 apart: missing
    assert np.array_equal(interpolate(grid, t, x, 1.0, bridge=True), grid * 2.0)


def test_uneven_times_are_gridded_for_estimate_and_refused_by_identify() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(400) / FS_HZ + rng.uniform(-5e-4, 5e-4, 400)
    rec = _record(t)
    grid = to_grid(rec, SENSORS, 40.0)
    assert np.allclose(np.diff(grid.t_s), 1.0 / grid.fs_hz, rtol=1e-9, atol=0)
    with pytest.raises(InputError, match="expected uniform sampling"):
        dataset_from_recording(rec, SENSORS)


def test_uneven_times_keep_white_noise_white_and_a_signal_exact() -> None:
    # issue 15: a recording on a clock 300 ppm fast against its grid sweeps every
    # fraction between samples; linear interpolation there halves and correlates the
    # noise, the band-limited fractional delay (gateway.frontend.fracdelay) does not
    n = 8000
    t = np.arange(n) * (1 + 300e-6) / FS_HZ + 0.3 / FS_HZ
    rng = np.random.default_rng(4)
    noise = rng.standard_normal(n)
    grid_t = t[0] + np.arange(n - 40) / FS_HZ
    inner = slice(20, -20)
    got = interpolate(grid_t, t, noise, 1 / FS_HZ, bridge=False)[inner]
    lin = np.interp(grid_t, t, noise)[inner]
    assert 0.9 < got.var() < 1.05 and abs(np.corrcoef(got[1:], got[:-1])[0, 1]) < 0.1
    assert lin.var() < 0.75                              # what linear does
    signal = np.sin(2 * np.pi * 37.0 * t)               # 0.19 of the rate, band-limited
    got = interpolate(grid_t, t, signal, 1 / FS_HZ, bridge=False)[inner]
    want = np.sin(2 * np.pi * 37.0 * grid_t)[inner]
    assert np.abs(got - want).max() < 1e-3
    assert np.abs(np.interp(grid_t, t, signal)[inner] - want).max() > 0.05
