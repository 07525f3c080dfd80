"""Innovation monitor: a CUSUM on block-averaged normalised innovations (abrupt faults).

Under the filter's model the innovations of a correct Kalman filter are white, and the
normalised innovation squared NIS = sum e^2/S has a chi-square distribution with as
many degrees of freedom as sensors used. The monitor averages the posterior-weighted
NIS over blocks of ``block_len`` samples, ``r_b = sum NIS / sum dof`` (1 when the model
fits), standardises it as ``z_b = (r_b - mu) / sigma`` with ``sigma^2 = 2 / dof`` (the
chi-square value, or larger if learned) and runs a one-sided CUSUM
``g = max(0, g + z_b - k)``; an alarm is ``g > h``.

- ``mu`` is the larger of 1 and the upper 97.5 % confidence bound of the block mean
  learned once the filter has settled (then frozen), so an imperfect model (e.g.
  saturating dampers) raises the baseline instead of alarming forever, while data that
  fit the model are tested against (about) the chi-square mean. A baseline that keeps
  adapting only on quiet blocks drifts low (selection bias) and was measured to cause
  false alarms; hence frozen, and the upper bound keeps a learning error from eating
  the CUSUM allowance k.
- From the prior the monitor waits ``warmup_blocks`` (filter converging), then learns
  ``learn_blocks``, then tests. After a re-diversification it waits again but keeps
  the baseline. It never tests while the filter is still converging.
- With k = 1 and h = 8 the in-control run length of the CUSUM for N(0, 1) block scores is
  about 5e7 blocks (Siegmund), i.e. years at 5 blocks/s; a 2-sigma shift is flagged in
  about 9 blocks.

State is a small float array so the estimator can checkpoint it bit-exactly. No I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class MonitorConfig:
    """Block length in samples, CUSUM k and h (in block-sigma units), phases in blocks."""

    block_len: int = 200
    k_sigma: float = 1.0
    h_sigma: float = 8.0
    warmup_blocks: int = 15
    learn_blocks: int = 25


# state vector layout
_NIS, _DOF, _N, _BLOCKS, _G, _MU, _VAR, _LAST_Z, _LEARN_SUM, _LEARN_SQ = range(10)
STATE_LEN = 10


def initial_state() -> np.ndarray:
    """A fresh monitor state (at a (re)seed)."""
    s = np.zeros(STATE_LEN)
    s[_MU] = 1.0
    return s


def after_reseed(state: np.ndarray) -> None:
    """Restart the phases after a re-diversification, keeping the learned baseline.

    The baseline is learned once, after the initial convergence; relearning it after a
    detected change would absorb a filter that re-converged to a wrong value.
    """
    mu, var = state[_MU], state[_VAR]
    state[:] = initial_state()
    state[_MU], state[_VAR] = mu, var
    state[_LEARN_SUM] = -1.0      # marks "learned": skip the learning phase


def update(cfg: MonitorConfig, state: np.ndarray, nis: float, dof: int) -> bool:
    """Add one sample's weighted NIS with ``dof`` sensors; True when an alarm is raised.

    ``state`` (STATE_LEN,) is updated in place.
    """
    return bool(update_nb(cfg.block_len, cfg.k_sigma, cfg.h_sigma, cfg.warmup_blocks,
                          cfg.learn_blocks, state, float(nis), int(dof)))


@numba.njit(cache=True, nogil=True)
def update_nb(block_len: int, k_sigma: float, h_sigma: float, warmup_blocks: int,
              learn_blocks: int, state: np.ndarray, nis: float, dof: int) -> bool:
    """:func:`update` with the configuration spelled out, callable from compiled code."""
    if dof <= 0 or not np.isfinite(nis):
        return False
    state[_NIS] += nis
    state[_DOF] += dof
    state[_N] += 1
    if state[_N] < block_len:
        return False
    r = state[_NIS] / state[_DOF]
    chi_var = 2.0 / state[_DOF]
    state[_NIS] = 0.0
    state[_DOF] = 0.0
    state[_N] = 0.0
    state[_BLOCKS] += 1
    b = state[_BLOCKS]
    if b <= warmup_blocks:
        return False
    if b <= warmup_blocks + learn_blocks and state[_LEARN_SUM] >= 0.0:
        state[_LEARN_SUM] += r
        state[_LEARN_SQ] += r * r
        m = b - warmup_blocks
        mean = state[_LEARN_SUM] / m
        var = max(state[_LEARN_SQ] / m - mean * mean, 0.0)
        state[_VAR] = var
        state[_MU] = mean + 2.0 * np.sqrt(max(var, chi_var) / m)   # upper 97.5 % bound
        return False
    mu = max(1.0, state[_MU])
    sigma = np.sqrt(max(chi_var, state[_VAR]))
    z = (r - mu) / sigma
    state[_LAST_Z] = z
    state[_G] = max(0.0, state[_G] + z - k_sigma)
    return state[_G] > h_sigma


def cusum(state: np.ndarray) -> float:
    """Current CUSUM value g (block-sigma units)."""
    return float(state[_G])
