"""Configuration of the RBPF estimator: one frozen, validated dataclass."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gateway.errors import EstimatorError
from gateway.estimator.faultbank import FaultBankConfig
from gateway.estimator.monitor import MonitorConfig
from gateway.estimator.particles import jitter_var
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    PARAM_NAMES,
    THETA_NOMINAL,
    Theta,
    VehicleParams,
    measurement_noise,
    sensor_set,
)

MODES = ("exact", "fast")
"""Estimator modes: the exact recursion (reference) and steady-state gains (fast)."""
AR_NAME = "ar_paper"
"""Name of the optional 4th parameter (Ar in the paper's printed units)."""
PAPER_DELTA = 0.99
"""The paper's Liu-West discount per sample."""
PAPER_FLOOR_REL = 1e-3
"""The paper's roughening-std floor per sample, a fraction of nominal (at PAPER_DELTA)."""


AUTO_DELTA = 0.999
"""The kernel discount ``[estimator] kernel_delta = 0`` (auto) takes from
:data:`AUTO_DELTA_MIN_PARTICLES` particles on (docs/estimator.md "The kernel's discount
and the Monte Carlo error")."""
AUTO_DELTA_MIN_PARTICLES = 250
"""Below this many particles auto takes the paper's discount: a kernel that re-draws
less needs enough particles to stay diverse (measured: at m = 64, 0.999 was far worse
than 0.99; at m = 250 and 1000 better; between 64 and 250 not measured)."""


def kernel_delta_for(configured: float, particles: int) -> float:
    """The Liu-West discount the service's filter runs with: ``configured``, or for 0
    (auto) :data:`AUTO_DELTA` from :data:`AUTO_DELTA_MIN_PARTICLES` particles on and the
    paper's below."""
    if configured != 0.0:
        return configured
    return AUTO_DELTA if particles >= AUTO_DELTA_MIN_PARTICLES else PAPER_DELTA


PAPER_PRIOR_LO = (0.3, 0.3, 0.3)
"""The paper's prior box's lower edges (x nominal: Csy, Csay, lambda): the bare filter's."""
WIDE_PRIOR_LO = (0.1, 0.1, PAPER_PRIOR_LO[2])
"""The lower edges (x nominal: Csy, Csay, lambda) of the service's prior box from
:data:`WIDE_PRIOR_MIN_PARTICLES` particles on: the dampers from 0.1 instead of the
paper's 0.3, so that a fresh filter on a vehicle whose damper failed before it started
has particles near the truth (docs/estimator.md "The thirteenth session")."""
WIDE_PRIOR_MIN_PARTICLES = 500
"""Below this many particles the service's filter keeps the paper's box (0.3 x for the
dampers): with few particles a first draw over the wider box is sparser. Measured on the
same 30 sets over the paper's box, 3 and 5 sensors, 10 s (seeds 6430-6459), the wider
box left a parameter beyond 4 sigma in 2 of 60 runs at m = 100 (16.9 and 6.9 sigma;
none with the paper's box), and the fault bank fired on 5 healthy records (none); at
m = 250 on one (none); at m = 500 and 1000 nothing measured was worse."""


def prior_lo_for(particles: int) -> tuple[float, float, float]:
    """The lower edges of the prior box the service's filter draws its first particles
    from: :data:`WIDE_PRIOR_LO` from :data:`WIDE_PRIOR_MIN_PARTICLES` particles on,
    :data:`PAPER_PRIOR_LO` below."""
    return WIDE_PRIOR_LO if particles >= WIDE_PRIOR_MIN_PARTICLES else PAPER_PRIOR_LO


def floor_for_delta(delta: float) -> float:
    """The per-sample roughening floor at Liu-West ``delta`` that keeps the paper's floor
    on the cloud's spread.

    The kernel holds a particle cloud with no information at a spread of about
    ``floor / h`` (``h^2 = 1 - a^2``, ``a`` the shrinkage): 0.1 % / 0.1 = about 1 % of
    nominal at the paper's delta. A larger delta has a smaller h, so it takes a floor
    smaller by ``h(delta) / h(0.99)`` (0.315 at delta 0.999) for the same 1 %.
    """
    if not 0.0 < delta < 1.0:
        raise EstimatorError(f"expected 0 < delta < 1, got {delta}")
    return float(PAPER_FLOOR_REL * (jitter_var(delta) / jitter_var(PAPER_DELTA)) ** 0.5)


@dataclass(frozen=True)
class RBPFConfig:
    """Settings of the estimator. Factors are relative to ``nominal`` (and ``ar_paper``).

    ``prior_*``: uniform initial box (paper: 0.3-2.5 x for dampers, 0.3-3.5 x for lambda;
    the service's filter takes its lower edges from :func:`prior_lo_for`);
    ``support_*``: hard bounds particles may never leave (log-space clip);
    ``reseed_*``: log-uniform box for particles re-drawn after a detected change;
    ``ar_prior``: log-uniform factor range on Ar when ``estimate_ar``;
    ``ess_threshold``: resample when the effective sample size falls below this
    fraction of m (0.2: each resample-move is an approximation, and at 0.5 the fast
    start-up contraction made ~3x as many; docs/estimator.md "Start-up lock-in");
    ``floor_rel``/``floor_reference``: roughening-std floor, a fraction of the nominal
    value (default) or of the parameter's own value;
    ``walk_rel_per_sqrt_s``: random-walk evolution of each parameter, relative std per
    square root of second of updated data (0: a static parameter, as in the paper;
    Ar, when estimated, stays static);
    ``output_every``: default decimation of :meth:`RBPF.run` (one estimate per that many
    samples; :meth:`RBPF.step` always returns one);
    ``mode``: ``"exact"`` (every particle runs the exact Kalman recursion; the reference)
    or ``"fast"`` (steady-state gains per particle from a DARE solve at each move or
    speed-band change, :mod:`gateway.estimator.steady`; the product's default);
    ``fast_warmup_s``: in fast mode, the exact recursion runs this long after every
    filter start (the prior's large P converges the states quickly; the steady gains
    alone would take the slow mode's 8 s time constant) and after a hold; 0.5 s since
    2026-11-30's sixteenth session (2 s before): the same accuracy against the truth,
    calibration and detection on fresh paired campaigns at 1.4 times the whole-run
    speed; fast and exact mode then part at 0.5 s (docs/estimator.md "Start of every
    filter", "The sixteenth session");
    ``gain_fit``: in fast mode, a resample-move in the steady phase solves a few
    particles' steady filters and fits the rest over the cloud where the fit holds to
    1e-3 (:mod:`gateway.estimator.gainfit`; docs/estimator.md "The twenty-second
    session"); False solves every particle's (the path before 2026-12-01, which the
    single-record tests found on it keep);
    ``moves_drop_null``: a moved particle keeps its ancestor's state less the component
    along the ancestor's static-yaw null vector (:func:`gateway.estimator.steady.without_null`);
    on by default since 2026-11-25 (docs/estimator.md "Calibration of the stated sigma": it
    removes the 5 s outliers; the fast-vs-exact, drift, accuracy, detection and
    start-up campaigns were re-measured with it); False keeps the state whole;
    ``start_ramp_s``: after every filter start, the particles' log-likelihoods are scaled
    by a weight rising linearly from 0 to 1 over this much data (s of samples with data):
    the first samples, whose likelihood rests on the assumed state level at the start
    (a running vehicle's), count less, and the data's information enters at a rate the
    resample-moves can follow; 0 (default, the paper) weighs every sample fully; the
    service uses 1 s (:class:`gateway.config.EstimatorConfig`; docs/estimator.md
    "Calibration of the stated sigma");
    ``start_ramp_m``: the same ramp lasts at least this much track (m), at the speed of
    the first data after the filter start: ``max(start_ramp_s, start_ramp_m / v)``
    (checkpointed once set). The kinematic mode, which
    carries most of λ's information, has a fixed wavelength, so a ramp in seconds covers
    fewer of its cycles at low speed; 0 (default) keeps the ramp in seconds alone; the
    service uses 42.5 m, 1 s at the paper's speed (docs/estimator.md "The start's ramp
    in track distance");
    ``noise_var``: the sensors' white-noise variances (SI units^2, in sensor-set order);
    None: the paper's Qv (:func:`gateway.model.vehicle.measurement_noise`). The service
    measures them at the start of a run (:mod:`gateway.estimator.noisestart`);
    ``noise_tested``: those variances were tested against the data (set by the test,
    whatever it found; the filter never reads it): a restart under ``sensor_noise =
    "measured"`` resumes only a tested filter
    (:func:`gateway.runtime.pipeline.checkpoint_mismatch`);
    ``faults``: the fault-hypothesis bank that detects abrupt changes
    (:mod:`gateway.estimator.faultbank`; None: none);
    ``threads``: numba threads wanted for the kernels (None: all); the process sets them
    once (:func:`gateway.estimator.threads.kernel_threads`: 1 below 16 chunks, where the
    thread hand-off costs more than it saves); the filter never changes numba's globals.
    """

    fs_hz: float
    n_particles: int = 1000
    delta: float = PAPER_DELTA
    ess_threshold: float = 0.2
    sensors: int = 3
    ar_paper: float = AR_PAPER_DEFAULT
    estimate_ar: bool = False
    seed: int | None = 0
    prior_lo: tuple[float, float, float] = PAPER_PRIOR_LO
    prior_hi: tuple[float, float, float] = (2.5, 2.5, 3.5)
    support_lo: tuple[float, float, float] = (0.05, 0.05, 0.05)
    support_hi: tuple[float, float, float] = (10.0, 10.0, 10.0)
    reseed_lo: tuple[float, float, float] = (0.1, 0.1, 0.3)
    reseed_hi: tuple[float, float, float] = (2.5, 2.5, 3.5)
    reseed_fraction: float = 0.5
    ar_prior: tuple[float, float] = (0.25, 4.0)
    floor_rel: float = PAPER_FLOOR_REL
    walk_rel_per_sqrt_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    floor_reference: str = "nominal"
    speed_tol: float = 2e-3
    threads: int | None = None
    mode: str = "exact"
    fast_warmup_s: float = 0.5
    gain_fit: bool = True
    output_every: int = 1
    moves_drop_null: bool = True
    start_ramp_s: float = 0.0
    start_ramp_m: float = 0.0
    resample: bool = True
    noise_var: tuple[float, ...] | None = None
    noise_tested: bool = False
    monitor: MonitorConfig | None = field(default_factory=MonitorConfig)
    faults: FaultBankConfig | None = field(default_factory=FaultBankConfig)
    nominal: Theta = THETA_NOMINAL
    params: VehicleParams = field(default_factory=VehicleParams)

    def __post_init__(self) -> None:
        if not (self.fs_hz > 0 and np.isfinite(self.fs_hz)):
            raise EstimatorError(f"expected a positive sample rate, got {self.fs_hz} Hz")
        if self.n_particles < 2:
            raise EstimatorError(f"expected at least 2 particles, got {self.n_particles}")
        if not 0.0 < self.delta < 1.0:
            raise EstimatorError(f"expected 0 < delta < 1, got {self.delta}")
        names = sensor_set(self.sensors)
        if self.noise_var is not None and (
                len(self.noise_var) != len(names)
                or not all(np.isfinite(v) and v > 0 for v in self.noise_var)):
            raise EstimatorError(f"expected {len(names)} positive noise variances for "
                                 f"{names}, got {self.noise_var}")
        if not 0.0 <= self.start_ramp_s <= 60.0:
            raise EstimatorError(f"expected start_ramp_s in [0, 60] s, got "
                                 f"{self.start_ramp_s}")
        if not 0.0 <= self.start_ramp_m <= 1000.0:
            raise EstimatorError(f"expected start_ramp_m in [0, 1000] m, got "
                                 f"{self.start_ramp_m}")
        if not 0.0 <= self.fast_warmup_s <= 60.0:
            raise EstimatorError(f"expected fast_warmup_s in [0, 60] s, got "
                                 f"{self.fast_warmup_s}")
        if self.mode not in MODES:
            raise EstimatorError(f"expected mode 'exact' or 'fast', got {self.mode!r}")
        if self.floor_reference not in ("nominal", "value"):
            raise EstimatorError(f"expected floor_reference 'nominal' or 'value', got "
                                 f"{self.floor_reference!r}")
        if len(self.walk_rel_per_sqrt_s) != 3 or not all(
                0.0 <= w < 1.0 for w in self.walk_rel_per_sqrt_s):
            raise EstimatorError(f"expected three random-walk rates in [0, 1) per sqrt(s), "
                                 f"got {self.walk_rel_per_sqrt_s}")
        if not self.ar_paper > 0:
            raise EstimatorError(f"expected a positive track roughness Ar, got {self.ar_paper}")

    @property
    def noise_variances(self) -> np.ndarray:
        """The sensors' noise variances (ny,), SI units^2: ``noise_var`` or the paper's."""
        if self.noise_var is not None:
            return np.array(self.noise_var, dtype=float)
        return np.diag(measurement_noise(self.sensors)).copy()

    @property
    def names(self) -> tuple[str, ...]:
        return PARAM_NAMES + ((AR_NAME,) if self.estimate_ar else ())

    @property
    def nominal_array(self) -> np.ndarray:
        """Nominal values (d,) of the estimated parameters."""
        nom = self.nominal.as_array()
        return np.append(nom, self.ar_paper) if self.estimate_ar else nom

    def box(self, lo: tuple[float, ...], hi: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Absolute bounds (d,), (d,) from factor tuples (Ar uses ``ar_prior``)."""
        lo_a, hi_a = np.array(lo, dtype=float), np.array(hi, dtype=float)
        if self.estimate_ar:
            lo_a, hi_a = np.append(lo_a, self.ar_prior[0]), np.append(hi_a, self.ar_prior[1])
        return lo_a * self.nominal_array, hi_a * self.nominal_array
