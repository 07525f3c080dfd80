"""Small dense linear algebra for the inner loops: one BLAS thread, and the filter DARE.

Why: on this (shared, 2-core) machine ``scipy.linalg.expm`` and ``scipy.linalg.solve``
of a 30 x 30 matrix took 2-20 ms, not 40 us, because each LAPACK call woke an
OpenBLAS thread per core. :func:`one_blas_thread` (threadpoolctl) removes that cause
for the length of a fit, so the inner loops call the one exact discretisation
(:mod:`gateway.model.discretisation`, scipy) instead of a copy of Pade 13. The DARE
solver uses only ``@`` and ``numpy.linalg.solve``; it is checked against scipy in
``tests/test_identify_linalg.py``.
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from gateway.errors import ModelError


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
