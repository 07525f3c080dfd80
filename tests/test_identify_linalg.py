"""The small linear-algebra kernels against scipy (known answers)."""

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_info

from gateway.identify.linalg import dare_filter, expm, one_blas_thread
from gateway.identify.params import ParamPoint
from gateway.identify.prediction_error import reduced_model
from gateway.model.discretisation import van_loan
from gateway.model.vehicle import SENSORS_5, discretize, measurement_noise, track_intensity


def test_expm_matches_scipy_on_the_stiff_vehicle_matrix():
    A, G, _ = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    for dt in (1e-3, 5e-3, 2e-2):
        ours, ref = expm(A * dt), scipy.linalg.expm(A * dt)
        assert np.max(np.abs(ours - ref)) <= 1e-11 * np.max(np.abs(ref))


def test_one_blas_thread_limits_openblas_and_gives_the_same_discretisation():
    A, G, _ = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    W = track_intensity(6.6e-4, 42.5) * (G @ G.T)
    free = van_loan(A, W, 5e-3)
    with one_blas_thread():
        assert {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"} == {1}
        one = van_loan(A, W, 5e-3)
    assert np.allclose(one[0], free[0], rtol=0, atol=1e-13)
    assert np.allclose(one[1], free[1], rtol=1e-10, atol=0)


def test_van_loan_matches_model_discretize():
    A, G, _ = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    q = track_intensity(6.6e-4, 42.5)
    phi, qd = van_loan(A, q * (G @ G.T), 5e-3)
    ref = discretize(A, G, q, 5e-3)
    assert np.allclose(phi, ref.phi, rtol=0, atol=1e-10)
    assert np.allclose(qd, ref.qd, rtol=1e-8, atol=1e-16)


def test_dare_matches_scipy_and_is_a_fixed_point():
    A, G, H = reduced_model(ParamPoint.nominal(), SENSORS_5, 42.5)
    phi, qd = van_loan(A, track_intensity(6.6e-4, 42.5) * (G @ G.T), 5e-3)
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
