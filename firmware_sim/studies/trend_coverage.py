"""Coverage of the fleet trend's crossing interval: a Monte Carlo over synthetic units.

How often :func:`gateway.fleet.trend.fit_trend`'s 95 % interval brackets the true
threshold-crossing date, over many synthetic units whose truth is the simulated fleet's
straight line (:func:`firmware_sim.fleet.trajectory`: wheel wear, the fleet-wide conicity
rise, a degrading damper), one run a day for ``days`` days. Each run's estimate is the
truth times ``1 + bias + k * s0 * N(0, 1)``, and it states ``s0`` times the truth as its std:
``k`` > 1 is a run whose stated std is too narrow, ``bias`` an error every run shares.
The figures of docs/fleet.md "Crossing intervals: coverage"; the test
``tests/test_fleet_trend.py`` checks the unbiased case. Run: ``python -m
firmware_sim.studies.trend_coverage``. A measuring tool; the product
never imports it.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_sim.fleet import FleetSpec, crossings, trajectory
from gateway.alerts.policy import default_params
from gateway.fleet.trend import DAY_S, fit_trend
from gateway.model.vehicle import PARAM_NAMES

HORIZON_DAYS = 120.0
"""Long enough for every case's crossing (the fleet-wide λ crosses at day 72)."""

SPEC = FleetSpec(degrade_days=12.0)
"""The demo's fleet (``railgw fleet demo``: ``--degrade-days 12``)."""
CASES: dict[str, tuple[str, str, str]] = {
    "wheel-wear-lambda": ("wheel-wear", "conicity", "high"),
    "nominal-lambda": ("nominal", "conicity", "high"),
    "csy-degrading": ("csy-degrading", "csy_ns_per_m", "low"),
}
"""name -> (the simulated fleet's role, parameter, threshold side): its truth lines
(:func:`firmware_sim.fleet.trajectory`) against the advisory thresholds."""


@dataclass(frozen=True)
class Coverage:
    """``covered`` of ``predicted`` intervals bracketed the true crossing; of the misses,
    ``truth_before`` had the truth before the interval (the interval was late)."""

    case: str
    s0: float
    k: float
    bias: float
    predicted: int
    covered: int
    truth_before: int

    @property
    def rate(self) -> float:
        return self.covered / self.predicted if self.predicted else math.nan


def coverage(case: str, *, s0: float, k: float, bias: float, reps: int,
             rng: np.random.Generator, days: int = 30) -> Coverage:
    """``reps`` synthetic units of ``case``: how many predicted crossings bracket the truth."""
    role, name, side = CASES[case]
    j = PARAM_NAMES.index(name)
    thr = default_params()[name].levels(side)[0]
    rel = trajectory(role, SPEC)
    t_true = crossings(rel, SPEC, HORIZON_DAYS)[name]["advisory"]
    assert thr is not None and t_true is not None, case
    t_true -= SPEC.t_start_s
    predicted = covered = truth_before = 0
    for _ in range(reps):
        d = np.arange(days) + (6.0 + rng.uniform(0.0, 1.0, days)) / 24.0
        truth = rel(d)[:, j]
        std = s0 * truth
        est = truth * (1.0 + bias + k * s0 * rng.standard_normal(days))
        tr = fit_trend(d * DAY_S, est, std, thr, side)
        if not math.isfinite(tr.crossing_lo_s):
            continue
        predicted += 1
        if tr.crossing_lo_s <= t_true <= tr.crossing_hi_s:
            covered += 1
        elif t_true < tr.crossing_lo_s:
            truth_before += 1
    return Coverage(case, s0, k, bias, predicted, covered, truth_before)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m firmware_sim.studies.trend_coverage",
                                description=__doc__.splitlines()[0])
    p.add_argument("--reps", type=int, default=500, help="units per row (500)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print("case               s0    k    bias    predicted  covered  rate   truth-before")
    for case in CASES:
        for s0 in (0.01, 0.02):
            for k in (1.0, 1.5, 2.0):
                for bias in (0.0, -0.005):
                    c = coverage(case, s0=s0, k=k, bias=bias, reps=args.reps, rng=rng)
                    print(f"{case:18s} {s0:.2f} {k:4.1f} {bias:+.3f} {c.predicted:9d} "
                          f"{c.covered:8d}  {c.rate:.3f} {c.truth_before:6d}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
