"""The service's filter as the studies build it, with a study's overrides, and its run.

:func:`service_filter` builds the filter the service builds from its default
``[estimator]`` settings (:func:`gateway.runtime.pipeline.build_estimator`: fast mode,
m = 1000, the drift, the innovation monitor, the fault bank, the sensor-noise test, the
start's likelihood ramp), then applies the overrides of a :class:`FilterOptions` record;
:func:`run` feeds it a record (T, ny) at 1 kHz and collects the estimates and the fault
bank's detections; :func:`filter_columns` names the filter's settings in a study's rows.
The detection, calibration, Monte Carlo, grid-posterior and oracle studies share them.
A measuring tool, not used by the service.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from firmware_sim.scenarios import V_PAPER
from gateway.config import DOMAINS, EstimatorConfig, Range
from gateway.errors import EstimatorError, InputError
from gateway.estimator.faultbank import FaultBankConfig
from gateway.estimator.noisestart import NoiseCheckedStart
from gateway.estimator.rbpf import RBPF
from gateway.estimator.rbpf_config import RBPFConfig
from gateway.records import Estimate, Sample
from gateway.runtime.pipeline import build_estimator

FS_HZ = 1000.0
"""The studies' grid rate, Hz."""
V_MPS = V_PAPER
"""The studies' default constant speed, m/s (the paper's Sec. 4.2)."""

Filter = RBPF | NoiseCheckedStart
"""The service's filter: the RBPF, in its sensor-noise test or not."""

Found = tuple[float, str, float, float]
"""A change the fault bank found, as :meth:`gateway.estimator.rbpf.RBPF.last_fault` gives
it: decision time (s), parameter name, located value relative to nominal, confirmation
time (s)."""

_RBPF_OVERRIDES = ("moves_drop_null", "start_ramp_s", "start_ramp_m", "prior_lo",
                   "fast_warmup_s", "gain_fit")
_BANK_OVERRIDES = ("locate_min_s", "locate_max_s", "replay_s", "replay_cov_scale",
                   "redraw_from", "refine_s", "runner_up", "runner_by", "located_by")


def kernel_delta_problem(value: float) -> str | None:
    """Why ``value`` is no value of the service's ``[estimator] kernel_delta`` (its
    configuration domain), or None."""
    domain = DOMAINS[("estimator", "kernel_delta")]
    assert isinstance(domain, Range)
    return domain.problem(value)


@dataclass(frozen=True)
class FilterOptions:
    """A study's filter: the service's, with these overrides (None: the service's own).

    ``particles``, ``mode`` (``"fast"`` or ``"exact"``) and ``sensor_noise``
    (``"measured"``: tested against the data, the service's default; ``"model"``) are
    the service's ``[estimator]`` settings; ``kernel_delta`` too (with its floor).
    ``moves_drop_null``, ``start_ramp_s``, ``start_ramp_m`` and ``prior_lo`` (the prior
    box's lower edges, e.g. the paper's (0.3, 0.3, 0.3) where the service's filter, from
    500 particles on, takes (0.1, 0.1, 0.3)) and ``fast_warmup_s`` (fast mode's exact
    warm-up, s; 2 s before 2026-11-30's sixteenth session) and ``gain_fit`` (False: every
    particle's steady gains solved at a move, as before 2026-12-01) override those options of the
    filter (:class:`gateway.estimator.rbpf_config.RBPFConfig`, which checks them, as the
    bank's below); ``locate_min_s``,
    ``locate_max_s``, ``replay_s``, ``replay_cov_scale``, ``redraw_from``,
    ``refine_s``, ``runner_up``, ``runner_by`` and ``located_by`` those of its fault bank
    (:class:`gateway.estimator.faultbank.FaultBankConfig`, which checks them: a bad
    value raises :class:`gateway.errors.InputError` here, before any run).
    """

    particles: int = 1000
    mode: str = "fast"
    sensor_noise: str = "measured"
    kernel_delta: float | None = None
    moves_drop_null: bool | None = None
    start_ramp_s: float | None = None
    start_ramp_m: float | None = None
    prior_lo: tuple[float, float, float] | None = None
    fast_warmup_s: float | None = None
    gain_fit: bool | None = None
    locate_min_s: float | None = None
    locate_max_s: float | None = None
    replay_s: float | None = None
    replay_cov_scale: float | None = None
    redraw_from: str | None = None
    refine_s: float | None = None
    runner_up: bool | None = None
    runner_by: str | None = None
    located_by: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("fast", "exact"):
            raise InputError(f"expected mode 'fast' or 'exact', got {self.mode!r}")
        if self.sensor_noise not in ("measured", "model"):
            raise InputError(f"expected sensor_noise 'measured' or 'model', got "
                             f"{self.sensor_noise!r}")
        if not self.particles >= 1:
            raise InputError(f"expected at least 1 particle, got {self.particles}")
        try:
            RBPFConfig(fs_hz=FS_HZ, **self.given(_RBPF_OVERRIDES))
        except EstimatorError as exc:
            raise InputError(f"filter option: {exc}") from None
        if self.kernel_delta is not None:
            problem = kernel_delta_problem(self.kernel_delta)
            if problem is not None:
                raise InputError(f"kernel delta: {problem}")
        try:
            replace(FaultBankConfig(), **self.given(_BANK_OVERRIDES))
        except EstimatorError as exc:
            raise InputError(f"fault bank option: {exc}") from None

    def given(self, names: tuple[str, ...]) -> dict[str, Any]:
        """The options of ``names`` that override the service's (not None), by name."""
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}


