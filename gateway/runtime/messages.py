"""The typed messages between the service and its estimator worker process.

Every item on the worker's two queues is one of these frozen dataclasses; the worker
and its link dispatch on the type (``match``), never on a string tag or a method name.
They are module-level dataclasses of plain values and numpy arrays, so they pickle
across the spawn boundary.

Parent -> worker (:data:`Request`), in queue order::

    Start (once) -> SampleBlock | BaselineReset ... -> Stop

Worker -> parent (:data:`Reply`): ``Ready`` once, then ``EstimateOut``,
``CheckpointOut`` and ``Progress`` as data is worked off, ``Stopped`` last. Every
reply carries ``seq``, the last grid sample (counted from 0 since the service started)
the worker had stepped when it sent it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.records import Estimate, NoiseCheck

# ------------------------------------------------------------- parent -> worker


@dataclass(frozen=True)
class Start:
    """The first item a (warm, waiting) worker reads: build a fresh estimator, or
    restore ``checkpoint``, which has seen every sample up to ``checkpoint_seq``."""

    checkpoint: bytes | None
    checkpoint_seq: int


@dataclass(frozen=True, eq=False)
class SampleBlock:
    """Consecutive grid samples ``seq0 ..``; arrays are time-first: ``t_s`` (n,) s,
    ``values`` (n, ny) SI units (NaN = no value), ``speed_mps`` (n,), ``update`` (n,)
    bool."""

    seq0: int
    t_s: np.ndarray
    values: np.ndarray
    speed_mps: np.ndarray
    update: np.ndarray

    @property
    def last_seq(self) -> int:
        return self.seq0 + len(self.t_s) - 1


@dataclass(frozen=True)
class Control:
    """An instruction for the estimator, applied in order between samples: after sample
    ``after_seq`` (-1: before the first). Only its subclasses are sent."""

    after_seq: int

    @property
    def last_seq(self) -> int:
        return self.after_seq


@dataclass(frozen=True)
class BaselineReset(Control):
    """A part was replaced: parameter ``index`` (``PARAM_NAMES`` order) re-learns from
    its prior (:meth:`gateway.records.Estimator.reset_parameter`)."""

    index: int


@dataclass(frozen=True)
class Stop:
    """Checkpoint, answer :class:`Stopped` and exit (a spare that never started exits
    at once)."""


Request = Start | SampleBlock | BaselineReset | Stop
"""Everything the parent puts on a worker's input queue."""

# ------------------------------------------------------------- worker -> parent


@dataclass(frozen=True)
class Ready:
    """The estimator is built (or restored to ``seq``; -1 when fresh).
    ``priority_error`` is "" when the worker lowered its CPU priority, else why not."""

    seq: int
    priority_error: str


@dataclass(frozen=True)
class EstimateOut:
    """The posterior after sample ``seq``."""

    seq: int
    estimate: Estimate


@dataclass(frozen=True)
class CheckpointOut:
    """The estimator's full state after sample ``seq``
    (:meth:`gateway.records.Estimator.checkpoint`)."""

    seq: int
    blob: bytes


@dataclass(frozen=True)
class NoiseOut:
    """The estimator's sensor-noise test, made by sample ``seq`` (sent once per worker)."""

    seq: int
    check: NoiseCheck


@dataclass(frozen=True)
class Progress:
    """Every sample up to ``seq`` is stepped (sent after each block)."""

    seq: int


@dataclass(frozen=True)
class Stopped:
    """The last reply: the worker exits after sample ``seq``."""

    seq: int


Reply = Ready | EstimateOut | CheckpointOut | NoiseOut | Progress | Stopped
"""Everything a worker puts on its output queue."""
