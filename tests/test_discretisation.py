"""The one exact discretisation: scipy Van Loan reference, batched kernel, and who calls them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.errors import ModelError
from gateway.estimator.batch_expm import DiscreteBatch
from gateway.estimator.kalman import from_lanes, n_chunks
from gateway.estimator.lanecode import LANES
from gateway.identify.simulate import discretise_forced
from gateway.model.coordinates import NZ, FilterCoords
from gateway.model.discretisation import van_loan, zero_order_hold
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    THETA_NOMINAL,
    VehicleParams,
    discretize,
    input_matrix,
    system_matrix,
    track_intensity,
)

V_MPS = 42.5
FS_HZ = 1000.0


def test_van_loan_known_answer_for_a_first_order_lag() -> None:
    """x' = -a x + w, w of intensity W: Phi = e^-aT, Qd = W (1 - e^-2aT) / 2a."""
    a, W, T = 3.0, 0.7, 0.25
    phi, qd = van_loan(np.array([[-a]]), np.array([[W]]), T)
    assert phi[0, 0] == pytest.approx(math.exp(-a * T), rel=1e-14)
    assert qd[0, 0] == pytest.approx(W * (1 - math.exp(-2 * a * T)) / (2 * a), rel=1e-13)


def test_zero_order_hold_known_answer_for_a_first_order_lag() -> None:
    """x' = -a x + g u, u held: Gamma = g (1 - e^-aT) / a."""
    a, g, T = 3.0, 2.0, 0.25
    phi, gamma = zero_order_hold(np.array([[-a]]), np.array([[g]]), T)
    assert phi[0, 0] == pytest.approx(math.exp(-a * T), rel=1e-14)
    assert gamma[0, 0] == pytest.approx(g * (1 - math.exp(-a * T)) / a, rel=1e-13)


def test_non_finite_input_is_a_model_error() -> None:
    A = np.array([[np.nan]])
    with pytest.raises(ModelError, match="expected a finite matrix"):
        van_loan(A, np.eye(1), 1e-3)
    with pytest.raises(ModelError, match="expected a finite matrix"):
        zero_order_hold(A, np.eye(1), 1e-3)


@pytest.mark.parametrize("doublings", [0, 4, 13])
def test_batched_kernel_matches_the_reference(doublings: int) -> None:
    """The particle filter's batched (Phi, Qd) over 2**doublings samples against van_loan
    over one sample and as many exact doublings (13: the 8.2 s prior horizon), over and
    beyond the prior box. Van Loan's block holds ``expm(-A T)``: for this stiff A its Qd
    loses digits from about 4 ms on (1e-9 at 4 ms, all at 8 ms), so longer periods are
    reached by doubling, as ``FilterCoords.initial_covariance`` does."""
    coords = FilterCoords.build()
    rng = np.random.default_rng(7)
    n = 2 * LANES
    theta = THETA_NOMINAL.as_array() * np.exp(rng.uniform(np.log(0.3), np.log(3.0), (n, 3)))
    q = track_intensity(AR_PAPER_DEFAULT, V_MPS) * rng.uniform(0.25, 4.0, n)
    phi = np.empty((n_chunks(n), NZ * NZ * LANES))
    qd = np.empty_like(phi)
    DiscreteBatch(coords, V_MPS, 2**doublings / FS_HZ).compute(theta, q, phi, qd)
    phis, qds = from_lanes(phi, n, (NZ, NZ)), from_lanes(qd, n, (NZ, NZ))
    for i in range(n):
        phi_ref, qd_ref = van_loan(coords.system(theta[i], V_MPS), q[i] * coords.noise_unit(),
                                   1 / FS_HZ)
        for _ in range(doublings):
            qd_ref = qd_ref + phi_ref @ qd_ref @ phi_ref.T
            phi_ref = phi_ref @ phi_ref
        assert np.max(np.abs(phis[i] - phi_ref)) <= 1e-9 * np.max(np.abs(phi_ref))
        assert np.max(np.abs(qds[i] - qd_ref)) <= 1e-9 * np.max(np.abs(qd_ref))


def test_the_model_stages_call_the_one_reference() -> None:
    """vehicle.discretize and FilterCoords.discrete give exactly the reference's numbers;
    identify's forced response agrees with it to rounding."""
    A = system_matrix(VehicleParams(), THETA_NOMINAL, V_MPS)
    G = input_matrix()
    q = track_intensity(AR_PAPER_DEFAULT, V_MPS)
    d = discretize(A, G, q, 1 / FS_HZ)
    phi, qd = van_loan(A, G @ (q * np.eye(2)) @ G.T, 1 / FS_HZ)
    assert np.array_equal(d.phi, phi) and np.array_equal(d.qd, qd)
    assert np.array_equal(d.gamma, zero_order_hold(A, G, 1 / FS_HZ)[1])

    coords = FilterCoords.build()
    th = THETA_NOMINAL.as_array()
    got = coords.discrete(th, V_MPS, q, 1 / FS_HZ)
    ref = van_loan(coords.system(th, V_MPS), q * coords.noise_unit(), 1 / FS_HZ)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])

    # identify keeps its own Pade 13 (gateway.model.discretisation says why): equal to
    # the reference to rounding, not bit for bit
    forced = discretise_forced(A, 5e-3)
    hold = zero_order_hold(A, G, 5e-3)
    for a, b in zip(forced, hold, strict=True):
        assert np.max(np.abs(a - b)) <= 1e-12 * np.max(np.abs(b))
