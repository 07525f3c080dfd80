"""Evaluate an objective over many parameter vectors on all available cores.

The objective (a picklable callable of a relative vector ``u``) is sent to each worker
process once, at start-up; afterwards only the vectors travel. ``workers`` defaults
to ``len(os.sched_getaffinity(0))``; with one worker everything runs in-process.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from gateway.identify.misfit import TrackMisfit
from gateway.identify.params import FreeSpace


class Misfit(Protocol):
    """Anything that maps a parameter point to a scalar misfit."""

    def __call__(self, point: Any) -> float: ...


class Objective:
    """``u (k,) -> J``: the misfit at ``space.point(u)``; ``per_signal`` for screening."""

    def __init__(self, misfit: Misfit, space: FreeSpace) -> None:
        self.misfit = misfit
        self.space = space

    def __call__(self, u: np.ndarray) -> float:
        return float(self.misfit(self.space.point(u)))

    def per_signal(self, u: np.ndarray) -> np.ndarray:
        """Per-signal misfits (ny,); only for a :class:`TrackMisfit`."""
        if not isinstance(self.misfit, TrackMisfit):
            raise TypeError("per-signal misfits need a TrackMisfit")
        return self.misfit.per_signal(self.space.point(u))


_OBJECTIVE: Objective | None = None


def _init(objective: Objective) -> None:
    global _OBJECTIVE
    _OBJECTIVE = objective


def _value(u: np.ndarray) -> float:
    assert _OBJECTIVE is not None
    return _OBJECTIVE(u)


def _signals(u: np.ndarray) -> np.ndarray:
    assert _OBJECTIVE is not None
    return _OBJECTIVE.per_signal(u)


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:       # not on Linux
        return os.cpu_count() or 1


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
