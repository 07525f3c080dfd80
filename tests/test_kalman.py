"""Known answers for the batched kernels: a plain 17-state numpy KF, scipy expm + Van Loan."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.estimator.batch_expm import DiscreteBatch
from gateway.estimator.kalman import from_lanes, n_chunks, to_lanes
from gateway.estimator.lanecode import LANES
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.coordinates import NZ, TRANSLATION, FilterCoords
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    THETA_NOMINAL,
    THETA_SEC42,
    VehicleParams,
    discretize,
    input_matrix,
    measurement_noise,
    output_matrix,
    sensor_set,
    system_matrix,
    track_intensity,
)
from gateway.records import Sample

V = 42.5
FS = 1000.0


@pytest.fixture(scope="module")
def coords() -> FilterCoords:
    return FilterCoords.build()


def reference_kf(theta: np.ndarray, Y: np.ndarray, sensors: tuple[str, ...], P0: np.ndarray,
                 ) -> tuple[np.ndarray, float]:
    """Textbook 17-state KF in physical coordinates (model.discretize); (x_T, loglik)."""
    p = VehicleParams()
    A = system_matrix(p, theta, V)
    d = discretize(A, input_matrix(), track_intensity(AR_PAPER_DEFAULT, V), 1 / FS)
    H = output_matrix(A, sensors)
    R = measurement_noise(sensors)
    x, P, ll = np.zeros(17), P0.copy(), 0.0
    for y in Y:
        x = d.phi @ x
        P = d.phi @ P @ d.phi.T + d.qd
        use = np.isfinite(y)
        if use.any():
            Hu, Ru = H[use], R[np.ix_(use, use)]
            S = Hu @ P @ Hu.T + Ru
            e = y[use] - Hu @ x
            K = np.linalg.solve(S, Hu @ P).T
            x = x + K @ e
            P = P - K @ S @ K.T
            P = 0.5 * (P + P.T)
            ll += -0.5 * (np.linalg.slogdet(2 * np.pi * S)[1] + e @ np.linalg.solve(S, e))
    return x, ll


@pytest.mark.parametrize("sensors", [3, 5])
def test_particles_at_true_theta_equal_reference_kf(coords: FilterCoords, sensors: int) -> None:
    """All particles at the true theta, no moves: each equals the 17-state reference KF."""
    n_steps = 400
    rng = np.random.default_rng(7)
    theta = THETA_SEC42.as_array()
    run = simulate(np.repeat(theta[None], n_steps, 0), np.full(n_steps, V), FS, rng)
    names = sensor_set(sensors)
    Y = add_sensor_noise(select(run.outputs, names), names, rng)
    Y[50:60, 0] = np.nan                      # a dropout of one sensor
    Y[100:103] = np.nan                       # a gap: predict only
    cfg = RBPFConfig(fs_hz=FS, n_particles=LANES + 3, sensors=sensors, resample=False,
                     monitor=None)
    filt = RBPF(cfg)
    filt.set_particles(np.repeat(theta[None], cfg.n_particles, 0))
    for k in range(n_steps):
        filt.step(Sample(t_s=k / FS, values=Y[k], speed_mps=V))
    # The 17-state prior equivalent to the 16-state one, plus some variance on the
    # unobservable translation (the exact likelihood does not depend on it; a large value
    # only costs the 17-state reference its own precision, since H e_t = 0 up to rounding).
    P0 = coords.initial_covariance(V, AR_PAPER_DEFAULT, 1 / FS, theta=theta)
    P0_17 = coords.to_physical @ P0 @ coords.to_physical.T + 1e-6 * np.outer(
        TRANSLATION, TRANSLATION)
    x_ref, ll_ref = reference_kf(theta, Y, names, P0_17)
    z_ref = coords.to_filter @ x_ref
    z = from_lanes(filt._X, cfg.n_particles, (NZ,))
    for i in range(cfg.n_particles):
        assert np.max(np.abs(z[i] - z_ref)) <= 1e-9 * np.max(np.abs(z_ref))
        assert abs(filt.logw[i] - ll_ref) <= 1e-6
    assert filt.n_resamples == 0


def test_batched_discretisation_matches_scipy(coords: FilterCoords) -> None:
    """Phi and Qd within 1e-9 of expm/Van Loan over and beyond the prior box."""
    rng = np.random.default_rng(3)
    nom = THETA_NOMINAL.as_array()
    n = 5 * LANES
    factors = np.exp(rng.uniform(np.log(0.05), np.log(10.0), (n, 3)))
    factors[0] = 1.0
    factors[1] = [6e3 / 40e3, 3e6 / 4.114e6, 0.3]          # unstable corner (+0.2 1/s)
    factors[2] = [0.3, 0.3, 0.3]
    factors[3] = [2.5, 2.5, 3.5]
    factors[4] = [0.05, 10.0, 0.05]
    factors[5] = [10.0, 10.0, 10.0]
    theta = nom * factors
    q = track_intensity(AR_PAPER_DEFAULT, V) * rng.uniform(0.25, 4.0, n)
    disc = DiscreteBatch(coords, V, 1 / FS)
    phi = np.empty((n_chunks(n), NZ * NZ * LANES))
    qd = np.empty_like(phi)
    disc.compute(theta, q, phi, qd)
    phis, qds = from_lanes(phi, n, (NZ, NZ)), from_lanes(qd, n, (NZ, NZ))
    for i in range(n):
        phi_ref, qd_ref = coords.discrete(theta[i], V, q[i], 1 / FS)
        assert np.max(np.abs(phis[i] - phi_ref)) <= 1e-9 * np.max(np.abs(phi_ref))
        assert np.max(np.abs(qds[i] - qd_ref)) <= 1e-9 * np.max(np.abs(qd_ref))


def test_reduced_model_has_the_same_outputs(coords: FilterCoords) -> None:
    """The translation is in ker A and ker H; H in filter coordinates reproduces H x."""
    p = VehicleParams()
    A = system_matrix(p, THETA_NOMINAL, V)
    assert np.max(np.abs(A @ TRANSLATION)) == 0.0
    assert np.max(np.abs(output_matrix(A, 5) @ TRANSLATION)) == 0.0
    x = np.random.default_rng(0).standard_normal(17)
    z = coords.to_filter @ x
    assert np.allclose(coords.output(5, V) @ z, output_matrix(A, 5) @ x, rtol=1e-12,
                       atol=1e-12)


def test_lane_layout_round_trip() -> None:
    a = np.random.default_rng(1).standard_normal((LANES * 2 + 5, 3, 4))
    lanes = to_lanes(a)
    assert lanes.shape == (3, 12 * LANES)
    assert np.array_equal(from_lanes(lanes, len(a), (3, 4)), a)


@pytest.mark.parametrize("n_sensors", [3, 5])
def test_block_kernel_is_k_single_steps(n_sensors: int) -> None:
    """kf_block over K samples (predict-only ones among them, one lane that blows up and
    is reset) gives the same bits as K calls of kf_step: states, covariances, each
    sample's log-likelihood and NIS."""
    from gateway.estimator.kalman import kf_block, kf_step

    rng = np.random.default_rng(2)
    nch, T = 8, 30
    X = rng.standard_normal((nch, NZ * LANES))
    A = rng.standard_normal((nch, NZ, NZ, LANES)) * 0.2
    P = (np.einsum("cikl,cjkl->cijl", A, A) + np.eye(NZ)[None, :, :, None]).reshape(nch, -1)
    F = rng.standard_normal((nch, NZ * NZ * LANES)) * 0.2
    F[3, 5 * LANES + 2] = 1e9                                # particle 26 diverges
    Q, H = 0.01 * P, rng.standard_normal((n_sensors, NZ))
    r = rng.random(n_sensors) + 0.1
    Y = rng.standard_normal((T, n_sensors))
    full = rng.random(T) > 0.2
    assert not full.all() and full.any()
    X1, P1 = X.copy(), P.copy()
    LL1, NIS1 = np.zeros((T, nch * LANES)), np.zeros((T, nch * LANES))
    for t in range(T):
        dead = np.zeros(nch * LANES, dtype=bool)
        kf_step(X1, P1, F, Q, H, r, Y[t], np.full(n_sensors, full[t]), np.eye(NZ), LL1[t],
                NIS1[t], dead)
    X2, P2 = X.copy(), P.copy()
    LL2, NIS2 = np.empty((T, nch * LANES)), np.empty((T, nch * LANES))
    kf_block(X2, P2, F, Q, H, r, Y, full, np.eye(NZ), LL2, NIS2)
    assert np.isinf(LL1[:, 26]).any()
    for a, b in ((X1, X2), (P1, P2), (LL1, LL2), (NIS1, NIS2)):
        assert np.array_equal(a, b)
