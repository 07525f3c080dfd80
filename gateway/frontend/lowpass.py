"""Streaming Butterworth low-pass of one channel, sample by sample, with a defined gap restart.

Coefficients come from ``scipy.signal.butter(order, cutoff_hz, output="sos", fs=fs_hz)``
and the recursion is scipy's ``sosfilt`` (direct form II transposed, the same two
delay values ``zi`` per section) written out per sample in pure Python. Why not call
``sosfilt``: the resampler filters one grid point at a time, and one ``sosfilt`` call
costs about 60 us of argument checking whatever its length, six channels 360 us per
point; this loop costs about 1 us per channel and point, and does the same arithmetic
in the same order on every platform, so output does not depend on how a stream is cut
into calls. ``tests/test_resample.py`` checks it against ``sosfilt``.

Gap rule: a non-finite input (missing or NotAvailable) outputs NaN and discards the
state. The first finite sample after it restarts the filter in its steady state for
that value (``sosfilt_zi(sos) * x``), so the output resumes at the input value with
no start-up transient. A stream's very first sample is handled the same way. With
``bridge`` > 0 (the curve detector's yaw rate) a gap of at most that many samples keeps
the state, and the filter goes on from it as if the gap were not there: a restart puts
the sample's noise into the output as a step, which at a slow cut-off lasts seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gateway.errors import ConfigError


@dataclass(frozen=True)
class Lowpass:
    """Fixed coefficients: per section ``(b0, b1, b2, a1, a2)`` (a0 = 1) and the unit-step
    steady-state delays ``(z0, z1)``, both tuples of length n_sections."""

    cutoff_hz: float
    sections: tuple[tuple[float, float, float, float, float], ...]
    zi_unit: tuple[tuple[float, float], ...]

    @property
    def sos(self) -> np.ndarray:
        """The coefficients in scipy's layout, shape (n_sections, 6)."""
        return np.array([[b0, b1, b2, 1.0, a1, a2] for b0, b1, b2, a1, a2 in self.sections])


def design_lowpass(order: int, cutoff_hz: float, fs_hz: float) -> Lowpass:
    """A Butterworth low-pass of ``order`` at ``cutoff_hz`` for a stream sampled at ``fs_hz``."""
    if order < 1 or not 0.0 < cutoff_hz < fs_hz / 2:
        raise ConfigError(f"expected order >= 1 and 0 < cutoff < fs/2 = {fs_hz / 2} Hz, "
                          f"got order {order}, cutoff {cutoff_hz} Hz")
    # Imported here, not at the top: scipy.signal pulls in scipy.stats, most of a second
    # of start-up, and the estimator workers import this module (they unpickle the
    # pipeline's estimator factory) without ever designing a filter.
    import scipy.signal

    sos = scipy.signal.butter(order, cutoff_hz, btype="low", output="sos", fs=fs_hz)
    zi = scipy.signal.sosfilt_zi(sos)
    sections = tuple((float(s[0]), float(s[1]), float(s[2]), float(s[4]), float(s[5]))
                     for s in sos)
    return Lowpass(float(cutoff_hz), sections, tuple((float(a), float(b)) for a, b in zi))


@dataclass
class LowpassState:
    """The delays of one channel, flat ``[z0, z1]`` per section; None = restart at the
    next finite sample."""

    z: list[float] | None = None
    gap: int = 0
    """Non-finite samples in a row so far."""


def lowpass_step(lp: Lowpass, state: LowpassState, x: float, bridge: int = 0) -> float:
    """Filter one sample; NaN in gives NaN out and, after more than ``bridge`` of them in
    a row, a restart at the next finite sample."""
    if not math.isfinite(x):
        state.gap += 1
        if state.gap > bridge:
            state.z = None
        return math.nan
    state.gap = 0
    z = state.z
    if z is None:
        z = [v * x for pair in lp.zi_unit for v in pair]
        state.z = z
    i = 0
    for b0, b1, b2, a1, a2 in lp.sections:
        y = b0 * x + z[i]
        z[i] = b1 * x - a1 * y + z[i + 1]
        z[i + 1] = b2 * x - a2 * y
        x = y
        i += 2
    return x
