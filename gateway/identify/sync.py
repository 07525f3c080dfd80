"""Synchronisation of measured and simulated signals by cross-correlation (Kraft Sec. 3.2).

The lag is estimated section by section on band-limited signals. The integer lag is
the arg-max of the weighted sum of the per-signal cross-correlations; a parabola
through the peak and its neighbours gives a sub-sample refinement, which is reported
but not needed for an integer shift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal

from gateway.errors import InputError


@dataclass(frozen=True)
class LagEstimate:
    """``measured[k] ~ simulated[k - lag_samples]``: positive means the measurement is late.

    ``fraction`` in (-0.5, 0.5) is the parabolic sub-sample refinement; ``peak`` the
    normalised correlation at the peak (1 for identical shapes, ~0 for no coherence).
    """

    lag_samples: int
    fraction: float
    peak: float

    @property
    def refined(self) -> float:
        return self.lag_samples + self.fraction


def estimate_lag(measured: np.ndarray, simulated_ext: np.ndarray, max_lag: int,
                 weights: np.ndarray | None = None) -> LagEstimate:
    """Lag of ``measured`` (N, ny) behind ``simulated_ext`` (N + 2 max_lag, ny).

    ``simulated_ext`` covers the measured window extended by ``max_lag`` samples on
    both sides, so every candidate lag in [-max_lag, max_lag] uses a full overlap.
    ``weights`` (ny,) weight each signal's correlation (default: equal, after each
    signal is normalised to unit energy).
    """
    m = np.asarray(measured, dtype=float)
    s = np.asarray(simulated_ext, dtype=float)
    if m.ndim == 1:
        m = m[:, None]
    if s.ndim == 1:
        s = s[:, None]
    n, ny = m.shape
    if max_lag < 1 or s.shape != (n + 2 * max_lag, ny):
        raise InputError(f"expected simulated signals of shape ({n + 2 * max_lag}, {ny}) for "
                         f"max_lag {max_lag}, got {s.shape}")
    w = np.ones(ny) if weights is None else np.asarray(weights, dtype=float)
    total = np.zeros(2 * max_lag + 1)
    for i in range(ny):
        c = scipy.signal.correlate(s[:, i], m[:, i], mode="valid", method="fft")
        # c[j] = sum_k s[k + j] m[k]; the energy of each simulated window normalises it
        energy = np.convolve(s[:, i] ** 2, np.ones(n), mode="valid")
        denom = np.sqrt(np.maximum(energy, 1e-300) * max(float(m[:, i] @ m[:, i]), 1e-300))
        total += w[i] * c / denom
    total /= float(np.sum(w))
    j = int(np.argmax(total))
    lag = max_lag - j
    frac = 0.0
    if 0 < j < len(total) - 1:
        a, b, c3 = total[j - 1], total[j], total[j + 1]
        curv = a - 2 * b + c3
        if curv < 0:
            # offset of the parabola's peak in j; the lag runs the other way
            frac = float(-(0.5 * (a - c3) / curv))
    return LagEstimate(lag_samples=lag, fraction=float(np.clip(frac, -0.5, 0.5)),
                       peak=float(total[j]))


def shift(signal: np.ndarray, lag_samples: int) -> np.ndarray:
    """``out[k] = signal[k - lag]`` along axis 0, with the edges filled by zeros."""
    x = np.asarray(signal)
    out = np.zeros_like(x)
    if lag_samples >= 0:
        out[lag_samples:] = x[: len(x) - lag_samples]
    else:
        out[:lag_samples] = x[-lag_samples:]
    return out
