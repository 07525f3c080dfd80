"""Small dense linear algebra for the inner loops: one BLAS thread, expm, the filter DARE.

Why: on this (shared, 2-core) machine ``scipy.linalg.expm`` and ``scipy.linalg.solve``
of a 30 x 30 matrix took 2-20 ms, not 40 us, because each LAPACK call woke an
OpenBLAS thread per core. :func:`one_blas_thread` (threadpoolctl) removes that cause
for the length of a fit. The identification keeps its own Pade 13 :func:`expm` (why:
:mod:`gateway.model.discretisation`, the one place that says so); it is checked against
scipy's in ``tests/test_identify_linalg.py``. The DARE
solver uses only ``@`` and ``numpy.linalg.solve``; it is checked against scipy in
``tests/test_identify_linalg.py``.
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from gateway.errors import ModelError

_PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
           1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
           33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0)
_THETA13 = 5.371920351148152


def expm(M: np.ndarray) -> np.ndarray:
    """e^M for a square matrix (n, n): Pade 13 with scaling and squaring (Higham 2005)."""
    A = np.asarray(M, dtype=float)
    norm = float(np.max(np.sum(np.abs(A), axis=0)))
    if not np.isfinite(norm):
        raise ModelError("expected a finite matrix for the exponential, got inf/nan entries")
    s = max(0, int(np.ceil(np.log2(norm / _THETA13)))) if norm > _THETA13 else 0
    A = A / (2.0**s)
    b = _PADE13
    ident = np.eye(A.shape[0])
    A2 = A @ A
    A4 = A2 @ A2
    A6 = A4 @ A2
    U = A @ (A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2)
             + b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * ident)
    V = (A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2)
         + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * ident)
    R = np.linalg.solve(V - U, V + U)
    for _ in range(s):
        R = R @ R
    return R


def one_blas_thread() -> threadpool_limits:
    """BLAS and LAPACK (numpy's and scipy's OpenBLAS) on one thread: a context manager.

    Entering costs about 2 ms, so enter it once around a fit, not per evaluation. The
    identification's worker processes call it once at start (each is one core already).
    Results do not depend on it; only the time per small matrix call does.
    """
    return threadpool_limits(limits=1, user_api="blas")


def dare_filter(phi: np.ndarray, H: np.ndarray, qd: np.ndarray, R: np.ndarray,
                max_iter: int = 60, rtol: float = 1e-12) -> np.ndarray:
    """Stabilising solution P (n, n) of the filter Riccati equation.

    ``P = phi P phi' - phi P H' (H P H' + R)^-1 H P phi' + qd``: P is the stationary
    one-step *prediction* covariance. Structure-preserving doubling algorithm
    (Chu, Fan and Lin 2005) on the dual control DARE with A = phi', B = H'.
    ``phi`` (n, n), ``H`` (ny, n), ``qd`` (n, n) PSD, ``R`` (ny, ny) positive definite.
    Raises ModelError if it does not converge (e.g. an undetectable unstable mode).
    """
    n = phi.shape[0]
    A = phi.T.copy()
    G = H.T @ np.linalg.solve(R, H)
    X = qd.copy()
    ident = np.eye(n)
    for _ in range(max_iter):
        W = ident + G @ X
        WA = np.linalg.solve(W, A)          # (I + G X)^-1 A
        WG = np.linalg.solve(W, G)          # (I + G X)^-1 G
        X_new = X + A.T @ X @ WA
        G = G + A @ WG @ A.T
        A = A @ WA
        X_new = 0.5 * (X_new + X_new.T)
        if not np.all(np.isfinite(X_new)):
            break
        delta = float(np.max(np.abs(X_new - X)))
        X = X_new
        if delta <= rtol * max(1e-300, float(np.max(np.abs(X)))):
            return X
    raise ModelError("expected the filter Riccati equation to converge, got no convergence "
                     "(unstable or undetectable model)")
