"""The time-domain least-squares misfit of Kraft et al. eq. (2), over learn sections.

``J(p) = sum_s int e' W e dt / sum_s int x_meas' W x_meas dt`` with ``e = x_meas -
x_model(p)``; both signals are band-limited (Butterworth band-pass, zero-phase
``sosfiltfilt``) before the comparison, and ``W = diag(1 / var(x_meas,i))`` by default,
so that every signal counts equally whatever its unit. ``J = 1`` means "no better than
predicting zero"; Kraft reports ``100 J`` as the "final value" in %.

The model is driven by the known track (:mod:`gateway.identify.track`) and simulated
at ``sim_rate_hz`` (the recording is decimated to it with a zero-phase anti-alias
FIR) with the exact discretisation of :mod:`gateway.identify.simulate`. Each section
is simulated from rest over a pre-roll, so that the start transient has decayed.
Measured and simulated signals are band-limited by the same filter over the same
window, the section plus ``margin_s`` each side, so ``e`` is exactly the band-limited
error and the filter's edge effects stay outside the section.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.signal

from gateway.errors import InputError
from gateway.identify.data import Dataset
from gateway.identify.params import ParamPoint
from gateway.identify.simulate import forced_response
from gateway.identify.sync import LagEstimate, estimate_lag
from gateway.identify.track import Track, wheel_alignment
from gateway.model.vehicle import VehicleParams

J_PENALTY = 1e3
"""Misfit returned when the simulation is not finite (a strongly unstable point)."""


@dataclass(frozen=True)
class MisfitConfig:
    """Band, rates and margins of the misfit. ``weights`` (ny,) or None for 1/variance."""

    band_low_hz: float = 0.4
    band_high_hz: float = 20.0
    filter_order: int = 4
    sim_rate_hz: float = 200.0
    preroll_s: float = 6.0
    margin_s: float = 5.0
    weights: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Section:
    """A learn section [start_s, stop_s) in recording time."""

    start_s: float
    stop_s: float

    def label(self) -> str:
        return f"{self.start_s:g}-{self.stop_s:g} s"


def sections_from_positions(dataset: Dataset, ranges_m: list[tuple[float, float]],
                            offset_m: float) -> list[Section]:
    """Learn sections given as position ranges [m] along the track, turned into time."""
    x = dataset.position_m(dataset.t_s, offset_m)
    out = []
    for a, b in ranges_m:
        if not (x[0] <= a < b <= x[-1]):
            raise InputError(f"learn section {a:g}-{b:g} m: expected a range within the "
                             f"recorded positions {x[0]:.1f}-{x[-1]:.1f} m")
        out.append(Section(float(np.interp(a, x, dataset.t_s)),
                           float(np.interp(b, x, dataset.t_s))))
    return out


def check_sections(dataset: Dataset, sections: list[Section], min_s: float = 1.0) -> None:
    """Raise InputError unless every section lies inside the recording and is long enough."""
    if not sections:
        raise InputError("expected at least one learn section, got none")
    t0, t1 = float(dataset.t_s[0]), float(dataset.t_s[-1])
    for s in sections:
        if not (t0 - 1e-9 <= s.start_s < s.stop_s <= t1 + 1.0 / dataset.fs_hz + 1e-9):
            raise InputError(f"learn section {s.label()}: expected a range within the "
                             f"recording {t0:g}-{t1:g} s")
        if s.stop_s - s.start_s < min_s:
            raise InputError(f"learn section {s.label()}: expected at least {min_s:g} s, "
                             f"got {s.stop_s - s.start_s:g} s")


class TrackMisfit:
    """J(point) for a dataset, a known track and learn sections; picklable for workers.

    ``lags_s`` (n_sections,) are the synchronisation shifts: the measurement at
    recorded time t is compared with the model response to the track at x(t - lag).
    """

    def __init__(self, dataset: Dataset, track: Track, sections: list[Section],
                 config: MisfitConfig, offset_m: float,
                 lags_s: tuple[float, ...] | None = None) -> None:
        check_sections(dataset, sections)
        self.dataset, self.track, self.sections = dataset, track, list(sections)
        self.config, self.offset_m = config, float(offset_m)
        self.lags_s = tuple(lags_s) if lags_s is not None else (0.0,) * len(sections)
        if len(self.lags_s) != len(sections):
            raise InputError(f"expected one lag per section ({len(sections)}), got "
                             f"{len(self.lags_s)}")
        fs = dataset.fs_hz
        self.decimation = max(1, int(round(fs / config.sim_rate_hz)))
        self.fs_sim_hz = fs / self.decimation
        nyquist = 0.5 * self.fs_sim_hz
        if not 0 < config.band_low_hz < config.band_high_hz < 0.8 * nyquist:
            raise InputError(f"expected 0 < band {config.band_low_hz:g}-"
                             f"{config.band_high_hz:g} Hz below 0.8 x the simulation Nyquist "
                             f"frequency {nyquist:g} Hz")
        self.sos_rec = self._sos(fs)
        self.sos_sim = self._sos(self.fs_sim_hz)
        self.measured_bl = scipy.signal.sosfiltfilt(self.sos_rec, dataset.measured, axis=0)
        q = self.decimation
        meas = dataset.measured if q == 1 else scipy.signal.decimate(
            dataset.measured, q, ftype="fir", zero_phase=True, axis=0)
        self.t_sim = dataset.t_s[::q]
        self.windows = [self._window(s) for s in sections]
        self.index = [np.arange(s0, s1) * q for _, _, s0, s1 in self.windows]
        self.meas_sections = [
            scipy.signal.sosfiltfilt(self.sos_sim, meas[w0:w1], axis=0)[s0 - w0:s1 - w0]
            for w0, w1, s0, s1 in self.windows]
        if config.weights is None:
            var = np.var(np.concatenate(self.meas_sections), axis=0)
            if np.any(var <= 0):
                raise InputError("expected varying band-limited signals in the learn "
                                 f"sections, got variances {var.tolist()}")
            self.weights = 1.0 / var
        else:
            self.weights = np.asarray(config.weights, dtype=float)
            if self.weights.shape != (len(dataset.sensors),) or np.any(self.weights < 0):
                raise InputError(f"expected {len(dataset.sensors)} non-negative weights, "
                                 f"got {config.weights}")
        self.denominator = np.array([np.sum(m**2, axis=0) for m in self.meas_sections]).sum(0)
        self._check_track()

    def _sos(self, fs_hz: float) -> np.ndarray:
        c = self.config
        return np.asarray(scipy.signal.butter(c.filter_order, [c.band_low_hz, c.band_high_hz],
                                              btype="band", fs=fs_hz, output="sos"))

    def _window(self, s: Section) -> tuple[int, int, int, int]:
        """Sim-grid indices (w0, w1, s0, s1): filter window and the section inside it.

        Measured and simulated signals are band-limited over the same window, the
        section widened by ``margin_s`` (clipped to the recording), so both see the same
        filter edge effects, which the margin keeps out of the section.
        """
        t = self.t_sim
        s0 = int(np.searchsorted(t, s.start_s - 1e-9))
        s1 = int(np.searchsorted(t, s.stop_s - 1e-9))
        n_margin = int(math.ceil(self.config.margin_s * self.fs_sim_hz))
        return max(0, s0 - n_margin), min(len(t), s1 + n_margin), s0, s1

    def _check_track(self) -> None:
        """Fail early, naming the needed range, if the track does not cover the sections."""
        behind_m = 2.0 * VehicleParams().a_m * 1.5      # trailing wheelset, a up to +50 %
        for (w0, w1, _, _), lag in zip(self.windows, self.lags_s, strict=True):
            t0 = self.t_sim[w0] - self.config.preroll_s - lag
            t1 = self.t_sim[w1 - 1] + 1.0 / self.fs_sim_hz - lag
            x = self.dataset.position_m(np.array([t0, t1]), self.offset_m)
            self.track.at(np.array([x[0] - behind_m, x[1]]))

    def _copy(self, **changes: object) -> TrackMisfit:
        new = object.__new__(TrackMisfit)
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        new._check_track()
        return new

    def with_lags(self, lags_s: tuple[float, ...]) -> TrackMisfit:
        """The same misfit with new synchronisation shifts."""
        if len(lags_s) != len(self.sections):
            raise InputError(f"expected one lag per section ({len(self.sections)}), got "
                             f"{len(lags_s)}")
        return self._copy(lags_s=tuple(float(v) for v in lags_s))

    def at_offset(self, offset_m: float) -> TrackMisfit:
        """The same misfit with the track registered at ``offset_m`` [m] instead.

        Cheap (no filtering is redone), so an optimiser may call it at every evaluation.
        """
        return self._copy(offset_m=float(offset_m))

    def simulate(self, point: ParamPoint, t_start_s: float, n: int, dt_s: float,
                 lag_s: float) -> np.ndarray:
        """Model outputs (n, ny), SI, at recording times ``t_start_s + k dt_s``, not filtered.

        Simulated from rest over a pre-roll, so the start transient has decayed; the track
        is read at x(t - lag_s). Non-finite or runaway responses come back as inf.
        """
        n_pre = int(math.ceil(self.config.preroll_s / dt_s))
        t = t_start_s + np.arange(-n_pre, n + 1) * dt_s - lag_s
        x = self.dataset.position_m(t, self.offset_m)
        speed = float(np.mean(np.interp(t, self.dataset.t_s, self.dataset.speed_mps)))
        wheels = wheel_alignment(self.track, x, point.as_dict()["a_m"])
        y = forced_response(point, self.dataset.sensors, speed, dt_s, wheels)[n_pre:]
        if not np.all(np.isfinite(y)) or float(np.max(np.abs(y))) > 1e6:
            return np.full((n, y.shape[1]), np.inf)
        return y

    def section_response(self, point: ParamPoint, k: int) -> np.ndarray:
        """Band-limited simulated signals of section k on the simulation grid, (n_k, ny)."""
        w0, w1, s0, s1 = self.windows[k]
        y = self.simulate(point, float(self.t_sim[w0]), w1 - w0, 1.0 / self.fs_sim_hz,
                          self.lags_s[k])
        if not np.all(np.isfinite(y)):
            return np.full((s1 - s0, y.shape[1]), np.inf)
        return scipy.signal.sosfiltfilt(self.sos_sim, y, axis=0)[s0 - w0:s1 - w0]

    def error_energy(self, point: ParamPoint) -> np.ndarray:
        """Sum over sections of the squared error of each signal, shape (ny,)."""
        total = np.zeros(len(self.dataset.sensors))
        for k, meas in enumerate(self.meas_sections):
            total += np.sum((meas - self.section_response(point, k)) ** 2, axis=0)
        return total

    def per_signal(self, point: ParamPoint) -> np.ndarray:
        """J of each signal alone, shape (ny,); J_PENALTY where not finite."""
        j = self.error_energy(point) / self.denominator
        return np.where(np.isfinite(j), j, J_PENALTY)

    def __call__(self, point: ParamPoint) -> float:
        """The weighted misfit J (dimensionless; 0 is a perfect fit)."""
        e = self.error_energy(point)
        j = float(self.weights @ e / (self.weights @ self.denominator))
        return j if math.isfinite(j) else J_PENALTY

    def synchronise(self, point: ParamPoint, max_lag_s: float,
                    sensors: tuple[str, ...] | None = None) -> list[LagEstimate]:
        """Cross-correlation lag of each section at the recording rate (Kraft Sec. 3.2).

        The model at ``point`` is simulated over each section widened by ``max_lag_s``
        on both sides; lags are in recording samples. ``sensors`` limits the signals
        used (default: the wheelset accelerations when recorded, which follow the track
        closely, as Kraft's axle-box signals do; otherwise all).
        """
        fs = self.dataset.fs_hz
        m = int(round(max_lag_s * fs))
        if m < 1:
            raise InputError(f"expected a maximum lag of at least one sample, got {max_lag_s} s")
        names = self.dataset.sensors
        if sensors is None:
            wheel = tuple(s for s in ("acc_w1", "acc_w2") if s in names)
            sensors = wheel or names
        use = np.array([s in sensors for s in names], dtype=float)
        out = []
        t = self.dataset.t_s
        n_margin = int(math.ceil(self.config.margin_s * fs))
        for s in self.sections:
            i0 = int(np.searchsorted(t, s.start_s - 1e-9))
            i1 = int(np.searchsorted(t, s.stop_s - 1e-9))
            wide = m + n_margin
            y = self.simulate(point, float(t[i0]) - wide / fs, i1 - i0 + 2 * wide, 1.0 / fs, 0.0)
            sim = scipy.signal.sosfiltfilt(self.sos_rec, y, axis=0)[n_margin:-n_margin]
            meas = self.measured_bl[i0:i1]
            out.append(estimate_lag(meas, sim, m, use * self.weights * np.sum(meas**2, axis=0)))
        return out

    def describe(self) -> dict[str, object]:
        """The settings as plain data, for the report."""
        return {"band_hz": [self.config.band_low_hz, self.config.band_high_hz],
                "filter": f"Butterworth order {self.config.filter_order}, zero-phase",
                "sim_rate_hz": self.fs_sim_hz, "decimation": self.decimation,
                "preroll_s": self.config.preroll_s, "margin_s": self.config.margin_s,
                "weights": dict(zip(self.dataset.sensors, self.weights.tolist(), strict=True)),
                "sections": [s.label() for s in self.sections],
                "lags_s": list(self.lags_s), "track_offset_m": self.offset_m}

