"""Deterministic forced response of the vehicle model to a known track alignment.

The model input is the pair of track lateral velocities ``b = [y_t1', y_t2']``. With a
known track they are deterministic, not white noise. Over each sample interval the
input is held at its interval mean ``b[k] = (y_t[k+1] - y_t[k]) / T`` and the model is
discretised exactly for that zero-order hold (``Phi = e^{AT}``,
``Gamma = int_0^T e^{As} ds G``). The hold then moves each ``delta_i`` by exactly the
track step, so the only approximation is the shape of the track *within* an interval,
an O(T^2) error; ``docs/identification.md`` measures it against a 2 kHz simulation.
"""

from __future__ import annotations

import numba
import numpy as np

from gateway.identify.linalg import expm
from gateway.identify.params import ParamPoint
from gateway.model.vehicle import input_matrix, output_matrix, system_matrix


def discretise_forced(A: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold pair ``(Phi (17, 17), Gamma (17, 2))`` for sample period dt_s."""
    G = input_matrix()
    n, m = G.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A
    aug[:n, n:] = G
    E = expm(aug * dt_s)
    return E[:n, :n], E[:n, n:]


@numba.njit(cache=True)
def _forced(phi: np.ndarray, gamma: np.ndarray, H: np.ndarray, b: np.ndarray,
            out: np.ndarray) -> None:
    """out[k] = H x[k], x[k+1] = phi x[k] + gamma b[k], x[0] = 0; out (T, ny), b (T, 2)."""
    n = phi.shape[0]
    ny = H.shape[0]
    x = np.zeros(n)
    y = np.zeros(n)
    for k in range(b.shape[0]):
        for i in range(ny):
            s = 0.0
            for j in range(n):
                s += H[i, j] * x[j]
            out[k, i] = s
        b0 = b[k, 0]
        b1 = b[k, 1]
        for i in range(n):
            s = gamma[i, 0] * b0 + gamma[i, 1] * b1
            for j in range(n):
                s += phi[i, j] * x[j]
            y[i] = s
        for i in range(n):
            x[i] = y[i]


def forced_response(point: ParamPoint, sensors: tuple[str, ...], speed_mps: float,
                    dt_s: float, wheel_alignment_m: np.ndarray) -> np.ndarray:
    """Sensor outputs (T, ny), SI units, for the track under the wheelsets (T+1, 2) in m.

    Starts from rest (x = 0) at the first sample; give a pre-roll long enough for the
    start transient to decay (the slowest mode, 0.8 Hz at zeta 0.17, decays as
    exp(-0.87 t)). The outputs do not depend on constant alignment offsets (those
    lie in the model's null space).
    """
    A = system_matrix(point.vehicle(), point.theta(), speed_mps)
    phi, gamma = discretise_forced(A, dt_s)
    H = output_matrix(A, sensors)
    b = np.ascontiguousarray(np.diff(wheel_alignment_m, axis=0) / dt_s)
    out = np.empty((b.shape[0], H.shape[0]))
    if not np.all(np.isfinite(phi)):
        out.fill(np.inf)
        return out
    _forced(np.ascontiguousarray(phi), np.ascontiguousarray(gamma), np.ascontiguousarray(H),
            b, out)
    return out