def service_filter(sensors: int, seed: int, options: FilterOptions | None = None) -> Filter:
    """The filter the service builds from its defaults for ``sensors`` and filter seed
    ``seed``, with ``options``' overrides (None: none)."""
    options = options or FilterOptions()
    cfg = replace(EstimatorConfig(), sensors=sensors, seed=seed, particles=options.particles,
                  mode=options.mode, sensor_noise=options.sensor_noise)
    if options.kernel_delta is not None:
        cfg = replace(cfg, kernel_delta=options.kernel_delta)
    filt = build_estimator(cfg, FS_HZ)
    assert isinstance(filt, (RBPF, NoiseCheckedStart))
    rbpf = replace(filt.config, **options.given(_RBPF_OVERRIDES))
    bank = options.given(_BANK_OVERRIDES)
    if rbpf.faults is not None and bank:
        rbpf = replace(rbpf, faults=replace(rbpf.faults, **bank))
    if rbpf == filt.config:
        return filt
    return NoiseCheckedStart(rbpf) if isinstance(filt, NoiseCheckedStart) else RBPF(rbpf)


def run(Y: np.ndarray, filt: Filter, every: int = 100, held: np.ndarray | None = None,
        speed_mps: float = V_MPS, replaced: list[Found] | None = None
        ) -> tuple[list[Estimate], list[Found], Filter]:
    """Estimates every ``every`` samples and the bank's detections on ``Y`` (T, ny)
    recorded at ``FS_HZ`` and ``speed_mps``; samples where ``held`` (T,) is True come
    without an update, as the gate sends them in a curve.

    The detections are the surviving filter's. Where the sensor-noise test replaces the
    filter (:mod:`gateway.estimator.noisestart`: another variance, the kept samples
    replayed), what the replaced filter found goes with it, into ``replaced`` if given:
    its estimates were provisional, so no alert came of them. (Until 2026-11-29's ninth
    session they stayed in the list, and the replacement's count started below them, so
    its first detection was not collected: seed 5334, 2 x noise, 3 sensors.)"""
    found: list[Found] = []
    gone = replaced if replaced is not None else []
    owner, seen = _inner(filt), 0

    def collect() -> None:
        nonlocal owner, seen
        if _inner(filt) is not owner:
            owner, seen = _inner(filt), 0
            gone.extend(found)
            found.clear()
        if filt.n_fault_detections > seen:
            seen = filt.n_fault_detections
            found.append(_last(filt))

    def samples() -> Iterator[Sample]:
        for k in range(len(Y)):
            collect()
            yield Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=speed_mps,
                         update=held is None or not held[k])

    est = filt.run(samples(), output_every=every)
    collect()
    return est, found, filt


def _inner(filt: Filter) -> RBPF:
    """The RBPF that runs now (inside the noise test, which may replace it)."""
    return filt.inner if isinstance(filt, NoiseCheckedStart) else filt


def _last(filt: Filter) -> Found:
    last = filt.last_fault()
    assert last is not None
    return last


def filter_columns(filt: Filter) -> dict[str, Any]:
    """The filter's settings as a study's row columns: its sensor-noise test's outcome
    (the variances used relative to the model's), ``moves_drop_null``, ``fast_warmup_s``,
    ``gain_fit``,
    the fault bank's location settings (None: no bank) and the kernel's delta."""
    res = filt.result if isinstance(filt, NoiseCheckedStart) else None
    bank = filt.config.faults
    return {"sensor_noise": "measured" if isinstance(filt, NoiseCheckedStart) else "model",
            "noise_used_rel": None if res is None else [
                round(u / m, 3) for u, m in zip(res.used_var, res.model_var, strict=True)],
            "moves_drop_null": filt.config.moves_drop_null,
            "fast_warmup_s": filt.config.fast_warmup_s,
            "gain_fit": filt.config.gain_fit,
            **{name: None if bank is None else getattr(bank, name)
               for name in ("redraw_from", "locate_min_s", "locate_s", "locate_max_s",
                            "replay_s", "replay_cov_scale", "refine_s", "runner_up",
                            "runner_by", "located_by")},
            "kernel_delta": filt.config.delta}
