"""Band-limited fractional-delay interpolation: the one tap table for node samples on a grid.

A sensor node samples on its own clock, at its own phase against the estimator's grid.
Putting its samples on the grid is a fractional delay: the value at ``k0 + f`` (sample
index ``k0``, fraction ``0 <= f < 1``) from the samples around it. Linear interpolation
is a two-tap fractional delay that low-passes the signal and scales the sensor noise by
``sqrt((1 - f)**2 + f**2)`` (0.71 at f = 1/2), correlated from one grid point to the
next: the estimator's white-noise model does not hold, and λ came out 3-7 % low with
nodes between grid points (docs/resampler.md "Node timing"). A windowed-sinc fractional
delay is close to all-pass: it delays the signal without smoothing it and leaves white
noise white with its variance, below the window's transition band.

The kernel (:func:`taps`): ``2 * HALF_TAPS`` taps on the samples ``k0 - HALF_TAPS + 1 ..
k0 + HALF_TAPS``, ``h[i] = sinc(f - i) * kaiser(f - i)``, normalised to unit DC gain,
tabulated at ``PHASES + 1`` fractions ``f = p / PHASES`` (the nearest is used: at most
``0.5 / PHASES`` of a node period off, 0.5 µs at 1 kHz). At f = 0 the kernel is the
sample itself. Response, against the ideal delay ``exp(i w f)``: within 1 % (complex
error) up to 0.43 of the node rate at every fraction; at f = 1/2, the worst, -3 dB at
0.47, and white noise keeps 94 % of its variance (99 % at f = 0.1); linear
interpolation at f = 1/2 is 1 % off at 0.045 of the node rate and keeps 50 %
(``tests/test_fracdelay.py``).

The cost is latency: a value needs ``HALF_TAPS`` node samples after ``k0``. No I/O, no
state: the table is computed once at import.
"""

from __future__ import annotations

import numpy as np

HALF_TAPS = 16
"""Taps on each side of the fraction: 32 taps, ``HALF_TAPS`` node periods of latency."""
PHASES = 1024
"""Fractions tabulated per node period."""
KAISER_BETA = 8.0
"""Kaiser window shape: about 80 dB side lobes, a transition band about 0.1 of the
node rate wide centred on its Nyquist frequency."""
OFFSETS = np.arange(-HALF_TAPS + 1, HALF_TAPS + 1)
"""Sample offsets from ``k0`` of the taps, shape (2 * HALF_TAPS,)."""


def _table() -> np.ndarray:
    f = np.arange(PHASES + 1)[:, None] / PHASES                # (P + 1, 1)
    x = f - OFFSETS[None, :]                                   # (P + 1, 2H): f - i
    window = np.i0(KAISER_BETA * np.sqrt(np.clip(1.0 - (x / HALF_TAPS) ** 2, 0.0, None)))
    h = np.sinc(x) * window / np.i0(KAISER_BETA)
    h /= h.sum(axis=1, keepdims=True)
    h[0] = OFFSETS == 0                                        # f = 0: the sample itself
    h[PHASES] = OFFSETS == 1                                   # f = 1: the next one
    return h


TABLE = _table()
"""Tap weights per tabulated fraction, shape (PHASES + 1, 2 * HALF_TAPS); read-only."""
TABLE.setflags(write=False)


def taps(f: float) -> np.ndarray:
    """The tap weights (2 * HALF_TAPS,) for fraction ``0 <= f <= 1`` after sample ``k0``,
    on the samples ``k0 + OFFSETS``."""
    return TABLE[int(f * PHASES + 0.5)]


def taps_many(f: np.ndarray) -> np.ndarray:
    """Tap weights for many fractions ``f`` (K,) in [0, 1]: shape (K, 2 * HALF_TAPS)."""
    return TABLE[np.clip(np.floor(f * PHASES + 0.5).astype(np.int64), 0, PHASES)]
