"""The vehicle model: Table 1, exact discretisation, structure, stability, vibration level."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from firmware_sim.truth import simulate
from gateway.errors import ModelError
from gateway.model.vehicle import (
    NX,
    SENSORS_3,
    SENSORS_5,
    THETA_NOMINAL,
    THETA_SEC42,
    Theta,
    VehicleParams,
    a_matrix_terms,
    discretize,
    eigenvalues,
    input_matrix,
    output_matrix,
    stability,
    system_matrix,
    theta_basis,
    track_intensity,
)

# Li et al. 2007, Table 1 (v = 42.5 m/s): frequency [Hz], damping ratio.
TABLE_1 = [(437.40, 1.0000), (37.25, 0.5677), (35.99, 0.5452), (23.75, 0.2595),
           (36.28, 0.9990), (26.76, 1.0000), (18.12, 1.0000), (1.23, 0.3157), (0.80, 0.1725)]
P = VehicleParams()


def test_table1_reproduced_by_the_command_line(cli):
    proc = cli("gateway", "model", "modes", "--speed", "42.5", "--json")
    assert proc.returncode == 0, proc.stderr
    found = json.loads(proc.stdout)
    assert len(found) == len(TABLE_1)
    unmatched = list(found)
    for f_paper, z_paper in TABLE_1:
        best = min(unmatched, key=lambda m: abs(m["frequency_hz"] - f_paper))
        unmatched.remove(best)
        assert abs(best["frequency_hz"] / f_paper - 1) < 0.005, (f_paper, best)
        assert abs(best["damping_ratio"] - z_paper) < 0.005, (f_paper, best)


def test_two_structural_zero_eigenvalues_unseen_by_every_sensor():
    A = system_matrix(P, THETA_NOMINAL, 42.5)
    zeros, rest = eigenvalues(A)
    assert len(zeros) == 2 and len(rest) == NX - 2
    _, s, vt = np.linalg.svd(A)
    null = vt[-2:].T
    assert np.abs(output_matrix(A, SENSORS_5) @ null).max() < 1e-9


def test_affine_decomposition_is_exact():
    terms = a_matrix_terms(P, 30.0)
    for th in (THETA_NOMINAL.as_array(), np.array([7e3, 1.1e6, 0.4])):
        direct = system_matrix(P, th, 30.0)
        assert np.array_equal(np.tensordot(theta_basis(th), terms, axes=1), direct)
    # Csay only enters the bogie-yaw damping, lambda only the wheelset yaw rows
    assert np.count_nonzero(terms[2]) == 1 and np.count_nonzero(terms[3]) == 2


def test_h_rows_are_accelerations_and_gyro():
    A = system_matrix(P, THETA_SEC42, 42.5)
    H5, H3 = output_matrix(A, 5), output_matrix(A, 3)
    assert H5.shape == (5, NX) and H3.shape == (3, NX)
    np.testing.assert_array_equal(H5[2:], H3)
    np.testing.assert_array_equal(H5[0], A[7])
    assert H5[3, 12] == 1.0 and np.count_nonzero(H5[3]) == 1
    assert SENSORS_5[2:] == SENSORS_3


def test_discretisation_matches_expm_and_a_van_loan_quadrature():
    dt = 1e-3
    A = system_matrix(P, THETA_SEC42, 42.5)
    G = input_matrix()
    q = track_intensity(2 * 0.33e-3, 42.5)
    d = discretize(A, G, q, dt)
    phi_ref = scipy.linalg.expm(A * dt)
    assert np.abs(d.phi - phi_ref).max() <= 1e-9 * np.abs(phi_ref).max()
    GQG = G @ G.T * q

    def integrand(s: float) -> np.ndarray:
        E = scipy.linalg.expm(A * s)
        return E @ GQG @ E.T

    qd_ref, _ = scipy.integrate.quad_vec(integrand, 0.0, dt, epsabs=0, epsrel=1e-12)
    assert np.abs(d.qd - qd_ref).max() <= 1e-9 * np.abs(qd_ref).max()
    gamma_ref, _ = scipy.integrate.quad_vec(lambda s: scipy.linalg.expm(A * s) @ G, 0.0, dt,
                                            epsabs=0, epsrel=1e-12)
    assert np.abs(d.gamma - gamma_ref).max() <= 1e-9 * np.abs(gamma_ref).max()


def test_unstable_parameters_are_reported_not_raised():
    # inside the RBPF prior box: low Csy and low conicity make the body mode grow
    s = stability(P, Theta(6e3, 3000e3, 0.045), 42.5)
    assert not s.stable and 0.1 < s.max_growth_rate_per_s < 0.3
    assert stability(P, THETA_NOMINAL, 42.5).stable
    d = discretize(system_matrix(P, Theta(6e3, 3000e3, 0.045), 42.5), input_matrix(), 1e-6, 1e-3)
    assert np.all(np.isfinite(d.phi)) and np.all(np.isfinite(d.qd))


@pytest.mark.parametrize("bad", [dict(v=0.0), dict(v=float("nan")), dict(theta=(-1.0, 3e6, 0.15))])
def test_bad_model_inputs_raise_model_error(bad):
    theta = np.array(bad.get("theta", THETA_NOMINAL.as_array()))
    with pytest.raises(ModelError, match="expected"):
        system_matrix(P, theta, bad.get("v", 42.5))


def test_simulated_vibration_is_physical():
    rng = np.random.default_rng(0)
    n = 20_000
    run = simulate(np.tile(THETA_SEC42.as_array(), (n, 1)), np.full(n, 42.5), 1000.0, rng)
    rms = run.outputs.std(axis=0)
    acc_b = rms[SENSORS_5.index("acc_b")]
    assert 0.1 < acc_b < 1.0
    # the model notes' stationary stds: 0.390, 0.244, 0.444, 0.0033, 0.144; over 20 s the
    # lightly damped 0.8 Hz body mode gives the body sensor the widest sampling spread
    np.testing.assert_allclose(rms[:4], [0.390, 0.244, 0.444, 0.0033], rtol=0.15)
    np.testing.assert_allclose(rms[4], 0.144, rtol=0.35)
