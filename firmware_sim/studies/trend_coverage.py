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
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.fleet.trend import DAY_S, fit_trend

CASES: dict[str, tuple[Callable[[np.ndarray], np.ndarray], float, str]] = {
    "wheel-wear-lambda": (lambda d: 1.0 + d / 12.0, 1.6, "high"),
    "nominal-lambda": (lambda d: 1.0 + 0.1 * d / 12.0, 1.6, "high"),
    "csy-degrading": (lambda d: 1.0 - 0.3 * d / 12.0, 0.75, "low"),
}
"""name -> (truth relative to nominal at days since the start, threshold, side): the
simulated fleet's ``--degrade-days 12`` lines and the advisory thresholds."""


@dataclass(frozen=True)
class Coverage:
    """``covered`` of ``predicted`` intervals bracketed the true crossing; ``early`` of the
    misses lay before the truth (the interval was late)."""

    case: str
    s0: float
    k: float
    bias: float
    predicted: int
    covered: int
    early: int

    @property
    def rate(self) -> float:
        return self.covered / self.predicted if self.predicted else math.nan


def true_crossing_s(case: str) -> float:
    """The truth line's crossing, s after the start."""
    rel, thr, side = CASES[case]
    a, b = float(rel(np.array([0.0]))[0]), float(rel(np.array([1.0]))[0]) - float(
        rel(np.array([0.0]))[0])
    return (thr - a) / b * DAY_S if (b > 0) == (side == "high") else math.inf


def coverage(case: str, *, s0: float, k: float, bias: float, reps: int,
             rng: np.random.Generator, days: int = 30) -> Coverage:
    """``reps`` synthetic units of ``case``: how many predicted crossings bracket the truth."""
    rel, thr, side = CASES[case]
    t_true = true_crossing_s(case)
    predicted = covered = early = 0
    for _ in range(reps):
        d = np.arange(days) + (6.0 + rng.uniform(0.0, 1.0, days)) / 24.0
        truth = rel(d)
        std = s0 * truth
        est = truth * (1.0 + bias + k * s0 * rng.standard_normal(days))
        tr = fit_trend(d * DAY_S, est, std, thr, side)
        if not math.isfinite(tr.crossing_lo_s):
            continue
        predicted += 1
        if tr.crossing_lo_s <= t_true <= tr.crossing_hi_s:
            covered += 1
        elif t_true < tr.crossing_lo_s:
            early += 1
    return Coverage(case, s0, k, bias, predicted, covered, early)


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
                          f"{c.covered:8d}  {c.rate:.3f} {c.early:6d}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
