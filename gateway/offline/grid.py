"""The one "recorded run -> uniform grid" rule of the offline tools (estimate, identify).

The rule, for a recording's times ``t`` (s) and each signal (:func:`grid_period_s`,
:func:`interpolate`):

- the period is ``median(diff(t))``; times must increase and the rate be 1 Hz to 100 kHz;
- a value at grid time ``t_g`` lies at fraction f between its two neighbouring *valid*
  (finite) recorded values; it is the band-limited fractional delay of the 32 valid
  values around it (:mod:`gateway.frontend.fracdelay`, the live resampler's
  interpolator: it does not smooth the signal or colour the noise, so uneven times do
  not move the estimate) where those 32 have no gap, else linear between the two; it is
  **missing** (NaN) when the two neighbours are more than ``GAP_PERIODS`` = 1.5
  periods apart (a gap or a dropout) or ``t_g`` lies outside the valid values;
  ``bridge=True`` fills it linearly instead (speed, which varies slowly, is always
  bridged, never band-limited).

What each tool does with a missing point is where they really differ, and only there:

- ``estimate`` (:func:`to_grid`, uneven CSV times allowed): the grid starts at the
  first time and steps by the period to the last; a missing point is NaN and the
  estimator predicts through it; a point with no valid sensor is a predict-only sample
  (``update=False``); speed from the ``speed_mps`` column, else ``--speed``.
- ``identify`` (:func:`gateway.identify.data.dataset_from_recording`): it simulates the
  model at every sample, so it needs a record already on its grid (each step within
  0.1 % of the period; the recorded times are the grid) and bridges missing points,
  up to 1 % per signal; more is an error.
- The live **streaming resampler** (:mod:`gateway.frontend.resample`) keeps its own
  rule, because it must: it places each sensor on its node's reconstructed clock by
  sample index (not by time gaps), decides each grid point once and in real time
  (a neighbour later than ``deadline_s`` makes the point missing, where an offline
  tool sees the whole run), calls a point missing when a neighbouring node sample is
  absent (two node periods, its own rate, not the grid's), and holds speed up to a
  timeout instead of bridging to a future it has not seen.

Bounds of :func:`to_grid`, checked before anything is allocated: no gap between two
rows is longer than ``MAX_GAP_S`` (the estimator would predict through it point by
point), and the grid has at most ``MAX_GRID_POINTS`` points (about 2.8 h at 1 kHz,
~0.7 GB of grid). A longer recording is split into runs.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from gateway.errors import InputError
from gateway.frontend import fracdelay
from gateway.offline.interchange import Recording
from gateway.records import Estimate, Sample

GAP_PERIODS = 1.5
MAX_GAP_S = 60.0
MAX_GRID_POINTS = 10_000_000
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 100_000.0


@dataclass(frozen=True)
class GridData:
    """Samples on a uniform grid. ``t_s`` (K,), ``values`` (K, ny) NaN = missing,
    ``speed_mps`` (K,), ``update`` (K,) bool; ``fs_hz`` the grid rate."""

    t_s: np.ndarray
    values: np.ndarray
    speed_mps: np.ndarray
    update: np.ndarray
    fs_hz: float
    sensors: tuple[str, ...]

    def samples(self) -> Iterator[Sample]:
        """The grid as estimator samples."""
        for k in range(len(self.t_s)):
            yield Sample(t_s=float(self.t_s[k]), values=self.values[k],
                         speed_mps=float(self.speed_mps[k]), update=bool(self.update[k]))


def grid_period_s(t_s: np.ndarray, source: str) -> float:
    """The grid period (s) of recorded times ``t_s`` (T,): their median step, checked."""
    period = float(np.median(np.diff(t_s)))
    if not period > 0:
        raise InputError(f"{source}: expected increasing times, got median step {period}")
    if not MIN_RATE_HZ <= 1.0 / period <= MAX_RATE_HZ:
        raise InputError(f"{source}: expected a sample rate of {MIN_RATE_HZ:g} to "
                         f"{MAX_RATE_HZ:g} Hz (median time step), got {1.0 / period:.6g} Hz")
    return period


def interpolate(t_grid: np.ndarray, t: np.ndarray, x: np.ndarray, period_s: float, *,
                bridge: bool) -> np.ndarray:
    """Signal ``x`` (T,) at times ``t`` (T,) on ``t_grid`` (K,) by the rule above; (K,).

    NaN where missing (neighbours more than ``GAP_PERIODS * period_s`` apart, or outside
    the valid values), unless ``bridge``; all NaN when ``x`` has no valid value."""
    valid = np.isfinite(x)
    if not valid.any():
        return np.full(len(t_grid), np.nan)
    tv, xv = t[valid], x[valid]
    out = np.interp(t_grid, tv, xv)
    if bridge:
        return out
    nxt = np.clip(np.searchsorted(tv, t_grid, side="left"), 0, len(tv) - 1)
    prv = np.clip(np.searchsorted(tv, t_grid, side="right") - 1, 0, len(tv) - 1)
    exact = tv[nxt] == t_grid
    span = tv[nxt] - tv[prv]
    _band_limited(out, t_grid, tv, xv, prv, period_s)
    bad = ((span > GAP_PERIODS * period_s) & ~exact) | (t_grid < tv[0]) | (t_grid > tv[-1])
    out[bad] = np.nan
    return out


def _band_limited(out: np.ndarray, t_grid: np.ndarray, tv: np.ndarray, xv: np.ndarray,
                  prv: np.ndarray, period_s: float, chunk: int = 100_000) -> None:
    """Replace ``out`` (K,) in place by the fractional delay of valid values ``xv`` (V,)
    at ``tv`` (V,) wherever the taps around grid time ``t_grid`` (K,) have no gap; ``prv``
    (K,) the valid value at or before each grid time."""
    first = prv + fracdelay.OFFSETS[0]
    last = prv + fracdelay.OFFSETS[-1]
    ok = np.flatnonzero((first >= 0) & (last < len(tv)) & (t_grid >= tv[0]))
    gaps = np.concatenate(([0], np.cumsum(np.diff(tv) > GAP_PERIODS * period_s)))   # (V,)
    ok = ok[gaps[last[ok]] == gaps[first[ok]]]
    for lo in range(0, len(ok), chunk):
        j = ok[lo:lo + chunk]
        k0 = prv[j]
        f = (t_grid[j] - tv[k0]) / (tv[k0 + 1] - tv[k0])
        taps = fracdelay.taps_many(f)                           # (n, 2H)
        out[j] = (taps * xv[k0[:, None] + fracdelay.OFFSETS[None, :]]).sum(axis=1)


def to_grid(rec: Recording, sensors: tuple[str, ...], default_speed_mps: float) -> GridData:
    """A recording on the estimator's uniform grid (the rule and estimate's use of it:
    module docstring)."""
    t = np.asarray(rec.t_s, dtype=float)
    if len(t) < 2:
        raise InputError(f"{rec.source}: expected at least 2 samples, got {len(t)}")
    period = grid_period_s(t, rec.source)
    gaps = np.diff(t)
    k = int(np.argmax(gaps))
    if gaps[k] > MAX_GAP_S:
        raise InputError(f"{rec.source}: expected no gap longer than {MAX_GAP_S:g} s "
                         f"(split the recording), got {gaps[k]:.6g} s after t = {t[k]:.6g} s")
    span = (t[-1] - t[0]) / period
    if not span < MAX_GRID_POINTS:
        raise InputError(f"{rec.source}: expected at most {MAX_GRID_POINTS} grid points "
                         f"(split the recording), got {span:.3g} ({t[-1] - t[0]:.6g} s at "
                         f"{1.0 / period:.6g} Hz)")
    n = int(np.floor(span + 1e-9)) + 1
    grid = t[0] + period * np.arange(n)
    missing = [s for s in sensors if s not in rec.signals]
    if missing:
        raise InputError(f"{rec.source}: expected columns for sensors {list(sensors)}, "
                         f"got none for {missing}")
    values = np.column_stack([interpolate(grid, t, rec.signals[s], period, bridge=False)
                              for s in sensors])
    empty = [s for k, s in enumerate(sensors) if not np.isfinite(values[:, k]).any()]
    if empty:
        raise InputError(f"{rec.source}: expected values for sensors {list(sensors)}, got "
                         f"none for {empty}")
    if "speed" in rec.signals:
        speed = interpolate(grid, t, rec.signals["speed"], period, bridge=True)
        if not np.all(np.isfinite(speed)):
            raise InputError(f"{rec.source}: expected at least one speed_mps value, got none")
    else:
        speed = np.full(n, float(default_speed_mps))
    if np.any(~(speed > 0)):
        raise InputError(f"{rec.source}: expected positive speeds, got min {speed.min()} m/s")
    update = np.isfinite(values).any(axis=1)
    return GridData(t_s=grid, values=values, speed_mps=speed, update=update,
                    fs_hz=1.0 / period, sensors=tuple(sensors))


def history_rows(estimates: list[Estimate]) -> list[dict[str, float]]:
    """Flatten estimates into report rows: t_s, <name>_mean, <name>_std, ess, v_sy, v_say."""
    rows = []
    for e in estimates:
        row: dict[str, float] = {"t_s": e.t_s}
        for name, m, s in zip(e.names, e.mean, e.std, strict=True):
            row[f"{name}_mean"] = m
            row[f"{name}_std"] = s
        row.update(ess=e.ess, v_sy_mps=e.v_sy_mps, v_say_mps=e.v_say_mps)
        rows.append(row)
    return rows
