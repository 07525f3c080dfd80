"""The sensors' white-noise variance, measured in a band above the vehicle's dynamics.

Why: the filter's likelihood takes the sensor noise variances R as known, and the
estimates are sensitive to them. Data whose noise std is 1.4 x the model's moved λ by
+13 % on 20 s runs, 0.7 x by -3 to -6 % (docs/estimator.md "Sensor noise"). The paper's
Qv is partly unreadable (docs/model-notes: two mantissas lost, one exponent doubtful),
and a real sensor, or another simulator's noise convention, need not match it.

How: above about 0.3 of the grid rate the vehicle's accelerations and yaw rate have
almost no power (they are states or rows of A, driven through the track's integrators),
while white sensor noise is flat up to the Nyquist frequency. So the mean one-sided
periodogram over the band ``BAND_FRACTION`` of the grid rate, times ``fs_hz / 2``, is the
noise variance plus the model's own signal in that band, which :func:`model_band_variance`
computes from A(θ, v) at the filter's current estimate and is subtracted. At 1 kHz the band
is 300-420 Hz: below the resampler's fractional-delay transition band (flat within 1 %
up to 0.43 of the node rate, :mod:`gateway.frontend.fracdelay`). The model's signal there,
relative to the paper's noise: 0.09 % for the bogie accelerometer, 4 % for a wheelset
accelerometer at the Sec. 4.2 point (up to 1.8 x at the prior box's corners at 80 m/s,
hence the subtraction), below 1e-5 for the gyro and the body accelerometer.

Segments: :func:`segment_len` samples (0.256 s: 256 at 1 kHz, 64 at 250 Hz), Hann window,
half overlap; a segment with a missing value
or a predict-only sample is left out. The relative standard error is the scatter of the
per-segment band means over the square root of their number.

No I/O, no state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.errors import EstimatorError
from gateway.model.vehicle import (
    VehicleParams,
    frequency_response,
    input_matrix,
    output_matrix,
    system_matrix,
    track_intensity,
)

BAND_FRACTION = (0.30, 0.42)
"""The measuring band as fractions of the grid rate (300-420 Hz at 1 kHz)."""
SEGMENT_S = 0.256
"""Periodogram segment length (3.9 Hz bins)."""
MIN_SEGMENTS = 8
"""Fewer complete segments than this measure nothing."""


@dataclass(frozen=True)
class BandVariance:
    """What the band says of each sensor: ``variance`` (ny,) SI units^2, the band's power
    as white-noise variance; ``se_rel`` (ny,) its relative standard error; ``segments``
    used."""

    variance: np.ndarray
    se_rel: np.ndarray
    segments: int


def segment_len(fs_hz: float) -> int:
    """Samples per periodogram segment on a grid of ``fs_hz``: the power of two nearest
    ``SEGMENT_S`` (at least 32)."""
    return max(32, 2 ** int(round(np.log2(SEGMENT_S * fs_hz))))


def band_bins(fs_hz: float) -> np.ndarray:
    """Indices of the rfft bins of a :func:`segment_len` segment inside the band."""
    f = np.fft.rfftfreq(segment_len(fs_hz), 1.0 / fs_hz)
    lo, hi = BAND_FRACTION[0] * fs_hz, BAND_FRACTION[1] * fs_hz
    return np.flatnonzero((f >= lo) & (f <= hi))


def complete_samples(y: np.ndarray, usable: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: the samples of ``y`` (T, ny) with every value finite and, where
    ``usable`` (T,) is given, marked usable."""
    ok = np.all(np.isfinite(np.asarray(y, dtype=float)), axis=1)
    if usable is not None:
        ok &= np.asarray(usable, dtype=bool)
    return ok


def segment_starts(complete: np.ndarray, fs_hz: float) -> list[int]:
    """Start indices of the complete, half-overlapping :func:`segment_len` segments over
    the samples ``complete`` (T,) bool marks."""
    n = segment_len(fs_hz)
    return [s for s in range(0, len(complete) - n + 1, n // 2) if complete[s:s + n].all()]


def band_variance(y: np.ndarray, fs_hz: float, usable: np.ndarray | None = None
                  ) -> BandVariance | None:
    """The band's power of ``y`` (T, ny) on a grid of ``fs_hz`` as white-noise variance
    (ny,); ``usable`` (T,) marks the samples that may be used (default: all finite).
    None when fewer than ``MIN_SEGMENTS`` complete segments exist."""
    y = np.asarray(y, dtype=float)
    if y.ndim != 2:
        raise EstimatorError(f"expected samples of shape (T, ny), got {y.shape}")
    n = segment_len(fs_hz)
    starts = segment_starts(complete_samples(y, usable), fs_hz)
    if len(starts) < MIN_SEGMENTS:
        return None
    w = np.hanning(n + 2)[1:-1]                  # (n,): zero-free Hann
    seg = np.stack([y[s:s + n] for s in starts])                  # (S, n, ny)
    seg = seg - seg.mean(axis=1, keepdims=True)
    spec = np.fft.rfft(seg * w[None, :, None], axis=1)            # (S, F, ny)
    density = 2.0 * np.abs(spec) ** 2 / (fs_hz * np.sum(w**2))    # one-sided, per Hz
    per_seg = density[:, band_bins(fs_hz), :].mean(axis=1) * fs_hz / 2.0   # (S, ny)
    mean = per_seg.mean(axis=0)
    se = per_seg.std(axis=0, ddof=1) / np.sqrt(len(starts))
    with np.errstate(divide="ignore", invalid="ignore"):
        se_rel = np.where(mean > 0, se / mean, np.inf)
    return BandVariance(variance=mean, se_rel=se_rel, segments=len(starts))


def model_band_variance(params: VehicleParams, theta: np.ndarray, v_mps: float,
                        sensors: tuple[str, ...], ar_paper: float, fs_hz: float
                        ) -> np.ndarray:
    """The model's own signal in the band, as :func:`band_variance` would read it, (ny,):
    the mean one-sided output PSD of the noise-free model at ``theta`` (Csy, Csay, λ) and
    ``v_mps`` over the band bins, times ``fs_hz / 2`` (the first alias included)."""
    A = system_matrix(params, np.asarray(theta, dtype=float)[:3], v_mps)
    G = input_matrix()
    H = output_matrix(A, sensors)
    q = track_intensity(ar_paper, v_mps)
    f_hz = np.fft.rfftfreq(segment_len(fs_hz), 1.0 / fs_hz)[band_bins(fs_hz)]
    total = np.zeros(H.shape[0])
    for T in frequency_response(A, G, H, np.concatenate([f_hz, fs_hz - f_hz])):  # (ny, nw)
        total += 2.0 * q * np.sum(np.abs(T) ** 2, axis=1)
    return total / len(f_hz) * fs_hz / 2.0
