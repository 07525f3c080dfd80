"""Evaluate an objective over many parameter vectors on all available cores.

The objective (a picklable callable of a relative vector ``u``, with the track offset
as its last entry when that is free) is sent to each worker process once, at start-up;
afterwards only the vectors travel. ``workers`` defaults
to ``len(os.sched_getaffinity(0))``; with one worker everything runs in-process.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from gateway.errors import InputError
from gateway.estimator.threads import available_cores
from gateway.identify.linalg import one_blas_thread
from gateway.identify.misfit import TrackMisfit
from gateway.identify.params import FreeSpace


class Misfit(Protocol):
    """Anything that maps a parameter point to a scalar misfit."""

    def __call__(self, point: Any) -> float: ...


class Objective:
    """``u (size,) -> J``: the misfit at ``space.point(u)``; ``per_signal`` for screening.

    With a free offset (``space.offset``) the misfit must be a :class:`TrackMisfit`,
    evaluated with the track registered at ``space.offset_m(u)``; the track must cover
    the sections over the whole offset range, which is checked here, once.
    """

    def __init__(self, misfit: Misfit, space: FreeSpace) -> None:
        self.misfit = misfit
        self.space = space
        if space.offset is not None:
            if not isinstance(misfit, TrackMisfit):
                raise InputError(f"expected a known-track misfit for a free track offset, got "
                                 f"{type(misfit).__name__}")
            for v in (-1.0, 1.0):
                misfit.at_offset(space.offset.offset_m(v))

    def _misfit_at(self, u: np.ndarray) -> Misfit:
        offset_m = self.space.offset_m(u)
        if offset_m is None:
            return self.misfit
        assert isinstance(self.misfit, TrackMisfit)
        return self.misfit.at_offset(offset_m)

    def __call__(self, u: np.ndarray) -> float:
        return float(self._misfit_at(u)(self.space.point(u)))

    def per_signal(self, u: np.ndarray) -> np.ndarray:
        """Per-signal misfits (ny,); only for a :class:`TrackMisfit`."""
        misfit = self._misfit_at(u)
        if not isinstance(misfit, TrackMisfit):
            raise TypeError("per-signal misfits need a TrackMisfit")
        return misfit.per_signal(self.space.point(u))


_OBJECTIVE: Objective | None = None


def _init(objective: Objective) -> None:
    global _OBJECTIVE
    _OBJECTIVE = objective
    one_blas_thread()      # for the worker's life: it is one of the cores already


def _value(u: np.ndarray) -> float:
    assert _OBJECTIVE is not None
    return _OBJECTIVE(u)


def _signals(u: np.ndarray) -> np.ndarray:
    assert _OBJECTIVE is not None
    return _OBJECTIVE.per_signal(u)


class Evaluator:
    """A process pool bound to one objective; a context manager, ``close()`` idempotent."""

    def __init__(self, objective: Objective, workers: int | None = None) -> None:
        self.objective = objective
        self.workers = max(1, workers if workers is not None else available_cores())
        self._pool: Any = None
        if self.workers > 1:
            methods = multiprocessing.get_all_start_methods()
            ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
            self._pool = ctx.Pool(self.workers, initializer=_init, initargs=(objective,))

    def values(self, us: Sequence[np.ndarray]) -> list[float]:
        """J at each vector, in order."""
        if self._pool is None:
            return [self.objective(u) for u in us]
        return list(self._pool.map(_value, list(us),
                                   chunksize=max(1, len(us) // (4 * self.workers))))

    def signals(self, us: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Per-signal misfits at each vector, in order."""
        if self._pool is None:
            return [self.objective.per_signal(u) for u in us]
        return list(self._pool.map(_signals, list(us),
                                   chunksize=max(1, len(us) // (4 * self.workers))))

    def scipy_map(self, func: Callable[[np.ndarray], float],
                  us: Iterable[np.ndarray]) -> list[float]:
        """A ``workers=`` map for scipy: ``func`` is scipy's wrapper of this objective."""
        del func                      # the workers already hold the objective
        return self.values(list(us))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
