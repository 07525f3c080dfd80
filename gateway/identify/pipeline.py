"""The two identification procedures, each an ``Identifier`` with ``fit(dataset) -> result``.

- :class:`TrackIdentifier` (known track): synchronise each learn section, screen all
  parameters with Morris, pick the ones to identify, then run every requested
  optimiser on the time-domain misfit and compare them (Kraft's Table 1). With a free
  track offset the offset is one more dimension of the optimisation instead of the
  synchronisation.
- :class:`PredictionErrorIdentifier` (no track): maximum likelihood of Csy, Csay and
  lambda (by default) through the Kalman prediction-error misfit.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from gateway.identify.data import Dataset
from gateway.identify.linalg import one_blas_thread
from gateway.identify.misfit import MisfitConfig, Section, TrackMisfit
from gateway.identify.optimise import Budget, MethodResult, run_method
from gateway.identify.parallel import Evaluator, Objective
from gateway.identify.params import ALL_NAMES, FreeSpace, OffsetRange, ParamPoint
from gateway.identify.prediction_error import PredictionErrorMisfit, standard_errors
from gateway.identify.screening import MorrisResult, morris, select
from gateway.identify.sync import LagEstimate
from gateway.identify.track import Track
from gateway.model.vehicle import AR_PAPER_DEFAULT, PARAM_NAMES

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackConfig:
    """Settings of the known-track identification.

    ``params`` None means "choose with Morris": the ``top_k`` best-ranked non-geometry
    parameters. ``max_lag_s`` 0 disables synchronisation. ``free_offset_m`` (m) makes
    the track offset a free dimension, ``offset_m +- free_offset_m``; the
    synchronisation is then not run (at constant speed lag and offset are the same
    degree of freedom), only the check of the lag at the identified point.
    """

    misfit: MisfitConfig = field(default_factory=MisfitConfig)
    offset_m: float = 0.0
    tolerance: float = 0.3
    params: tuple[str, ...] | None = None
    top_k: int = 5
    morris_trajectories: int = 8
    methods: tuple[str, ...] = ("de", "da", "nm", "ps")
    budget: Budget = field(default_factory=Budget)
    max_lag_s: float = 1.0
    workers: int | None = None
    free_offset_m: float | None = None


@dataclass(frozen=True)
class TrackResult:
    """Everything the report needs. ``methods`` in the order run; ``best`` the lowest J."""

    space: FreeSpace
    j_nominal: float
    lags: tuple[LagEstimate, ...]
    lags_after: tuple[LagEstimate, ...]
    morris: MorrisResult | None
    methods: tuple[MethodResult, ...]
    evals_per_s_one_core: float
    wall_s: float
    misfit: TrackMisfit

    @property
    def best(self) -> MethodResult:
        return min(self.methods, key=lambda m: m.j_final)

    def point(self, method: MethodResult | None = None) -> ParamPoint:
        return self.space.point(np.array((method or self.best).u))

    def offset_m(self, method: MethodResult | None = None) -> float:
        """The track offset [m] of ``method`` (default the best): identified or as given."""
        offset_m = self.space.offset_m(np.array((method or self.best).u))
        return self.misfit.offset_m if offset_m is None else offset_m


def _eval_rate(objective: Objective, n: int = 20) -> float:
    """Misfit evaluations per second on one core, measured at nominal."""
    u = np.zeros(objective.space.size)
    objective(u)                              # warm-up (JIT, caches)
    t0 = time.perf_counter()
    for _ in range(n):
        objective(u)
    return n / (time.perf_counter() - t0)


class TrackIdentifier:
    """Known-track identification (Kraft et al.): ``fit(dataset) -> TrackResult``."""

    def __init__(self, track: Track, sections: list[Section], config: TrackConfig) -> None:
        self.track, self.sections, self.config = track, list(sections), config

    def fit(self, dataset: Dataset) -> TrackResult:
        with one_blas_thread():
            return self._fit(dataset)

    def _fit(self, dataset: Dataset) -> TrackResult:
        c = self.config
        t_start = time.perf_counter()
        nominal = ParamPoint.nominal()
        misfit = TrackMisfit(dataset, self.track, self.sections, c.misfit, c.offset_m)
        lags: tuple[LagEstimate, ...] = ()
        if c.max_lag_s > 0 and c.free_offset_m is None:
            lags = tuple(misfit.synchronise(nominal, c.max_lag_s))
            misfit = misfit.with_lags(tuple(e.lag_samples / dataset.fs_hz for e in lags))
            log.info("synchronised: lags %s samples", [e.lag_samples for e in lags])
        screening = None
        if c.params is None:
            everything = FreeSpace.uniform(ALL_NAMES, c.tolerance)
            with Evaluator(Objective(misfit, everything), c.workers) as ev:
                screening = morris(ev, c.morris_trajectories, seed=c.budget.seed)
            names = select(screening, top_k=c.top_k)
            log.info("Morris selected %s", names)
        else:
            names = c.params
        offset = None if c.free_offset_m is None else OffsetRange(c.offset_m, c.free_offset_m)
        space = FreeSpace.uniform(names, c.tolerance, offset=offset)
        objective = Objective(misfit, space)
        rate = _eval_rate(objective)
        j0 = objective(np.zeros(space.size))
        results = []
        with Evaluator(objective, c.workers) as ev:
            for m in c.methods:
                results.append(run_method(m, objective, ev, c.budget, j0))
                log.info("%s: J %.5f -> %.5f in %d evaluations", m, j0, results[-1].j_final,
                         results[-1].n_evals)
        best = np.array(min(results, key=lambda r: r.j_final).u)
        after: tuple[LagEstimate, ...] = ()
        if c.max_lag_s > 0:
            best_offset_m = space.offset_m(best)
            at = misfit if best_offset_m is None else misfit.at_offset(best_offset_m)
            after = tuple(at.with_lags((0.0,) * len(self.sections)).synchronise(
                space.point(best), c.max_lag_s))
            before = [e.lag_samples for e in lags] or [0] * len(after)
            if [e.lag_samples for e in after] != before:
                log.warning("the lags at the identified point %s differ from those used %s; "
                            "consider re-running with them", [e.lag_samples for e in after],
                            before)
        return TrackResult(space=space, j_nominal=j0, lags=lags, lags_after=after,
                           morris=screening, methods=tuple(results),
                           evals_per_s_one_core=rate, wall_s=time.perf_counter() - t_start,
                           misfit=misfit)


@dataclass(frozen=True)
class PredictionErrorResult:
    """ML estimate: ``values`` SI, ``std`` SI (from the observed information), mean NLL."""

    names: tuple[str, ...]
    values: tuple[float, ...]
    std: tuple[float, ...]
    nll_nominal: float
    nll_final: float
    n_evals: int
    evals_per_s_one_core: float
    wall_s: float
    settings: dict[str, object]


class PredictionErrorIdentifier:
    """No-track maximum likelihood: ``fit(dataset) -> PredictionErrorResult``.

    Bounded Nelder-Mead from nominal, then L-BFGS-B polish; the likelihood of this
    linear-Gaussian model was unimodal in every run we made (see the docs).
    """

    def __init__(self, sections: list[Section] | None = None,
                 params: tuple[str, ...] = PARAM_NAMES, tolerance: float = 0.75,
                 ar_paper: float = AR_PAPER_DEFAULT, decimation: int = 1,
                 maxfev: int = 600) -> None:
        self.sections, self.params, self.tolerance = sections, tuple(params), tolerance
        self.ar_paper, self.decimation, self.maxfev = ar_paper, decimation, maxfev

    def fit(self, dataset: Dataset) -> PredictionErrorResult:
        with one_blas_thread():
            return self._fit(dataset)

    def _fit(self, dataset: Dataset) -> PredictionErrorResult:
        t0 = time.perf_counter()
        sections = self.sections or [Section(float(dataset.t_s[0]),
                                             float(dataset.t_s[-1]) + 1.0 / dataset.fs_hz)]
        misfit = PredictionErrorMisfit(dataset, sections, self.ar_paper,
                                       decimation=self.decimation)
        space = FreeSpace.uniform(self.params, self.tolerance)
        objective = Objective(misfit, space)
        k = len(self.params)
        rate = _eval_rate(objective, n=5)
        nll0 = objective(np.zeros(k))
        count = [0]

        def f(u: np.ndarray) -> float:
            count[0] += 1
            return objective(u)

        res = scipy.optimize.minimize(f, np.zeros(k), method="Nelder-Mead", bounds=space.bounds,
                                      options={"maxfev": self.maxfev, "xatol": 1e-4,
                                               "fatol": 1e-9})
        res = scipy.optimize.minimize(f, res.x, method="L-BFGS-B", bounds=space.bounds,
                                      options={"eps": 1e-6})
        se = standard_errors(lambda u: misfit.total_nll(space.point(u)), res.x)
        base = space.base.as_dict()
        point = space.point(res.x).as_dict()
        return PredictionErrorResult(
            names=self.params, values=tuple(point[n] for n in self.params),
            std=tuple(float(s) * base[n] for s, n in zip(se, self.params, strict=True)),
            nll_nominal=nll0, nll_final=float(res.fun), n_evals=count[0],
            evals_per_s_one_core=rate, wall_s=time.perf_counter() - t0,
            settings=misfit.describe())
