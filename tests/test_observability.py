"""What a set of sensors can tell about each parameter (gateway.estimator.observability).

The Whittle bound is checked against the exact Kalman filter's own log-likelihood on
simulated records (its curvature in each parameter is the observed information), and
the parameters it calls unresolved are those the dead-node campaigns could not follow
(docs/estimator.md "Dead sensors": with the body node out of a 3-sensor vehicle a Csy
failure was found in 1 record of 10; with the wheelset node out of a 5-sensor one every
fault was found).
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.oracle import exact_filter, model
from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.estimator import observability as obs
from gateway.model.coordinates import FilterCoords
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    PARAM_NAMES,
    SENSOR_NOISE_VAR,
    THETA_NOMINAL,
    sensor_set,
    track_intensity,
)

FS_HZ = 1000.0
COORDS = FilterCoords.build()
THETA = THETA_NOMINAL.as_array()


def _without(n: int, *gone: str) -> tuple[str, ...]:
    return tuple(s for s in sensor_set(n) if s not in gone)


def _rate(sensors: tuple[str, ...], v_mps: float) -> np.ndarray:
    return obs.information_rate(COORDS, THETA, v_mps, COORDS.output(sensors, v_mps),
                                np.array([SENSOR_NOISE_VAR[s] for s in sensors]),
                                float(track_intensity(AR_PAPER_DEFAULT, v_mps)), FS_HZ)


def _unresolved(sensors: tuple[str, ...], v_mps: float) -> tuple[str, ...]:
    J = _rate(sensors, v_mps)
    bound = np.sqrt(np.diag(np.linalg.inv(J)) / obs.HORIZON_S)
    return obs.unresolved(PARAM_NAMES, bound)


def _loglik(theta: np.ndarray, sensors: tuple[str, ...], v_mps: float,
            Y: np.ndarray) -> float:
    """The exact 17-state filter's log-likelihood of ``Y`` at ``theta``, from the
    stationary covariance (no start-up transient)."""
    phi, qd, H, r = model(theta, sensors, 1.0, v_mps)
    phi_k, P = phi, qd
    for _ in range(14):              # doubling: the covariance 16 s after a start at rest
        P, phi_k = P + phi_k @ P @ phi_k.T, phi_k @ phi_k
    _, _, ll = exact_filter(phi, qd, H, r, np.zeros(len(P)), 0.5 * (P + P.T), Y)
    return float(ll.sum())


@pytest.mark.parametrize("sensors, parameter, records, tol", [
    (sensor_set(3), 2, 2, 0.06), (sensor_set(3), 0, 6, 0.25),
    (_without(3, "acc_bd"), 0, 6, 0.25)])
def test_the_bound_is_the_filters_own_information(sensors, parameter, records, tol) -> None:
    """On 12 s records at 42.5 m/s the exact filter's observed information about one
    parameter (the curvature of its log-likelihood in log θ), averaged over the records,
    is the Whittle rate times 12 s within ``tol``: so is the collapse of Csy's
    information when the body node is left out (about 200 x). One record's observed
    information spreads about 2 % for λ and 25-30 % for Csy (measured over 8 seeds:
    means 1.01, 0.91, 0.98)."""
    v_mps, n = 42.5, 12_000
    h = 0.2 if "acc_bd" not in sensors else 0.02
    ratios = []
    for seed in range(71, 71 + records):
        rng = np.random.default_rng(seed)
        truth = simulate(np.repeat(THETA[None], n, 0), np.full(n, v_mps), FS_HZ, rng)
        Y = add_sensor_noise(select(truth.outputs, sensors), sensors, rng)
        ll = []
        for k in (-1, 0, 1):
            th = THETA.copy()
            th[parameter] *= np.exp(k * h)
            ll.append(_loglik(th, sensors, v_mps, Y))
        observed = -(ll[0] - 2 * ll[1] + ll[2]) / h**2
        ratios.append(observed / (_rate(sensors, v_mps)[parameter, parameter] * n / FS_HZ))
    assert abs(np.mean(ratios) - 1.0) < tol, ratios


@pytest.mark.parametrize("v_mps", [20.0, 42.5, 70.0])
def test_unresolved_names_what_the_dead_node_campaigns_could_not_follow(v_mps) -> None:
    """Every sensor: nothing unresolved. The body node out of a 3-sensor set: Csy alone
    (found in 1 of 10 records; Csay found in 9 of 10). The wheelset node out of a
    5-sensor set: nothing (40 of 40 found)."""
    assert _unresolved(sensor_set(3), v_mps) == ()
    assert _unresolved(sensor_set(5), v_mps) == ()
    assert _unresolved(_without(3, "acc_bd"), v_mps) == ("csy_ns_per_m",)
    assert _unresolved(_without(5, "acc_w1", "acc_w2"), v_mps) == ()


def test_below_the_gates_speed_even_every_sensor_leaves_the_dampers_unresolved() -> None:
    """The track excites the vehicle less at low speed: 13 m/s with the 3-sensor set
    cannot resolve either damper (15 m/s, the gate's default lower edge, both just)."""
    assert _unresolved(sensor_set(3), 13.0) == ("csy_ns_per_m", "csay_ns_per_m")
    assert _unresolved(sensor_set(3), 15.5) == ()


def test_the_bound_shrinks_with_the_horizon_and_bands_hold_a_speed() -> None:
    """sqrt(1/T) in the horizon; a band's centre is within half a band of the speed."""
    args = (COORDS, THETA, 42.5, COORDS.output(sensor_set(3), 42.5),
            np.array([SENSOR_NOISE_VAR[s] for s in sensor_set(3)]),
            float(track_intensity(AR_PAPER_DEFAULT, 42.5)), FS_HZ)
    np.testing.assert_allclose(obs.bound_rel(*args, horizon_s=20.0) * 2.0,
                               obs.bound_rel(*args, horizon_s=5.0), rtol=1e-12)
    for v in (15.0, 20.0, 33.3, 42.5, 70.0):
        c = obs.band_speed(v)
        assert abs(np.log(c / v)) <= np.log1p(obs.SPEED_BAND_REL) / 2 + 1e-12
        assert obs.band_speed(c) == pytest.approx(c, rel=1e-12)


def test_a_filter_names_what_its_speed_band_cannot_resolve() -> None:
    """Every sensor of the 3-sensor set: at 13 m/s (below the gate's default 15 m/s) the
    estimates call both dampers unresolved, at 40 m/s nothing; the bound is asked once per
    speed band, not at each of the filter's 0.2 % speed steps."""
    from gateway.estimator.rbpf import RBPF, RBPFConfig
    from gateway.records import Sample

    n = 1200
    v = np.where(np.arange(n) < n // 2, 13.0, 40.0) * (1 + 1e-3 * np.arange(n) / n)
    rng = np.random.default_rng(74)
    truth = simulate(np.repeat(THETA[None], n, 0), v, FS_HZ, rng)
    Y = add_sensor_noise(select(truth.outputs, sensor_set(3)), sensor_set(3), rng)
    filt = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, seed=1, mode="exact",
                           speed_tol=1e-4))
    said = [e.unresolved for e in filt.run(
        [Sample(t_s=k / FS_HZ, values=Y[k], speed_mps=float(v[k])) for k in range(n)],
        output_every=100)]
    assert said[:6] == [("csy_ns_per_m", "csay_ns_per_m")] * 6 and said[6:] == [()] * 6
    assert len(filt._bounds) == 2
