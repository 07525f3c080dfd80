"""Identification datasets: turn a recorded source into a checked, uniformly sampled run.

The readers (:mod:`gateway.identify.sources`: an interchange CSV or a CAN log through
the gateway's own decode, validation, resampler and gate) each produce a
:class:`~gateway.offline.interchange.Recording` for :func:`dataset_from_recording`.
Its grid and gaps follow the offline tools' one rule (:mod:`gateway.offline.grid`,
whose docstring also says where identification, estimation and the streaming
resampler differ): identification needs a record already on its grid, and bridges
its missing points, up to ``MAX_MISSING_FRACTION`` per signal.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gateway.errors import InputError
from gateway.model.vehicle import SENSORS_5
from gateway.offline.grid import grid_period_s, interpolate
from gateway.offline.interchange import SENSOR_COLUMNS, Recording

log = logging.getLogger(__name__)

UNIFORM_TOLERANCE = 1e-3
"""Largest relative deviation of a sample interval from the grid period (median step)."""
MAX_MISSING_FRACTION = 0.01
"""Dropouts (NaN) are bridged by linear interpolation up to this fraction per signal."""


@dataclass(frozen=True)
class Dataset:
    """A run ready for identification; time is the first axis.

    ``t_s`` (T,) uniform; ``measured`` (T, ny) SI units in ``sensors`` order;
    ``speed_mps`` (T,) > 0; ``fs_hz`` the sample rate.
    """

    t_s: np.ndarray
    measured: np.ndarray
    sensors: tuple[str, ...]
    speed_mps: np.ndarray
    fs_hz: float
    source: str

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def position_m(self, t_s: np.ndarray, offset_m: float) -> np.ndarray:
        """Leading-wheelset position [m] at times ``t_s`` (any), ``offset_m`` at t_s[0].

        Integrates the speed (trapezoid); outside the recording the end speeds are held.
        """
        dt = np.diff(self.t_s)
        x = np.concatenate([[0.0], np.cumsum(0.5 * (self.speed_mps[1:] + self.speed_mps[:-1])
                                             * dt)])
        t = np.asarray(t_s, dtype=float)
        inside = np.interp(t, self.t_s, x)
        before = (t - self.t_s[0]) * self.speed_mps[0]
        after = x[-1] + (t - self.t_s[-1]) * self.speed_mps[-1]
        pos = np.where(t < self.t_s[0], before, np.where(t > self.t_s[-1], after, inside))
        return offset_m + pos


def _bridge_dropouts(name: str, t_s: np.ndarray, values: np.ndarray, period_s: float,
                     source: str) -> np.ndarray:
    bad = ~np.isfinite(values)
    if not bad.any():
        return values
    column = SENSOR_COLUMNS.get(name, name)
    if bad.mean() > MAX_MISSING_FRACTION:
        raise InputError(f"{source}: column {column!r}: expected at most "
                         f"{MAX_MISSING_FRACTION:.0%} missing values, got {bad.mean():.1%}")
    log.info("%s: bridged %d dropouts in %s by interpolation", source, int(bad.sum()), column)
    return interpolate(t_s, t_s, values, period_s, bridge=True)


def dataset_from_recording(rec: Recording, sensors: tuple[str, ...] | None = None,
                           speed_mps: float | None = None) -> Dataset:
    """Check a Recording and make a Dataset of ``sensors`` (default: all present).

    The speed comes from the recording's speed column, else from ``speed_mps``.
    Raises InputError on missing columns, uneven time, constant signals or no speed.
    """
    names = tuple(sensors) if sensors else rec.sensors
    unknown = [s for s in names if s not in SENSORS_5]
    if unknown:
        raise InputError(f"expected sensors from {SENSORS_5}, got {unknown}")
    missing = [SENSOR_COLUMNS[s] for s in names if s not in rec.signals]
    if missing:
        raise InputError(f"{rec.source}: expected columns {[SENSOR_COLUMNS[s] for s in names]}, "
                         f"got none of {missing}")
    t = np.asarray(rec.t_s, dtype=float)
    if len(t) < 16:
        raise InputError(f"{rec.source}: expected at least 16 samples, got {len(t)}")
    dt = np.diff(t)
    period = grid_period_s(t, rec.source)
    if float(np.max(np.abs(dt - period))) > UNIFORM_TOLERANCE * period:
        raise InputError(f"{rec.source}: expected uniform sampling (within "
                         f"{UNIFORM_TOLERANCE:.1%}), got intervals from {dt.min():.6g} s "
                         f"to {dt.max():.6g} s")
    columns = []
    for s in names:
        v = _bridge_dropouts(s, t, np.asarray(rec.signals[s], dtype=float), period,
                             rec.source)
        if float(np.ptp(v)) <= 1e-12 * max(1.0, float(np.max(np.abs(v)))):
            raise InputError(f"{rec.source}: column {SENSOR_COLUMNS[s]!r}: expected a varying "
                             f"signal, got the constant value {v[0]:g}")
        columns.append(v)
    speed = _speed(rec, speed_mps, t, period)
    return Dataset(t_s=t, measured=np.column_stack(columns), sensors=names, speed_mps=speed,
                   fs_hz=1.0 / period, source=rec.source)


def _speed(rec: Recording, speed_mps: float | None, t_s: np.ndarray,
           period_s: float) -> np.ndarray:
    n = len(t_s)
    if speed_mps is not None:
        if not (np.isfinite(speed_mps) and speed_mps > 0):
            raise InputError(f"expected a positive speed in m/s, got {speed_mps}")
        return np.full(n, float(speed_mps))
    if "speed" not in rec.signals:
        raise InputError(f"{rec.source}: expected a speed_mps column or a --speed-mps "
                         f"value, got neither")
    v = _bridge_dropouts("speed_mps", t_s, np.asarray(rec.signals["speed"], dtype=float),
                         period_s, rec.source)
    if np.any(v <= 0):
        raise InputError(f"{rec.source}: column 'speed_mps': expected positive speeds, got "
                         f"minimum {float(np.min(v)):g}")
    return v


