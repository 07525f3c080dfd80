"""The fleet trend's crossing interval is a calibrated 95 % interval on unbiased runs."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.trend_coverage import coverage

REPS = 150


@pytest.mark.parametrize("case, k", [("wheel-wear-lambda", 1.0), ("wheel-wear-lambda", 2.0),
                                     ("csy-degrading", 1.0)])
def test_the_crossing_interval_brackets_the_true_date_about_95_percent_of_the_time(
        case: str, k: float) -> None:
    """Runs scattered around the truth line: with their stated std (k = 1), and twice as
    wide as they state (k = 2: the fit scales its band by the scatter it sees). A band
    too narrow (misses) or unbounded (no misses at all) fails; 95 % of 150 is 142.5 with
    a binomial std of 2.5."""
    c = coverage(case, s0=0.02, k=k, bias=0.0, reps=REPS, rng=np.random.default_rng(7))
    assert c.predicted == REPS, f"expected a crossing predicted on every unit, got {c}"
    assert 0.88 <= c.rate <= 0.99, f"expected 88-99 % of intervals to bracket the truth, got {c}"
