"""The one threshold judge: an estimate relative to nominal, its confidence gate, its side.

Used by the alert policy (which adds hold times and hysteresis on top) and by the
console's estimates view (which shows the same numbers to a fitter), so that both say
the same about one estimate. Pure functions, no state.

- ``value_rel = mean / nominal``;
- ``sigma_rel = std / max(|mean|, nominal)``: the spread relative to the larger of the
  estimate and nominal, so that a collapsed damper (mean near 0) is not gated shut by
  its own small mean;
- confident when ``sigma_rel <= max_std_rel`` (finite);
- beyond a threshold: ``value_rel <= threshold`` on the low side (a weak damper),
  ``value_rel >= threshold`` on the high side (worn wheels).
"""

from __future__ import annotations

import math


def value_rel(mean: float, nominal: float | None) -> float | None:
    """``mean / nominal``; None without a nominal (or a zero one)."""
    return mean / nominal if nominal else None


def sigma_rel(mean: float, std: float, nominal: float | None) -> float | None:
    """``std / max(|mean|, nominal)`` (no nominal: ``std / |mean|``); None when both
    are zero."""
    return std / max(abs(mean), nominal or 0.0) if (mean or nominal) else None


def confident(sigma: float | None, max_std_rel: float) -> bool:
    """Is the estimate inside the confidence gate: ``sigma_rel`` finite and
    ``<= max_std_rel``?"""
    return sigma is not None and math.isfinite(sigma) and bool(sigma <= max_std_rel)


def judgeable(rel: float | None, sigma: float | None, max_std_rel: float) -> bool:
    """May the estimate be judged against thresholds at all: ``value_rel`` finite and
    :func:`confident`? (The policy resets its hold timers when not.)"""
    return rel is not None and math.isfinite(rel) and confident(sigma, max_std_rel)


def beyond(side: str, rel: float, threshold: float) -> bool:
    """Is ``rel`` past ``threshold`` on ``side`` ("low": ``<=``, "high": ``>=``)?"""
    return rel <= threshold if side == "low" else rel >= threshold
