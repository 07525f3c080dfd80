"""Parameter particles: prior draws, systematic resampling and the Liu-West kernel move.

Pure functions; randomness comes from the ``numpy.random.Generator`` passed in.
Parameters are handled in log space (``z = log theta``) so they stay positive; the
columns are (Csy [N s/m], Csay [N s/m], lambda [-]) and optionally Ar (paper units).
Shapes: particles first, ``z (N, d)``, weights ``(N,)``.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.stats import qmc

from gateway.estimator.monitor import update_nb


def shrinkage(delta: float) -> float:
    """Liu-West shrinkage a = (3 delta - 1) / (2 delta)."""
    return (3.0 * delta - 1.0) / (2.0 * delta)


def jitter_var(delta: float) -> float:
    """Liu-West jitter variance factor h^2 = 1 - a^2 (a: :func:`shrinkage`)."""
    a = shrinkage(delta)
    return 1.0 - a * a


def _unit_points(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    """n scrambled Halton points in [0, 1)^d: evenly spread, random, from ``rng``.

    A 1000-point prior over a 3-D box leaves holes when drawn iid; a low-discrepancy set
    covers the box evenly, so the particle nearest to the truth is nearer on average.
    """
    return np.asarray(qmc.Halton(d, scramble=True, seed=rng).random(n))


def draw_uniform(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray,
                 n: int) -> np.ndarray:
    """Log of n points uniform in [lo, hi] (linear scale, the paper's prior); (n, d)."""
    u = _unit_points(rng, n, len(lo))
    return np.log(lo + (hi - lo) * u)


def draw_mixed(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, n: int,
               log_dims: np.ndarray) -> np.ndarray:
    """Log of n points in [lo, hi]: uniform, or log-uniform where ``log_dims`` (d,) is True."""
    u = _unit_points(rng, n, len(lo))
    lin = np.log(lo + (hi - lo) * u)
    log = np.log(lo) + (np.log(hi) - np.log(lo)) * u
    return np.where(log_dims, log, lin)


def draw_log_uniform(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray,
                     n: int) -> np.ndarray:
    """Log of n points log-uniform in [lo, hi]; (n, d)."""
    u = _unit_points(rng, n, len(lo))
    return np.log(lo) + (np.log(hi) - np.log(lo)) * u


def draw_log_cells(rng: np.random.Generator, edges_log: np.ndarray, log_mass: np.ndarray,
                   n: int) -> np.ndarray:
    """n points (n,) from the density that is constant within each cell
    ``[edges_log[j], edges_log[j + 1])`` (J + 1,) of a log scale and holds mass
    proportional to ``exp(log_mass[j])`` (J,) there, evenly spread (inverse CDF of
    scrambled Halton points); :func:`log_cell_density` is its density."""
    width = np.diff(edges_log)
    mass, _ = normalise_log(log_mass)
    cdf = np.concatenate(([0.0], np.cumsum(mass)))
    u = _unit_points(rng, n, 1)[:, 0]
    j = np.minimum(np.searchsorted(cdf, u, side="right") - 1, len(mass) - 1)
    j = np.where(mass[j] > 0, j, np.argmax(mass))      # u on a zero-mass boundary
    frac = (u - cdf[j]) / np.where(mass[j] > 0, mass[j], 1.0)
    return edges_log[j] + np.clip(frac, 0.0, 1.0) * width[j]


def log_cell_density(z: np.ndarray, edges_log: np.ndarray, log_mass: np.ndarray
                     ) -> np.ndarray:
    """The log density (n,) of :func:`draw_log_cells`'s density at points ``z`` (n,);
    -inf outside the cells."""
    width = np.diff(edges_log)
    mass, _ = normalise_log(log_mass)
    j = np.clip(np.searchsorted(edges_log, z, side="right") - 1, 0, len(mass) - 1)
    inside = (z >= edges_log[0]) & (z <= edges_log[-1])
    with np.errstate(divide="ignore"):
        return np.where(inside, np.log(mass[j] / width[j]), -np.inf)


def systematic(weights: np.ndarray, u: float) -> np.ndarray:
    """Ancestor indices (N,) for normalised weights (N,) and one uniform u in [0, 1)."""
    n = len(weights)
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.minimum(np.searchsorted(c, (u + np.arange(n)) / n, side="right"), n - 1)


def weighted_moments(z: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (d,) and covariance (d, d) of z (N, d) with normalised w (N,)."""
    mean = w @ z
    dz = z - mean
    cov = (dz * w[:, None]).T @ dz
    return mean, 0.5 * (cov + cov.T)


def liu_west_move(rng: np.random.Generator, z: np.ndarray, w: np.ndarray,
                  ancestors: np.ndarray, *, delta: float, steps: int,
                  floor_log: np.ndarray, widen: float = 1.0,
                  walk_var_log: np.ndarray | None = None) -> np.ndarray:
    """Resample-move with the Liu-West kernel compounded over ``steps`` samples.

    The paper's per-sample kernel ``theta' = a theta + (1-a) mean + N(0, h^2 V)``,
    ``h^2 = 1 - a^2``, with the roughening std floored at ``floor_log`` (d,), applied
    ``steps`` times without reweighting in between, is exactly
    ``a^k theta + (1-a^k) mean + N(0, (1-a^2k) V_f)`` where V_f is V with its diagonal
    raised to ``floor^2 / h^2``. That is what is drawn here, once, at resampling.
    ``widen`` > 1 scales V_f (used after a detected change). ``walk_var_log`` (d,) adds
    an independent random-walk step of that variance (log units) to every particle: the
    parameters' own evolution over the interval, which the kernel above, built for static
    parameters, does not have. Returns new z (N, d).
    """
    a = shrinkage(delta)
    h2 = jitter_var(delta)
    mean, cov = weighted_moments(z, w)
    cov = cov + np.diag(np.maximum(floor_log**2 / h2 - np.diag(cov), 0.0))
    ak = a ** max(int(steps), 1)
    noise_cov = (1.0 - ak * ak) * widen * cov
    vals, vecs = np.linalg.eigh(noise_cov)      # PSD square root: V may be rank-deficient
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))
    eps = rng.standard_normal(z.shape)
    znew = ak * z[ancestors] + (1.0 - ak) * mean + eps @ root.T
    if walk_var_log is not None:
        znew += rng.standard_normal(z.shape) * np.sqrt(np.asarray(walk_var_log))
    return znew


def effective_sample_size(w: np.ndarray) -> float:
    """1 / sum w^2 for normalised weights."""
    return float(1.0 / np.dot(w, w))


def normalise_log(logw: np.ndarray) -> tuple[np.ndarray, float]:
    """(normalised weights, log of the sum of exp(logw)); all -inf gives (zeros, -inf)."""
    top = float(np.max(logw))
    if not np.isfinite(top):
        return np.zeros_like(logw), -np.inf
    e = np.exp(logw - top)
    s = float(e.sum())
    return e / s, top + float(np.log(s))


@numba.njit(cache=True, nogil=True)
def absorb(logw: np.ndarray, ll: np.ndarray, nis: np.ndarray, w_prev: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """One sample's bookkeeping in one pass (the filter's per-sample Python cost).

    ``logw`` (N,) plus the sample's log-likelihoods ``ll[:N]`` gives the new log-weights;
    returns (new log-weights, normalised weights, log of their sum, ESS, the NIS
    ``nis[:N]`` averaged under the previous weights ``w_prev``). All -inf gives zero
    weights, a -inf sum and ESS 0, as :func:`normalise_log`.
    """
    n = logw.shape[0]
    out = np.empty(n)
    top = -np.inf
    nisbar = 0.0
    for i in range(n):
        v = logw[i] + ll[i]
        out[i] = v
        if v > top:
            top = v
        nisbar += w_prev[i] * nis[i]
    w = np.zeros(n)
    if not np.isfinite(top):
        return out, w, -np.inf, 0.0, nisbar
    total = 0.0
    for i in range(n):
        e = np.exp(out[i] - top)
        w[i] = e
        total += e
    sq = 0.0
    for i in range(n):
        w[i] /= total
        sq += w[i] * w[i]
    return out, w, top + np.log(total), 1.0 / sq, nisbar


@numba.njit(cache=True, nogil=True)
def absorb_block(logw: np.ndarray, LL: np.ndarray, NIS: np.ndarray, w_prev: np.ndarray,
                 ess_min: float, monitor_on: bool, dof: np.ndarray, block_len: int,
                 k_sigma: float, h_sigma: float, warmup_blocks: int, learn_blocks: int,
                 monitor_state: np.ndarray
                 ) -> tuple[int, np.ndarray, np.ndarray]:
    """:func:`absorb` and the innovation monitor over K samples until one needs more.

    ``LL``, ``NIS`` (K, >= N); ``dof`` (K,) sensors used per sample. Sample t is taken
    while it leaves the weights finite, raises no monitor alarm and keeps the ESS at or
    above ``ess_min``; the first sample that does not is left untouched (the monitor
    state too) for the caller's full step. Returns (samples taken, log-weights,
    normalised weights after them); ``monitor_state`` is updated in place.
    """
    n = logw.shape[0]
    w = w_prev
    for t in range(LL.shape[0]):
        new, wn, total, ess, nis = absorb(logw, LL[t, :n], NIS[t, :n], w)
        if not np.isfinite(total) or ess < ess_min:
            return t, logw, w
        if monitor_on and dof[t] > 0:
            saved = monitor_state.copy()
            if update_nb(block_len, k_sigma, h_sigma, warmup_blocks, learn_blocks,
                         monitor_state, nis, dof[t]):
                monitor_state[:] = saved
                return t, logw, w
        logw, w = new, wn
    return LL.shape[0], logw, w
