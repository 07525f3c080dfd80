"""The frozen records that cross stage boundaries: samples in, estimates and alerts out.

Data flows one way::

    can.Message -> DecodedFrame (codec) -> Sample (resampler) -> Estimate (estimator)
    -> Alert (alert policy) -> sinks

Every stage imports these records, never a sibling stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from gateway.model import PARAM_NAMES


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
class Estimate:
    """Posterior summary at data time ``t_s``.

    ``mean`` and ``std`` are in :data:`gateway.model.PARAM_NAMES` order (N s/m, N s/m, -),
    plus Ar (paper units) as a 4th entry when it is estimated jointly.
    ``ess`` is the effective sample size; ``v_sy_mps``/``v_say_mps`` are the damper
    operating velocities from the state estimates (paper Figs. 9-10).
    """

    t_s: float
    mean: tuple[float, ...]
    std: tuple[float, ...]
    ess: float
    v_sy_mps: float = float("nan")
    v_say_mps: float = float("nan")
    updated: bool = True
    names: tuple[str, ...] = field(default=PARAM_NAMES)

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{name: {"mean": m, "std": s}}`` for each parameter."""
        return {n: {"mean": m, "std": s}
                for n, m, s in zip(self.names, self.mean, self.std, strict=True)}


class Estimator(Protocol):
    """An online estimator: samples on the grid in, estimates out."""

    def reset(self, rng: np.random.Generator) -> None:
        """Start again from the prior, drawing from ``rng``."""

    def step(self, sample: Sample) -> Estimate:
        """Consume one grid sample and return the posterior after it."""
