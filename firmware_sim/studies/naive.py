"""The naive baseline for the benchmark: a per-particle Python loop of textbook KFs.

This is the RBPF's inner loop as one would first write it with numpy: for every
particle, a 17-state Kalman filter in physical coordinates with ``@``, ``inv`` and
``det``. It is measured on a short slice of data by ``gateway bench`` to give the
speed-up of the batched exact kernels (:mod:`gateway.estimator.kalman`). Moves and Phi
recomputation are not included (that would only make the baseline slower).
"""

from __future__ import annotations

import numpy as np


def naive_steps(phi: np.ndarray, qd: np.ndarray, H: np.ndarray, R: np.ndarray,
                x: np.ndarray, P: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Run ``len(Y)`` KF steps for every particle; returns log-likelihoods (N,).

    ``phi, qd (N, 17, 17)``, ``H (ny, 17)``, ``R (ny, ny)``, ``x (N, 17)``,
    ``P (N, 17, 17)`` (updated in place), ``Y (K, ny)``.
    """
    n = phi.shape[0]
    ll = np.zeros(n)
    eye = np.eye(phi.shape[1])
    for y in Y:
        for i in range(n):
            xp = phi[i] @ x[i]
            Pp = phi[i] @ P[i] @ phi[i].T + qd[i]
            S = H @ Pp @ H.T + R
            Si = np.linalg.inv(S)
            K = Pp @ H.T @ Si
            e = y - H @ xp
            x[i] = xp + K @ e
            P[i] = (eye - K @ H) @ Pp
            ll[i] += -0.5 * (np.log(np.linalg.det(2 * np.pi * S)) + e @ Si @ e)
    return ll
