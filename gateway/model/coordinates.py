"""The estimator's 16-state filter coordinates: relative lateral positions, balanced.

The 17-state model (gateway.model.vehicle) has the rigid lateral translation
``e_t`` (y_w1 = y_w2 = y_b = y_bd = y_sr = 1, all else 0) in the kernel of A (for every
theta and v) and of H, and the noise does not drive it (G feeds only delta1, delta2).
Writing the positions relative to the body, ``z_r = Pm x`` with
``z_r[j] = x[keep[j]] - x[y_bd] e_t[keep[j]]``, gives a closed 16-state model
``A_r = Pm A Tm`` (``Tm`` re-inserts y_bd = 0) whose outputs, and therefore whose
Kalman likelihood, equal those of the 17-state model exactly (proved numerically by
``tests/test_kalman.py`` against a 17-state reference filter). The absolute translation
is an unobservable random walk that the 17-state filter would carry with ever-growing
variance; it is simply not needed.

The 16 states are then scaled by a fixed diagonal ``D`` of powers of two
(``scipy.linalg.matrix_balance`` of A_r at the nominal theta, 42.5 m/s): filter state
``z = D^-1 z_r``. Powers of two make the scaling exact in floating point. It cuts
``||A T||_1`` from about 170 to about 3 at 1 ms, which makes the batched matrix
exponential cheap and accurate, and conditions the covariances.

Shapes: terms ``(4, 16, 16)`` in the basis ``(1, 1/Csy, Csay, lambda)``; ``H (ny, 16)``;
covariances ``(16, 16)``. No I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from gateway.model.discretisation import van_loan
from gateway.model.vehicle import (
    IDX,
    NX,
    THETA_NOMINAL,
    VehicleParams,
    a_matrix_terms,
    input_matrix,
    output_matrix,
    sensor_set,
    theta_basis,
    track_intensity,
)

NZ = NX - 1
"""Number of filter states."""
REF_STATE = IDX["y_bd"]
KEEP: tuple[int, ...] = tuple(i for i in range(NX) if i != REF_STATE)
TRANSLATION = np.zeros(NX)
TRANSLATION[[IDX["y_w1"], IDX["y_w2"], IDX["y_b"], IDX["y_bd"], IDX["y_sr"]]] = 1.0

BALANCE_SPEED_MPS = 42.5
"""Speed at which the fixed balancing scale D is computed."""


def _reduction() -> tuple[np.ndarray, np.ndarray]:
    """(Pm (16, 17), Tm (17, 16)) with Pm Tm = I, Pm e_t = 0, x = Tm Pm x + x[y_bd] e_t."""
    Pm = np.zeros((NZ, NX))
    Tm = np.zeros((NX, NZ))
    for j, i in enumerate(KEEP):
        Pm[j, i] = 1.0
        Pm[j, REF_STATE] -= TRANSLATION[i]
        Tm[i, j] = 1.0
    return Pm, Tm


PM, TM = _reduction()


def _balance(params: VehicleParams) -> np.ndarray:
    terms = a_matrix_terms(params, BALANCE_SPEED_MPS)
    A = np.tensordot(theta_basis(THETA_NOMINAL.as_array()), terms, axes=1)
    _, (scale, _) = scipy.linalg.matrix_balance(PM @ A @ TM, permute=False, separate=True)
    return np.asarray(scale, dtype=float)


@dataclass(frozen=True)
class FilterCoords:
    """The filter coordinate system for one set of vehicle parameters.

    ``scale`` (16,) is D; ``to_filter`` (16, 17) maps a physical state to z;
    ``to_physical`` (17, 16) maps z back (positions relative to the body, y_bd = 0).
    """

    params: VehicleParams
    scale: np.ndarray
    to_filter: np.ndarray
    to_physical: np.ndarray

    @classmethod
    def build(cls, params: VehicleParams | None = None) -> FilterCoords:
        p = params or VehicleParams()
        d = _balance(p)
        return cls(params=p, scale=d, to_filter=PM / d[:, None], to_physical=TM * d[None, :])

    def terms(self, v_mps: float) -> np.ndarray:
        """Balanced reduced A-terms at speed v, shape (4, 16, 16), 1/s."""
        t = a_matrix_terms(self.params, v_mps)
        return np.einsum("ij,tjk,kl->til", self.to_filter, t, self.to_physical)

    def system(self, theta: np.ndarray, v_mps: float) -> np.ndarray:
        """A in filter coordinates for one theta (3,), shape (16, 16)."""
        return np.tensordot(theta_basis(np.asarray(theta, dtype=float)), self.terms(v_mps), 1)

    def noise_input(self) -> np.ndarray:
        """The noise input matrix in filter coordinates, ``D^-1 Pm G``, (16, 2)."""
        return self.to_filter @ input_matrix()

    def noise_unit(self) -> np.ndarray:
        """Continuous noise intensity matrix ``D^-1 Pm G G' Pm' D^-1`` for Q = 1, (16, 16)."""
        g = self.noise_input()
        return g @ g.T

    def output(self, sensors: tuple[str, ...] | int, v_mps: float) -> np.ndarray:
        """H in filter coordinates, (ny, 16). H depends on v but not on theta."""
        t0 = a_matrix_terms(self.params, v_mps)[0]
        return output_matrix(t0, sensor_set(sensors) if isinstance(sensors, int) else sensors) \
            @ self.to_physical

    def discrete(self, theta: np.ndarray, v_mps: float, q: float,
                 dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference (Phi, Qd) for one theta (:func:`gateway.model.discretisation.van_loan`);
        (16, 16) each."""
        return van_loan(self.system(theta, v_mps), q * self.noise_unit(), dt_s)

    def initial_covariance(self, v_mps: float, ar_paper: float, dt_s: float,
                           doublings: int = 13, theta: np.ndarray | None = None) -> np.ndarray:
        """Covariance ``dt_s * 2**doublings`` s after a start from rest, (16, 16).

        At ``theta`` (default nominal). This is how the simulator starts its runs (a
        burn-in from rest); 2**13 ms = 8.2 s. Reference for the batched computation.
        """
        q = track_intensity(ar_paper, v_mps)
        th = THETA_NOMINAL.as_array() if theta is None else np.asarray(theta, dtype=float)
        phi, qd = self.discrete(th, v_mps, q, dt_s)
        for _ in range(doublings):
            qd = qd + phi @ qd @ phi.T
            qd = 0.5 * (qd + qd.T)
            phi = phi @ phi
        return qd

    def sparsity(self) -> np.ndarray:
        """Boolean (16, 16): entries of A that can be non-zero for some theta, v."""
        nz = np.zeros((NZ, NZ), dtype=bool)
        for v in (10.0, BALANCE_SPEED_MPS, 90.0):
            nz |= np.any(self.terms(v) != 0.0, axis=0)
        return nz
