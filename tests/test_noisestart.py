"""The sensor-noise test at the start of a run: the band measurement, the decision, and
the filter that replaces the model's noise where the data reject it.

The data are the simulator's (``firmware_sim.truth.measured``) with a known sensor-noise
variance, the model's or a scaled one; what is checked is what was measured and what
the filter then estimates, against that truth.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from firmware_sim.output import write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from firmware_sim.truth import SENSOR_NOISE_VAR, measured
from gateway.config import Config, load_config
from gateway.errors import ConfigError
from gateway.estimator.noisefloor import band_variance, model_band_variance
from gateway.estimator.noisestart import NoiseCheckedStart, decide
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.vehicle import THETA_NOMINAL, VehicleParams, sensor_set
from gateway.records import Sample
from gateway.runtime.pipeline import build_estimator, restore_estimator

FS_HZ = 1000.0
V_MPS = 42.5


def _data(sensors: int, seconds: float, scale: float, seed: int) -> np.ndarray:
    """Nominal-θ measurements (T, ny) whose sensor-noise variance is ``scale`` x Qv."""
    n = int(round(seconds * FS_HZ))
    th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
    var = {k: v * scale for k, v in SENSOR_NOISE_VAR.items()}
    return measured(th, np.full(n, V_MPS), FS_HZ, sensor_set(sensors),
                    np.random.default_rng(seed), noise_var=var)


def _samples(Y: np.ndarray) -> list[Sample]:
    return [Sample((k + 1) / FS_HZ, Y[k], V_MPS, True) for k in range(len(Y))]


def _qv(sensors: int) -> np.ndarray:
    return np.array([SENSOR_NOISE_VAR[s] for s in sensor_set(sensors)])


# ---------------------------------------------------------------- the band
def test_the_band_reads_white_noise_as_its_variance() -> None:
    rng = np.random.default_rng(5)
    var = np.array([1.0, 4.0, 1e-2])
    got = band_variance(rng.standard_normal((20000, 3)) * np.sqrt(var), FS_HZ)
    assert got is not None and got.segments == 155
    z = (got.variance / var - 1.0) / got.se_rel
    assert np.all(np.abs(z) < 4.0), (got, z)
    assert np.all(got.se_rel < 0.03)


def test_missing_and_predict_only_samples_leave_their_segments_out() -> None:
    rng = np.random.default_rng(6)
    y = rng.standard_normal((5000, 2))
    y[1000:1010, 0] = np.nan
    usable = np.ones(5000, dtype=bool)
    usable[3000:3100] = False
    got = band_variance(y, FS_HZ, usable)
    whole = band_variance(rng.standard_normal((5000, 2)), FS_HZ)
    assert got is not None and whole is not None and got.segments < whole.segments
    assert np.all(np.isfinite(got.variance))
    assert band_variance(y[:1000], FS_HZ) is None          # fewer than 8 segments


@pytest.mark.parametrize("sensors", [3, 5])
def test_the_simulated_sensors_read_as_the_noise_they_were_given(sensors: int) -> None:
    """Signal plus noise: band minus the model's own signal is the noise variance; the
    model's signal in the band is the simulator's (noise-free run)."""
    Y = _data(sensors, 20.0, 1.0, seed=41)
    got = band_variance(Y, FS_HZ)
    assert got is not None
    signal = model_band_variance(VehicleParams(), THETA_NOMINAL.as_array(), V_MPS,
                                 sensor_set(sensors), 6.6e-4, FS_HZ)
    noise = got.variance - signal
    z = (noise / _qv(sensors) - 1.0) / got.se_rel
    assert np.all(np.abs(z) < 4.0), z
    clean = band_variance(_data(sensors, 20.0, 1e-12, seed=41), FS_HZ)
    assert clean is not None
    big = signal > 1e-3 * _qv(sensors)       # the wheelset and bogie accelerometers
    np.testing.assert_allclose(clean.variance[big], signal[big], rtol=0.2)


def test_the_decision_keeps_what_agrees_and_replaces_what_the_data_reject() -> None:
    model = np.array([1.0, 1.0, 1.0, 1.0])
    band = np.array([1.05, 1.96, 0.49, 1e-4])       # agrees, 1.4 x std, 0.7 x, filtered out
    used, replaced, _ = decide(model, band, np.zeros(4), np.full(4, 0.04))
    assert replaced.tolist() == [False, True, True, False]
    np.testing.assert_allclose(used, [1.0, 1.96, 0.49, 1.0])
    # a large model signal in the band makes the test less sure: 1.3 x is then kept
    _, replaced, se = decide(np.ones(1), np.array([2.3]), np.array([1.0]), np.array([0.04]))
    assert not replaced[0] and se[0] > 0.15


# ---------------------------------------------------------------- the filter
def _config(sensors: int = 3, particles: int = 64) -> RBPFConfig:
    return RBPFConfig(fs_hz=FS_HZ, n_particles=particles, sensors=sensors, seed=3,
                      mode="fast", walk_rel_per_sqrt_s=(0.01,) * 3)


def test_data_that_match_the_model_run_the_plain_filter_bit_for_bit() -> None:
    smp = _samples(_data(3, 6.0, 1.0, seed=42))
    checked = NoiseCheckedStart(_config())
    a = checked.run(smp, output_every=250)
    b = RBPF(_config()).run(smp, output_every=250)
    assert checked.result is not None and not any(checked.result.replaced)
    assert [repr(replace(x, provisional=False)) for x in a] == [repr(x) for x in b]
    # provisional until the first look at 2 s found nothing gross
    assert [x.provisional for x in a] == [x.t_s < 2.0 for x in a]
    assert checked.checkpoint() == checked.inner.checkpoint()   # the plain filter's


def test_louder_sensors_are_measured_and_the_filter_restarts_with_them() -> None:
    smp = _samples(_data(3, 6.0, 1.96, seed=43))
    checked = NoiseCheckedStart(_config())
    out = checked.run(smp, output_every=250)
    res = checked.result
    assert res is not None and all(res.replaced) and res.t_s == pytest.approx(5.0)
    np.testing.assert_allclose(np.array(res.used_var) / _qv(3), 1.96, rtol=0.15)
    assert checked.inner.config.noise_var == res.used_var
    # 1.96 x the variance is beyond the first look's 1.5 x: provisional until the test
    assert [x.provisional for x in out] == [x.t_s < 5.0 for x in out]
    # what comes after the test is the new filter's: the same as a filter given the
    # measured variances from the start (to rounding: it restarts from a checkpoint
    # taken before any data, which is ulps off after the first move)
    fresh = RBPF(replace(_config(), noise_var=res.used_var))
    want = fresh.run(smp, output_every=250)
    for a, b in zip(out[19:], want[19:], strict=True):
        assert a.t_s == b.t_s
        np.testing.assert_allclose(a.mean + a.std, b.mean + b.std, rtol=1e-8)
    assert not np.allclose(out[10].mean, want[10].mean, rtol=1e-4)   # before: the old R


def test_run_and_step_and_checkpoints_agree_through_the_test() -> None:
    """Outputs every 7 samples from run() equal step() one by one; a checkpoint taken
    during the test restores to the same continuation, through the replacement."""
    smp = _samples(_data(3, 5.3, 1.96, seed=44))
    a = NoiseCheckedStart(_config(particles=32))
    got = a.run(smp, output_every=7)
    b = NoiseCheckedStart(_config(particles=32))
    want = [b.step(s) for s in smp]
    want = [e for k, e in enumerate(want, 1) if k % 7 == 0 or k == len(smp)]
    assert [repr(x) for x in got] == [repr(x) for x in want]
    c = NoiseCheckedStart(_config(particles=32))
    c.run(smp[:3000], output_every=3000)
    c.restart_filters()
    blob = c.checkpoint()
    assert c.testing and not blob.startswith(b"RBPF")
    d = restore_estimator(blob)
    assert isinstance(d, NoiseCheckedStart) and d.testing
    assert [repr(x) for x in c.run(smp[3000:], 100)] == [repr(x) for x in d.run(smp[3000:], 100)]
    assert c.result is not None and any(c.result.replaced)
    after = restore_estimator(c.checkpoint())
    assert isinstance(after, RBPF) and after.config.noise_var == c.result.used_var


def test_the_service_builds_the_test_unless_told_to_keep_the_model() -> None:
    cfg = Config()
    assert cfg.estimator.sensor_noise == "measured"
    assert isinstance(build_estimator(cfg.estimator, FS_HZ), NoiseCheckedStart)


def test_a_start_at_standstill_waits_for_data_before_the_window() -> None:
    """Predict-only samples (the gate at standstill) before the first data: the window
    starts at the first data, and the replacement starts from the filter as it was
    then."""
    Y = _data(3, 7.5, 1.96, seed=45)
    smp = [Sample((k + 1) / FS_HZ, Y[k], V_MPS, k >= 2000) for k in range(len(Y))]
    checked = NoiseCheckedStart(_config(particles=32))
    checked.run(smp[:6999], output_every=500)
    assert checked.testing
    checked.run(smp[6999:], output_every=500)
    res = checked.result
    assert res is not None and res.t_s == pytest.approx(7.0) and all(res.replaced)
    np.testing.assert_allclose(np.array(res.used_var) / _qv(3), 1.96, rtol=0.15)


@pytest.mark.parametrize("scale", [1.0, 1.4])
def test_a_replay_measures_the_sensor_noise_of_the_nodes_on_the_bus(cli, tmp_path, scale
                                                                     ) -> None:
    """Through the whole path: simulated nodes (own clocks and phases, quantised frames)
    -> CAN log -> ``gateway replay`` (front end, a real worker process). The report says
    what the test found: the model's noise kept for the model's noise, and the louder
    sensors' variance (1.96 x) measured and used."""
    sim = Simulation(get_scenario("paper"), SimConfig(duration_s=6.5, seed=12,
                                                      noise_scale=scale))
    log = tmp_path / "run.log"
    write_log(list(sim.messages()), log)
    proc = cli("gateway", "replay", str(log), "--report", str(tmp_path / "r.json"),
               "--jsonl", str(tmp_path / "r.jsonl"), "--particles", "64", "--no-progress",
               timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads((tmp_path / "r.json").read_text())["diagnostics"]["sensor_noise"]
    assert got is not None and got["note"] == "", got
    rel = {s: v["band_var"] / v["model_var"] for s, v in got["sensors"].items()}
    replaced = {s: v["replaced"] for s, v in got["sensors"].items()}
    assert set(rel) == set(sensor_set(3))
    for s in rel:
        assert rel[s] == pytest.approx(scale**2, rel=0.15), rel
        assert replaced[s] == (scale != 1.0), (s, rel)
    assert ("replaced" in proc.stdout) == (scale != 1.0), proc.stdout


@pytest.mark.parametrize("resampler, refused", [
    ("lowpass_gyro_hz = 10.0", "lowpass_gyro_hz on"),
    ('interpolation = "linear"', 'interpolation = "linear"'),
])
def test_what_colours_the_noise_and_the_measured_noise_are_refused_together(
        tmp_path, resampler: str, refused: str) -> None:
    path = tmp_path / "gw.toml"
    path.write_text(f"[resampler]\n{resampler}\n")
    with pytest.raises(ConfigError, match=f'sensor_noise: expected "model" with .*{refused}'):
        load_config(path)
    path.write_text(f'[resampler]\n{resampler}\n[estimator]\nsensor_noise = "model"\n')
    assert load_config(path).estimator.sensor_noise == "model"


def test_nearest_interpolation_keeps_the_measured_noise_and_a_bad_choice_is_refused(
        tmp_path) -> None:
    path = tmp_path / "gw.toml"
    path.write_text('[resampler]\ninterpolation = "nearest"\n')
    assert load_config(path).estimator.sensor_noise == "measured"
    path.write_text("[estimator]\nsensor_noise = \"guess\"\n")
    with pytest.raises(ConfigError, match="sensor_noise"):
        load_config(path)


def test_data_too_gappy_to_measure_keep_the_model_and_say_why() -> None:
    """A sensor missing every 200th sample leaves no complete 256-sample segment: after
    four windows the test gives up, keeps the model's noise, says how far the data fell
    short (no complete segment; one sample in 200 incomplete), and its report is strict
    JSON."""
    Y = _data(3, 20.5, 1.96, seed=46)
    Y[1::200, 2] = np.nan
    smp = _samples(Y)
    checked = NoiseCheckedStart(_config(particles=16))
    checked.run(smp[:19999], output_every=1000)
    assert checked.testing
    checked.run(smp[19999:], output_every=1000)
    res = checked.noise_check()
    assert res is not None and not any(res.replaced) and "too few" in res.note
    assert ": 0 of 16 needed, 0.5 % of the last 20000 samples" in res.note, res.note
    assert res.used_var == res.model_var and res.t_s == pytest.approx(20.0)
    json.dumps(res.as_dict(), allow_nan=False)
