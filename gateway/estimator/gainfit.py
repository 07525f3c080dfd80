"""Fast mode's steady gains at a resample-move, fitted over the cloud from a few solved particles.

A move jitters every particle's theta, so each needs its steady filter again (a DARE
solve from its ancestor's, :func:`gateway.estimator.steady.steady_gains`: about 22 ms
for 1000 particles, a quarter of fast mode's time over a 5 s run, docs/estimator.md
"The nineteenth session"). The steady filter is a smooth function of theta, and after
the first second the cloud spans a few per cent of it. So :func:`fitted_gains` solves
only ``ANCHORS`` particles (each parameter's two extremes and particles evenly spaced in
the resampled order) and fits every quantity the steady step and its hand-overs use
(``P-``, the sequential gains ``g``, the innovation variances ``S``) by least squares
on a quadratic in log theta, scaled by the cloud's spread; every other particle takes
the fit. ``CHECKS`` more particles, the farthest from the cloud's centre that are not
anchors, are solved too and compared with the fit: if any gain is off by more than
``FIT_TOL`` of its particle's largest, or any ``S`` by more than ``FIT_TOL`` relative
(or a solved particle is dead), nothing is written and the caller solves every
particle as before. Solved particles keep their own solution; a fitted one is marked
``iters`` = :data:`FITTED`.

Why ``FIT_TOL`` = 1e-3, the rejoin test's tolerance on the same quantities
(:data:`gateway.estimator.rejoin.REJOIN_TOL`): measured on the bench's record (docs/
estimator.md "The nineteenth session"), a fit with gains off by at most 1.8e-3 moved no
particle's log-likelihood over the next 0.5 s by more than 0.13 nats against the solved
gains (weighted rms 0.008 nats), where the particles' own log-likelihoods spread by 2.1
nats; at 4e-4 by at most 0.005 nats. A gain off by a small amount changes the state's
error only to second order (the steady gain is optimal), and an innovation variance off
by a relative ``e`` changes a sample's log-likelihood by ``e (1 - NIS) / 2``, zero on
average for the particle the data fit.

No I/O. Arrays in the lane layout of :mod:`gateway.estimator.steady`.
"""

from __future__ import annotations

import numpy as np

from gateway.estimator.kalman import _LOG_2PI, from_lanes, n_chunks, to_lanes
from gateway.estimator.steady import SteadyGains, steady_gains, take_lanes
from gateway.model.coordinates import NZ

__all__ = ["ANCHORS", "CHECKS", "FITTED", "FIT_TOL", "MIN_PARTICLES", "fitted_gains"]

ANCHORS = 24
"""Particles solved and fitted at a move (a quadratic in 3 parameters has 10 terms, in 4
has 15; at least twice the terms are solved)."""
CHECKS = 4
"""Particles solved to check the fit: the farthest from the cloud's centre that are not
anchors."""
FIT_TOL = 1e-3
"""Largest error of a fitted gain (relative to the particle's largest gain element) or
innovation variance (relative) on the check particles for the fit to be used."""
MIN_PARTICLES = 128
"""Below this many particles every particle is solved (the fit saves little)."""
FITTED = -1000
"""``SteadyGains.iters`` of a particle whose gains were fitted, not solved."""


def _terms(theta: np.ndarray) -> np.ndarray:
    """The fit's regressors (N, terms): 1, z_i, z_i z_j (i <= j) with ``z`` the log theta
    (N, d) centred and scaled by the cloud's spread."""
    z = np.log(theta)
    z = (z - z.mean(axis=0)) / np.maximum(z.std(axis=0), 1e-12)
    d = z.shape[1]
    cols = [np.ones(len(z))] + [z[:, i] for i in range(d)]
    cols += [z[:, i] * z[:, j] for i in range(d) for j in range(i, d)]
    return np.stack(cols, axis=1)


def _choose(X: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Anchor and check particle indices (ascending), deterministic: no random draw."""
    m = len(theta)
    n_anchor = max(ANCHORS, 2 * X.shape[1])
    chosen = {int(i) for c in range(theta.shape[1])
              for i in (np.argmin(theta[:, c]), np.argmax(theta[:, c]))}
    for i in np.linspace(0, m - 1, 4 * n_anchor).astype(int):
        if len(chosen) >= n_anchor:
            break
        chosen.add(int(i))
    anchors = np.array(sorted(chosen), dtype=np.int64)
    far = np.argsort(-np.einsum("mi,mi->m", X[:, 1:1 + theta.shape[1]],
                                X[:, 1:1 + theta.shape[1]]), kind="stable")
    checks = np.array(sorted(int(i) for i in far[~np.isin(far, anchors)][:CHECKS]),
                      dtype=np.int64)
    return anchors, checks


def fitted_gains(theta: np.ndarray, phi: np.ndarray, qd: np.ndarray, v0: np.ndarray,
                 H: np.ndarray, r: np.ndarray, out: SteadyGains, start: np.ndarray) -> bool:
    """Fill ``out`` (every particle's steady filter, lane layout) from a fit over the
    cloud ``theta`` (m, d), solving anchors and checks warm from ``start`` (their
    ancestors' P-, lane layout); False, with ``out`` untouched, where the fit does not
    hold (module docstring). ``phi``, ``qd``, ``v0`` lane layout as for
    :func:`gateway.estimator.steady.steady_gains`."""
    m = len(theta)
    if m < MIN_PARTICLES:
        return False
    X = _terms(np.asarray(theta, dtype=float))
    anchors, checks = _choose(X, theta)
    solved = np.concatenate([anchors, checks])
    ny = len(r)
    sub = SteadyGains.empty(n_chunks(len(solved)), ny)
    steady_gains(take_lanes(phi, solved), take_lanes(qd, solved), take_lanes(v0, solved),
                 H, r, sub, start=take_lanes(start, solved))
    k = len(solved)
    if not np.isfinite(sub.c0[:k]).all():
        return False
    p = from_lanes(sub.p_pred, k, (NZ * NZ,))
    g = from_lanes(sub.g, k, (ny * NZ,))
    s = from_lanes(sub.s, k, (ny,))
    Y = np.concatenate([p, g, s], axis=1)
    na = len(anchors)
    coef = np.linalg.lstsq(X[anchors], Y[:na], rcond=None)[0]
    guess = np.einsum("kt,tc->kc", X[checks], coef)
    g_err = (np.abs(guess[:, NZ * NZ:-ny] - g[na:]).max(axis=1)
             / np.abs(g[na:]).max(axis=1))
    s_err = np.abs(guess[:, -ny:] / s[na:] - 1.0).max(axis=1)
    if not (g_err.max() <= FIT_TOL and s_err.max() <= FIT_TOL):
        return False
    fit = np.einsum("mt,tc->mc", X, coef)     # not BLAS: its threads would then spin
    fit[solved] = Y
    if not (fit[:, -ny:] > 0).all():
        return False
    for name, cols in (("p_pred", fit[:, :NZ * NZ]), ("g", fit[:, NZ * NZ:-ny]),
                       ("s", fit[:, -ny:])):
        getattr(out, name)[...] = to_lanes(cols)
    out.c0[:m] = np.log(fit[:, -ny:]).sum(axis=1) + ny * _LOG_2PI
    out.c0[solved] = sub.c0[:k]
    out.c0[m:] = out.c0[m - 1]
    out.iters[:] = FITTED
    out.iters[solved] = sub.iters[:k]
    return True
