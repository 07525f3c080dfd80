"""Synthetic "measured" runs: a (perturbed) model driven by a known track, plus sensor noise.

The truth is simulated ``oversample`` times faster than the recording rate (2 kHz for a
200 Hz recording), then decimated with a zero-phase anti-alias FIR filter, as an
accelerometer's front end would, and white sensor noise of the paper's variances
(``gateway.model.vehicle.SENSOR_NOISE_VAR``) is added at the recording rate. The
identification simulates at its own, lower rate, so the two discretisations differ.
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
from gateway.identify.track import Track, jointed_track, random_track, wheel_alignment
from gateway.model.vehicle import SENSOR_NOISE_VAR, SENSORS_5


@dataclass(frozen=True)
class SyntheticSpec:
    """How to record a synthetic run.

    ``shift_samples`` > 0 delays the measurement: ``measured[k] = truth[k - shift]``.
    ``noise_scale`` multiplies the paper's sensor-noise standard deviations.
    """

    duration_s: float
    fs_hz: float
    speed_mps: float
    offset_m: float
    sensors: tuple[str, ...] = SENSORS_5
    shift_samples: int = 0
    noise_scale: float = 1.0
    oversample: int = 10
    preroll_s: float = 10.0


def record(truth: ParamPoint, track: Track, spec: SyntheticSpec,
           rng: np.random.Generator) -> Dataset:
    """Simulate the truth over the track and return the noisy measured Dataset."""
    if not (spec.duration_s > 0 and spec.fs_hz > 0 and spec.speed_mps > 0
            and spec.oversample >= 1 and spec.noise_scale >= 0):
        raise InputError(f"expected positive duration, rate, speed and oversampling, got {spec}")
    n = int(round(spec.duration_s * spec.fs_hz))
    n_pre = int(math.ceil(spec.preroll_s * spec.fs_hz)) + max(spec.shift_samples, 0)
    n_post = max(-spec.shift_samples, 0) + 64
    q = int(spec.oversample)
    fs_fine = spec.fs_hz * q
    # fine grid from -n_pre to n + n_post recording samples, one extra point for the input
    j = np.arange(-(n_pre * q), (n + n_post) * q + 1)
    t_fine = j / fs_fine
    x = spec.offset_m + spec.speed_mps * t_fine
    wheels = wheel_alignment(track, x, truth.as_dict()["a_m"])
    y_fine = forced_response(truth, spec.sensors, spec.speed_mps, 1.0 / fs_fine, wheels)
    y = scipy.signal.decimate(y_fine, q, ftype="fir", zero_phase=True, axis=0) if q > 1 \
        else y_fine
    k = np.arange(n) + n_pre - spec.shift_samples     # y[i] is at time (i - n_pre) / fs
    clean = y[k]
    std = np.sqrt([SENSOR_NOISE_VAR[s] for s in spec.sensors]) * spec.noise_scale
    measured = clean + rng.standard_normal(clean.shape) * std
    t = np.arange(n) / spec.fs_hz
    return Dataset(t_s=t, measured=measured, sensors=tuple(spec.sensors),
                   speed_mps=np.full(n, float(spec.speed_mps)), fs_hz=float(spec.fs_hz),
                   source="synthetic")


DEMO_PERTURBATION: dict[str, float] = {
    "kx_n_per_m": 1.25, "f11_n": 0.75, "conicity": 1.28, "csay_ns_per_m": 0.78, "mbd_kg": 1.20,
}
"""The known perturbation of the acceptance test: five parameters by 20-28 %."""


@dataclass(frozen=True)
class DemoCase:
    """A ready-made synthetic identification problem with its truth."""

    dataset: Dataset
    track: Track
    truth: ParamPoint
    offset_m: float
    sections: tuple[tuple[float, float], ...]


TRACK_KINDS: tuple[str, ...] = ("random", "jointed")
"""Tracks :func:`demo_track` makes."""


def demo_track(kind: str, length_m: float, rms_m: float, rng: np.random.Generator) -> Track:
    """A 0.05 m grid track of ``length_m`` (m) for synthetic runs.

    ``random``: IRIS-band random alignment of ``rms_m`` (m RMS). ``jointed``: 25 m rails
    with a ``rms_m`` (m) cusp at each joint (1 m decay) and a random alignment of
    ``rms_m / 3`` RMS (3 mm cusps and 1 mm random for the default 3 mm).
    """
    if kind == "random":
        return random_track(length_m, 0.05, rms_m, rng)
    if kind == "jointed":
        return jointed_track(length_m, 0.05, rng, cusp_m=rms_m, random_rms_m=rms_m / 3.0)
    raise InputError(f"expected a track kind from {list(TRACK_KINDS)}, got {kind!r}")


def demo_case(seed: int, section_s: float = 15.0, track_rms_m: float = 3e-3,
              shift_samples: int = 0, noise_scale: float = 1.0,
              perturbation: dict[str, float] | None = None,
              track_kind: str = "random") -> DemoCase:
    """Two learn sections of ``section_s`` at 42.5 m/s, 200 Hz, 5 sensors.

    ``track_kind`` and ``track_rms_m`` (m) as in :func:`demo_track`; the track runs 10 s
    of travel past the end of the recording, and from position 0 m, 500 m before the
    leading wheelset's position at the first sample.
    """
    rng = np.random.default_rng(seed)
    offset_m = 500.0
    duration_s = 2 * section_s + 8.0
    track = demo_track(track_kind, offset_m + 42.5 * (duration_s + 10.0), track_rms_m, rng)
    truth = ParamPoint.nominal().scaled(perturbation or DEMO_PERTURBATION)
    spec = SyntheticSpec(duration_s=duration_s, fs_hz=200.0, speed_mps=42.5, offset_m=offset_m,
                         shift_samples=shift_samples, noise_scale=noise_scale)
    ds = record(truth, track, spec, rng)
    sections = ((2.0, 2.0 + section_s), (6.0 + section_s, 6.0 + 2 * section_s))
    return DemoCase(ds, track, truth, offset_m, sections)
