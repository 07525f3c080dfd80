"""Gating on real simulator traffic: speed window, curves, missing speed and sensors."""

from __future__ import annotations

import dataclasses
import math
import pickle
from functools import lru_cache

import numpy as np
import pytest

from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.codec import default_codec
from gateway.errors import ConfigError, StateError
from gateway.frontend.gating import REASONS, Gate, GateConfig
from gateway.frontend.resample import NO_LOWPASS_HZ, Resampler, ResamplerConfig
from gateway.records import DecodedFrame, GridSample, Quality, Sample

V_PAPER = 42.5
CONFIG = GateConfig(sensors=3, default_speed_mps=V_PAPER)
ENTER_MPS2 = 0.25
EXIT_MPS2 = 0.125
"""The default curve detector: |yaw_rate_lp| * v in at 0.25, out below 0.125 m/s^2."""


@lru_cache(maxsize=4)
def traffic(scenario: str, duration_s: float, nodes: tuple[str, ...] = ("WSN", "BGN", "BDN", "VEH")
            ) -> tuple[DecodedFrame, ...]:
    sim = Simulation(get_scenario(scenario), SimConfig(duration_s=duration_s, seed=11,
                                                       nodes=nodes))
    codec = default_codec()
    return tuple(codec.decode_message(m) for m in sim.messages())


def grid(frames, suspect=lambda f: False) -> list[GridSample]:
    rs = Resampler(ResamplerConfig(fs_hz=1000.0, lowpass_hz=NO_LOWPASS_HZ),
                   periods_s=default_codec().sensor_periods_s())
    out: list[GridSample] = []
    for f in frames:
        out.extend(rs.push(f, suspect=suspect(f)))
        out.extend(rs.pop_ready(f.timestamp_s))
    return out


def gate(samples: list[GridSample], config: GateConfig = CONFIG
         ) -> tuple[Gate, list[Sample], list[str]]:
    g = Gate(config)
    out, reasons = [], []
    for s in samples:
        before = g.counts
        out.append(g.apply(s))
        reasons.append(next(r for r in REASONS if g.counts[r] > before[r]))
    return g, out, reasons


def test_defaults_match_the_documented_thresholds():
    assert (GateConfig(sensors=3).curve_lat_acc_mps2, GateConfig(sensors=3).curve_exit_ratio
            ) == (ENTER_MPS2, EXIT_MPS2 / ENTER_MPS2)


def test_speed_window_using_the_speed_profile():
    samples = grid(traffic("speed-profile", 8.0))   # 20 -> 42.5 m/s by 2.4 s, 30 m/s at 8 s
    config = dataclasses.replace(CONFIG, speed_min_mps=25.0, speed_max_mps=40.0)
    g, out, reasons = gate(samples, config)
    v = np.array([s.speed_mps for s in samples])
    update = np.array([s.update for s in out])
    settled = np.array([s.t_s > 0.05 for s in samples])
    np.testing.assert_array_equal(update[settled], ((v >= 25.0) & (v <= 40.0))[settled])
    r = np.array(reasons)
    assert np.all(r[settled & (v < 25.0)] == "speed_low")
    assert np.all(r[settled & (v > 40.0)] == "speed_high")
    assert {"speed_low", "speed_high", "updated"} <= set(r[settled])
    assert "curve" not in r                          # straight track: no false curve
    assert g.counts["updated"] == update.sum() and sum(g.counts.values()) == len(samples)
    np.testing.assert_array_equal([s.speed_mps for s in out[100:]], v[100:])


def with_yaw_rate(frames, add_radps: float, t0_s: float, t1_s: float) -> list[DecodedFrame]:
    """The frames with a constant yaw rate added to the bogie gyro in [t0, t1)."""
    def bend(f: DecodedFrame) -> DecodedFrame:
        if f.message != "BGN_Lat" or not t0_s <= f.timestamp_s < t1_s:
            return f
        return dataclasses.replace(f, values={**f.values,
                                              "BGN_YawRate": f.values["BGN_YawRate"] + add_radps})
    return [bend(f) for f in frames]


