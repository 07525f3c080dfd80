"""The frozen records and protocols crossing stage boundaries: samples in, estimates out.

Data flows one way::

    can.Message -> DecodedFrame (decoded by can/codec) -> Sample (resampler) -> Estimate (estimator)
    -> Alert (alert policy) -> sinks

Every stage imports these records, never a sibling stage.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from gateway.model.vehicle import PARAM_NAMES


@dataclass(frozen=True)
class Sample:
    """One point of the fixed-rate grid.

    ``values`` (ny,): measurements in the estimator's sensor-set order, SI units; NaN
    marks a sensor with no valid value at this point (gap or rejected frame).
    ``update`` False means "predict only" (gated: outside the speed window, in a curve,
    or a gap). ``speed_mps`` is the vehicle speed at this point.
    """

    t_s: float
    values: np.ndarray
    speed_mps: float
    update: bool = True


@dataclass(frozen=True)
class Located:
    """A change the estimator's fault bank decided (:mod:`gateway.estimator.faultbank`)
    at data time ``t_s``: ``parameter`` (a :data:`PARAM_NAMES` name), its located value
    ``rel`` and its redraw range ``rel_lo``..``rel_hi`` (three location-grid steps either
    side: :meth:`gateway.estimator.faultbank.FaultBank.redraw_range`), and its likelihood
    interval ``like_lo``..``like_hi`` (the values whose summed log-likelihood the
    location found within 8 nats, 4 sigma, of the located one's:
    :meth:`gateway.estimator.faultbank.FaultBank.likely_range`; 0 or inf where it is
    open), all relative to nominal. The bank's CUSUM crossed its threshold and the
    location beat the old value by half that, so the alert policy may act on it at once
    where the whole likelihood interval is past a threshold (docs/alerts.md, "Located
    changes")."""

    t_s: float
    parameter: str
    rel: float
    rel_lo: float
    rel_hi: float
    like_lo: float
    like_hi: float


@dataclass(frozen=True)
class Estimate:
    """Posterior summary at data time ``t_s``.

    ``mean`` and ``std`` are in :data:`gateway.model.vehicle.PARAM_NAMES` order (N s/m, N s/m, -),
    plus Ar (paper units) as a 4th entry when it is estimated jointly.
    ``ess`` is the effective sample size; ``v_sy_mps``/``v_say_mps`` are the damper
    operating velocities from the state estimates (paper Figs. 9-10). ``provisional``:
    the estimator is still testing its model against the data (the first 2-5 s of the
    sensor-noise test, :mod:`gateway.estimator.noisestart`); the alert policy does not
    judge it, and the estimate frame says Converging at best. ``located``: the fault
    bank's latest change while it is recent (up to 2 s of data after its decision;
    the same record on each of those estimates), or None. ``left_out``: the sensors the
    filters left out for this estimate, having had no values (a dead node,
    :mod:`gateway.estimator.sensormask`), in sensor-set order; empty when every sensor
    was used or the producer does not say. What only those sensors show (with the body
    node out, most of Csy) is then not in ``mean`` and ``std``. ``unresolved``: the
    parameters (of ``names``) the sensors in use cannot resolve
    (:mod:`gateway.estimator.observability`: their Cramér-Rao bound over 5 s of data is
    above 6.25 % at the nominal and this speed band), e.g. Csy with the body node out of
    a 3-sensor set; their ``mean`` is mostly what the filters knew before; empty when
    every parameter is resolved or the producer does not say.
    """

    t_s: float
    mean: tuple[float, ...]
    std: tuple[float, ...]
    ess: float
    v_sy_mps: float = float("nan")
    v_say_mps: float = float("nan")
    updated: bool = True
    names: tuple[str, ...] = field(default=PARAM_NAMES)
    provisional: bool = False
    located: Located | None = None
    left_out: tuple[str, ...] = ()
    unresolved: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{name: {"mean": m, "std": s}}`` for each parameter."""
        return {n: {"mean": m, "std": s}
                for n, m, s in zip(self.names, self.mean, self.std, strict=True)}


@dataclass(frozen=True)
class NoiseCheck:
    """The estimator's test of its sensor-noise variances against the data
    (:mod:`gateway.estimator.noisestart`), per sensor (tuples in sensor-set order):
    ``model_var`` assumed at the start (SI units^2); ``band_var`` the data's white-noise
    variance in the band above the vehicle's dynamics, less ``signal_var``, the model's
    own signal there; ``se_rel`` the test's relative standard error; ``used_var`` what
    the filter uses from now on; ``replaced`` which sensors changed; ``t_s`` data time of
    the test; ``note`` why nothing could be measured, or ''."""

    sensors: tuple[str, ...]
    model_var: tuple[float, ...]
    band_var: tuple[float, ...]
    signal_var: tuple[float, ...]
    se_rel: tuple[float, ...]
    used_var: tuple[float, ...]
    replaced: tuple[bool, ...]
    t_s: float
    note: str = ""

    def as_dict(self) -> dict[str, object]:
        """JSON-able: one entry per sensor, and the test's time and note."""
        def num(x: float) -> float | None:
            return x if math.isfinite(x) else None   # strict JSON

        per = {s: {"model_var": m, "band_var": num(b), "signal_var": num(g), "se_rel": num(e),
                   "used_var": u, "replaced": r}
               for s, m, b, g, e, u, r in zip(self.sensors, self.model_var, self.band_var,
                                               self.signal_var, self.se_rel, self.used_var,
                                               self.replaced, strict=True)}
        return {"t_s": self.t_s, "note": self.note, "sensors": per}

    def summary(self) -> str:
        """One line for the log and the console."""
        if self.note:
            return f"sensor noise not measured ({self.note}); the model's is kept"
        changed = [f"{s} {u / m:.2f} x" for s, u, m, r in zip(
            self.sensors, self.used_var, self.model_var, self.replaced, strict=True) if r]
        if not changed:
            return "sensor noise agrees with the model"
        return "sensor noise measured, the model's replaced: " + ", ".join(changed) + \
            " (variance)"


class Estimator(Protocol):
    """An online estimator: samples on the grid in, estimates out; its whole state
    checkpoints to bytes. What the worker process (:mod:`gateway.runtime.worker`) calls;
    :class:`gateway.estimator.rbpf.RBPF` is one."""

    def reset(self, rng: np.random.Generator) -> None:
        """Start again from the prior, drawing from ``rng``."""

    def step(self, sample: Sample) -> Estimate:
        """Consume one grid sample and return the posterior after it."""

    def advance(self, sample: Sample) -> None:
        """Consume one grid sample like :meth:`step`, without summarising the posterior
        (the same evolution; for the samples between two outputs)."""

    def run(self, samples: Iterable[Sample], output_every: int | None = None
            ) -> list[Estimate]:
        """Consume samples in order (the same evolution as :meth:`step` on each);
        returns the posterior after every ``output_every``-th sample and after the last."""

    def checkpoint(self) -> bytes:
        """The full state as bytes; :meth:`restore` continues exactly from here."""

    @classmethod
    def restore(cls, blob: bytes) -> Estimator:
        """An estimator that continues exactly where :meth:`checkpoint` left off (the
        worker is given a picklable restorer callable that calls it)."""

    def restart_filters(self) -> None:
        """After a long gap in the data: restart the state filters, keep what has been
        learnt about the parameters."""

    def reset_parameter(self, index: int) -> None:
        """Baseline reset: parameter ``index`` (``PARAM_NAMES`` order) re-learns from
        its prior, the others keep what they learnt."""

    def noise_check(self) -> NoiseCheck | None:
        """The outcome of the sensor-noise test once made; None before it, or when the
        estimator makes none."""


class Sink(Protocol):
    """Where estimates and alert events go (CAN frames, the log, JSON Lines): ``emit``
    each record in order; ``close`` releases the sink and is idempotent."""

    def emit(self, record: Estimate | Alert) -> None:
        """Take one estimate or alert event; a sink ignores the kinds it does not carry."""

    def close(self) -> None:
        """Release what the sink holds; idempotent."""


class Quality(enum.IntEnum):
    """Per-sensor quality flag of a grid sample."""

    OK = 0
    MISSING = 1
    """No frame covered this grid point (gap, timeout, dropped or rejected frames)."""
    NOT_AVAILABLE = 2
    """The node sent its NotAvailable value."""
    SUSPECT = 3
    """Delivered, but flagged by validation (e.g. stuck value, counter trouble)."""


@dataclass(frozen=True)
class GridSample:
    """One point of the resampler's fixed-rate grid, all sensors.

    ``values`` (5,) in SENSORS_5 order (acc_w1, acc_w2, acc_b, gyro_b, acc_bd), SI units,
    NaN unless ``quality`` is OK or SUSPECT; ``quality`` (5,) of :class:`Quality` ints;
    ``speed_mps`` NaN when unknown; ``yaw_rate_lp_radps`` the low-passed bogie yaw rate
    used for curve gating.
    """

    t_s: float
    values: np.ndarray
    quality: np.ndarray
    speed_mps: float
    yaw_rate_lp_radps: float = float("nan")


class Severity(enum.IntEnum):
    """Alert severities, in increasing order (values as on the CAN bus)."""

    ADVISORY = 1
    WARNING = 2
    ALARM = 3


class AlertState(enum.IntEnum):
    """Alert lifecycle states (values as on the CAN bus)."""

    RAISED = 0
    CLEARED = 1
    ACKNOWLEDGED = 2


@dataclass(frozen=True)
class Alert:
    """An alert event: raised, cleared or acknowledged, for one parameter.

    ``t_s`` is data time; ``value_rel`` the estimate relative to nominal at that time;
    ``seq`` a sequence number unique over the gateway's life (persisted).
    """

    seq: int
    t_s: float
    parameter: str
    severity: Severity
    state: AlertState
    code: int
    value_rel: float
    message: str = ""


@dataclass(frozen=True)
class DecodedFrame:
    """One validated frame. ``values`` holds physical values of the data signals (DBC
    units, float); NotAvailable is NaN. CRC, counter and sample index are separate
    fields; ``sample_idx`` is None for messages without one (gateway outputs)."""

    message: str
    arbitration_id: int
    counter: int
    sample_idx: int | None
    values: dict[str, float]
    timestamp_s: float

    @property
    def not_available(self) -> frozenset[str]:
        """Names of the signals that were NotAvailable in this frame."""
        return frozenset(k for k, v in self.values.items() if math.isnan(v))
