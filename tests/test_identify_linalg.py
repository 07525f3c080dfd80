"""The small linear-algebra kernels against scipy (known answers)."""

import numpy as np
import scipy.linalg

from gateway.identify.linalg import dare_filter, expm
from gateway.identify.params import ParamPoint
from gateway.identify.prediction_error import reduced_model, van_loan
from gateway.model.vehicle import SENSORS_5, discretize, measurement_noise, track_intensity


def test_expm_matches_scipy_on_the_stiff_vehicle_matrix():
    A, G, _ = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    for dt in (1e-3, 5e-3, 2e-2):
        ours, ref = expm(A * dt), scipy.linalg.expm(A * dt)
        assert np.max(np.abs(ours - ref)) <= 1e-11 * np.max(np.abs(ref))


def test_van_loan_matches_model_discretize():
    A, G, _ = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    q = track_intensity(6.6e-4, 42.5)
    phi, qd = van_loan(A, G, q, 5e-3)
    ref = discretize(A, G, q, 5e-3)
    assert np.allclose(phi, ref.phi, rtol=0, atol=1e-10)
    assert np.allclose(qd, ref.qd, rtol=1e-8, atol=1e-16)


def test_dare_matches_scipy_and_is_a_fixed_point():
    A, G, H = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    phi, qd = van_loan(A, G, track_intensity(6.6e-4, 42.5), 5e-3)
    R = measurement_noise(SENSORS_5)
    P = dare_filter(phi, H, qd, R)
    ref = scipy.linalg.solve_discrete_are(phi.T, H.T, qd, R)
    assert np.max(np.abs(P - ref)) <= 1e-9 * np.max(np.abs(ref))
    S = H @ P @ H.T + R
    rhs = phi @ P @ phi.T - phi @ P @ H.T @ np.linalg.solve(S, H @ P @ phi.T) + qd
    assert np.max(np.abs(rhs - P)) <= 1e-9 * np.max(np.abs(P))


def test_reduced_model_keeps_the_outputs():
    """Removing the two null-space states changes no transfer function."""
    A, G, H = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    assert A.shape == (15, 15) and G.shape == (15, 2) and H.shape == (5, 15)
    assert np.max(np.linalg.eigvals(A).real) < 0
