"""Exact discretisation of a linear model: the one Van Loan reference (scipy expm).

For ``x' = A x + w`` with ``w`` continuous white noise of intensity ``W`` (n, n) on the
state, over a sample period ``T``::

    Phi = expm(A T),       Qd = int_0^T expm(A s) W expm(A s)' ds

Both come from one matrix exponential of the Van Loan (1978) block
``[[-A, W], [0, A']] T``: its lower-right block is ``Phi'`` and ``Phi`` times its
upper-right block is ``Qd``. A deterministic input ``u`` held constant over the period
(``x' = A x + G u``) enters through ``Gamma = int_0^T expm(A s) ds G``, the upper-right
block of ``expm([[A, G], [0, 0]] T)`` (:func:`zero_order_hold`).

Valid for short periods only: the block holds ``expm(-A T)``, which for the stiff
vehicle model grows so fast that ``Qd`` loses digits as T grows (measured, relative to
doubling from 1 ms: filter coordinates over the prior box 1e-9 at 4 ms and no digit
left at 8 ms; the identification's 15-state model at nominal 3e-12 at 8 ms, 4e-3 at
16 ms). Longer periods are reached by exact doubling from one short period,
``Qd(2T) = Qd(T) + Phi(T) Qd(T) Phi(T)'``, ``Phi(2T) = Phi(T)^2``.

These are the reference: the vehicle model (:func:`gateway.model.vehicle.discretize`)
and the filter coordinates (:meth:`gateway.model.coordinates.FilterCoords.discrete`)
call them. The offline identification keeps its own Pade 13 exponential
(``gateway.identify.linalg.expm``, equal to scipy's to 1e-13): its optimisers' answers
move with the last bits of the misfit, which has shallow neighbouring minima on the
jointed-track case (measured: with scipy's expm, dual annealing ends 5.9 % off on one
parameter at a J 1e-4 below the truth's, against 3.3 % before), and the documented
results in docs/identification.md were measured with that copy. Until the
identification tests judge against what the data determines (the ML sigma), not a
fixed 5 %, it stays bit-for-bit. The particle filter's
batched kernel (:mod:`gateway.estimator.batch_expm`, many parameter vectors at once
by Taylor series and doubling) computes the same pair and is checked against
:func:`van_loan` by ``tests/test_discretisation.py``.

Threads: ``scipy.linalg.expm`` calls LAPACK, and OpenBLAS may start a thread per core for
it; on a shared 2-core machine that turned a 40 us call into milliseconds. An inner loop
that calls these thousands of times limits BLAS to one thread around the loop
(``gateway.identify.linalg.one_blas_thread``); the result does not depend on it.
Shapes as stated per function; SI units; no I/O.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from gateway.errors import ModelError


def _expm(M: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(M)):
        raise ModelError("expected a finite matrix for the exponential, got inf/nan entries")
    return scipy.linalg.expm(M)


def van_loan(A: np.ndarray, W: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``(Phi, Qd)`` for ``x' = A x + w``, ``w`` white of intensity ``W``; (n, n) each.

    ``A`` (n, n) [1/s]; ``W`` (n, n) symmetric PSD [state^2/s]; ``dt_s`` > 0 the period.
    Raises ModelError for inf/nan entries. ``Qd`` is returned exactly symmetric; ``Phi``
    is a transposed view of the block exponential (``np.ascontiguousarray`` it where a
    kernel needs C order).
    """
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = W
    M[n:, n:] = A.T
    F = _expm(M * dt_s)
    phi = F[n:, n:].T
    qd = phi @ F[:n, n:]
    return phi, 0.5 * (qd + qd.T)


def zero_order_hold(A: np.ndarray, G: np.ndarray, dt_s: float) -> tuple[np.ndarray,
                                                                        np.ndarray]:
    """Exact ``(Phi (n, n), Gamma (n, m))`` for ``x' = A x + G u``, ``u`` held over ``dt_s``.

    Raises ModelError for inf/nan entries."""
    n, m = G.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A
    aug[:n, n:] = G
    E = _expm(aug * dt_s)
    return E[:n, :n], E[:n, n:]