def test_a_curve_is_gated_with_hysteresis_and_a_hold_time():
    frames = with_yaw_rate(traffic("nominal", 8.0), 0.02, 2.0, 3.0)   # R ~ 2 km at 42.5 m/s
    samples = grid(frames)
    _, out, reasons = gate(samples)
    t = np.array([s.t_s for s in samples])
    a_lat = np.abs([s.yaw_rate_lp_radps for s in samples]) * V_PAPER
    r = np.array(reasons)
    curve = r == "curve"
    first, last = np.flatnonzero(curve)[[0, -1]]
    assert 2.0 < t[first] < 2.4 and a_lat[first] >= ENTER_MPS2 > a_lat[first - 1]
    exit_t = t[np.flatnonzero((t > 3.0) & (a_lat < EXIT_MPS2))[0]]  # a_lat fell below exit
    assert np.all(a_lat[(t >= t[first]) & (t < exit_t)] >= EXIT_MPS2)   # hysteresis
    assert t[last] == pytest.approx(exit_t + CONFIG.straight_hold_s, abs=2e-3)
    assert np.all(curve[first:last + 1])
    assert np.all(r[(t > 0.05) & (t < 2.0)] == "updated")
    assert np.all(r[t > t[last] + 0.01] == "updated")
    assert not any(s.update for s in out[first:last + 1])
    by_yaw_rate = dataclasses.replace(CONFIG, curve_lat_acc_mps2=None,
                                      curve_yaw_rate_max_radps=0.01)   # the service's form
    _, _, reasons_yaw = gate(samples, by_yaw_rate)
    curve_yaw = np.array(reasons_yaw) == "curve"
    first_yaw = np.flatnonzero(curve_yaw)[0]
    assert abs(samples[first_yaw].yaw_rate_lp_radps) >= 0.01 > abs(
        samples[first_yaw - 1].yaw_rate_lp_radps)
    assert np.array_equal(curve_yaw[t < 1.9], np.zeros(np.sum(t < 1.9), dtype=bool))


def test_without_speed_the_estimator_predicts_with_the_last_or_default_speed():
    samples = grid(traffic("nominal", 2.0, nodes=("WSN", "BGN", "BDN")))
    _, out, reasons = gate(samples)
    assert all(math.isnan(s.speed_mps) for s in samples)
    assert set(reasons) == {"no_speed"} and not any(s.update for s in out)
    assert all(s.speed_mps == V_PAPER for s in out)
    frames = [f for f in traffic("nominal", 2.0) if f.message != "VEH_Speed"
              or f.timestamp_s < 1.0]                # the vehicle node goes quiet at 1 s
    samples = grid(frames)
    _, out, reasons = gate(samples, dataclasses.replace(CONFIG, default_speed_mps=10.0))
    t = np.array([s.t_s for s in samples])
    quiet = t > 1.0 + 0.1 + 0.02                     # after the speed timeout
    assert np.all(np.array(reasons)[quiet] == "no_speed")
    assert all(s.speed_mps == pytest.approx(V_PAPER) for s in np.array(out)[quiet])


def test_no_usable_sensor_and_sensor_selection():
    frames = [f for f in traffic("nominal", 2.0)
              if f.message not in ("BGN_Lat", "BDN_Lat") or not 1.0 <= f.timestamp_s < 1.5]
    samples = grid(frames, suspect=lambda f: f.message == "WSN_Lat")
    _, out3, reasons = gate(samples)
    t = np.array([s.t_s for s in samples])
    gap = (t > 1.01) & (t < 1.49)
    assert np.all(np.array(reasons)[gap] == "no_sensor")     # yaw gap < yaw_hold_s
    assert all(np.isnan(s.values).all() and not s.update for s in np.array(out3)[gap])
    assert out3[500].values.shape == (3,) and out3[500].update
    np.testing.assert_array_equal(out3[500].values, samples[500].values[[2, 3, 4]])
    assert np.all(samples[500].quality[:2] == Quality.SUSPECT)
    _, out5, _ = gate(samples, dataclasses.replace(CONFIG, sensors=5))
    assert out5[500].values.shape == (5,) and np.isnan(out5[500].values[:2]).all()
    _, out5s, _ = gate(samples, dataclasses.replace(CONFIG, sensors=5, use_suspect=True))
    np.testing.assert_array_equal(out5s[500].values, samples[500].values)


def test_gate_checkpoint_restores_identically_and_config_is_checked():
    frames = with_yaw_rate(traffic("nominal", 8.0), 0.02, 2.0, 3.0)
    samples = grid(frames)
    _, ref, _ = gate(samples)
    g = Gate(CONFIG)
    out = [g.apply(s) for s in samples[:2500]]              # inside the curve
    g = Gate(CONFIG, pickle.loads(pickle.dumps(g.snapshot())))
    out += [g.apply(s) for s in samples[2500:]]
    assert [s.update for s in out] == [s.update for s in ref]
    with pytest.raises(StateError):
        Gate(dataclasses.replace(CONFIG, sensors=5), g.snapshot())
    with pytest.raises(ConfigError, match="expected sensors 3 or 5"):
        GateConfig(sensors=4)
    with pytest.raises(ConfigError, match="curve_exit_ratio"):
        GateConfig(sensors=3, curve_exit_ratio=1.5)
    with pytest.raises(ConfigError, match="curve_lat_acc_mps2 and/or"):
        GateConfig(sensors=3, curve_lat_acc_mps2=None)
