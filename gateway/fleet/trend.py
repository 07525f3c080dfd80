"""Degradation trends: fit a parameter's run-by-run estimates, predict its threshold crossing.

Pure numpy/scipy, no I/O. Input per unit and parameter: run end times ``t_s`` (n,)
(Unix s), estimates relative to nominal ``rel`` (n,) and their std ``std_rel`` (n,).
Two models are fitted by weighted least squares (weights 1/std^2, covariance scaled
up by the reduced chi-square when the scatter exceeds the stated std):

- a straight line in days (slow degradation or wear), crossing = where the line meets
  the threshold, interval = where the line's 95 % confidence band contains it;
- a step (two constant levels, one change point: an abrupt failure), crossing = between
  the last run before and the first run after the change.

The step is chosen when it fits better by BIC (one parameter more). ``status`` is
``crossed`` (the latest fitted value is beyond the threshold), ``trending`` (crossing
predicted in the future), ``stable`` (no significant trend towards the threshold) or
``insufficient`` (fewer than 3 runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

DAY_S = 86_400.0
CONFIDENCE = 0.95
STD_FLOOR_REL = 0.01
"""A run's stated std is floored at 1 % of nominal: a short run's posterior std can be
optimistic, and one over-confident run must not carry the fit."""
OUTLIER_Z = 5.0
"""A run further than this many (scaled) stds from what the other runs predict is left
out of the fit: a particle filter with few particles occasionally locks onto a wrong
mode at start-up (README, "Start-up")."""
MIN_SCREENED = 6
"""Fewer runs than this are not screened for outliers (too few to tell)."""
MIN_BEFORE_STEP = 2
"""Runs before a change point: a lone odd first run is an outlier, not a repair."""
HORIZON_DAYS = 3650.0
"""Crossings later than this after the last run are reported as none (stable)."""


@dataclass(frozen=True)
class Trend:
    """A fitted trend of one parameter of one unit against its threshold.

    ``slope_per_day`` in rel units per day (line model; 0 for the step); ``crossing_s``
    and its interval ``[crossing_lo_s, crossing_hi_s]`` Unix s, NaN when no crossing is
    predicted (``crossing_hi_s`` may be +inf: not bounded by the data)."""

    threshold_rel: float
    side: str
    model: str
    status: str
    n: int
    current_rel: float
    slope_per_day: float
    crossing_s: float
    crossing_lo_s: float
    crossing_hi_s: float
    line: tuple[float, float, float]
    """(t_ref_s, intercept, slope_per_day) of the line model, for plotting."""


def _beyond(x: np.ndarray | float, thr: float, side: str) -> np.ndarray:
    return np.asarray(x) <= thr if side == "low" else np.asarray(x) >= thr


def _wls(d: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted line fit: coefficients (a, b), covariance (2, 2), weighted SSE."""
    X = np.column_stack([np.ones_like(d), d])
    W = X * w[:, None]
    cov = np.linalg.pinv(X.T @ W)
    beta = cov @ (W.T @ y)
    sse = float(np.sum(w * (y - X @ beta) ** 2))
    scale = max(1.0, sse / max(len(d) - 2, 1))
    return beta, cov * scale, sse


def _step(d: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[int, float, float, float]:
    """Best change point k (levels y[:k], y[k:], k >= MIN_BEFORE_STEP): (k, level0,
    level1, weighted SSE); cumulative sums, O(n)."""
    n = len(d)
    if n <= MIN_BEFORE_STEP:
        return 0, math.nan, math.nan, math.inf
    S0, S1, S2 = np.cumsum(w), np.cumsum(w * y), np.cumsum(w * y * y)
    k = np.arange(MIN_BEFORE_STEP, n)
    a0, a1, a2 = S0[k - 1], S1[k - 1], S2[k - 1]
    b0, b1, b2 = S0[-1] - a0, S1[-1] - a1, S2[-1] - a2
    sse = (a2 - a1**2 / a0) + (b2 - b1**2 / b0)
    j = int(np.argmin(sse))
    return int(k[j]), float(a1[j] / a0[j]), float(b1[j] / b0[j]), float(sse[j])


@dataclass(frozen=True)
class _Fit:
    beta: np.ndarray
    cov: np.ndarray
    step: tuple[int, float, float]
    t_step_s: float
    t_pre_s: float
    use_step: bool
    chi2_red: float

    def residual(self, t_s: float, y: float, t_ref: float) -> float:
        """|y - model(t_s)|; between the runs around a change either level fits."""
        if self.use_step:
            if self.t_pre_s < t_s < self.t_step_s:
                return min(abs(y - self.step[1]), abs(y - self.step[2]))
            return abs(y - (self.step[2] if t_s >= self.t_step_s else self.step[1]))
        return abs(y - float(self.beta[0] + self.beta[1] * (t_s - t_ref) / DAY_S))


def _fit(t: np.ndarray, y: np.ndarray, s: np.ndarray, t_ref: float) -> _Fit:
    """Both models; the step when its BIC is lower (one parameter more)."""
    n = len(t)
    w = 1.0 / s**2
    d = (t - t_ref) / DAY_S
    beta, cov, sse_line = _wls(d, y, w)
    k, m0, m1, sse_step = _step(d, y, w)
    use_step = sse_step + 3 * math.log(n) < sse_line + 2 * math.log(n)
    sse = sse_step if use_step else sse_line
    return _Fit(beta, cov, (k, m0, m1), float(t[k]) if use_step else math.nan,
                float(t[k - 1]) if use_step else math.nan, use_step,
                max(1.0, sse / max(n - 3, 1)))


def _outliers(t: np.ndarray, y: np.ndarray, s: np.ndarray, t_ref: float) -> np.ndarray:
    """Runs kept (bool mask): leave-one-out, the run worst predicted by the others goes if
    more than OUTLIER_Z scaled stds off; repeated, at most a quarter of the runs, never
    the latest run (a failure seen once must not be explained away)."""
    keep = np.ones(len(t), dtype=bool)
    for _ in range(len(t) // 4 if len(t) >= MIN_SCREENED else 0):
        idx = np.flatnonzero(keep)
        if len(idx) <= 3:
            break
        z = np.zeros(len(idx))
        for j, i in enumerate(idx[:-1]):
            m = keep.copy()
            m[i] = False
            f = _fit(t[m], y[m], s[m], t_ref)
            z[j] = f.residual(float(t[i]), float(y[i]), t_ref) / (s[i] * math.sqrt(f.chi2_red))
        j = int(np.argmax(z))
        if z[j] <= OUTLIER_Z:
            break
        keep[idx[j]] = False
    return keep


def fit_trend(t_s: np.ndarray, rel: np.ndarray, std_rel: np.ndarray, threshold_rel: float,
              side: str) -> Trend:
    """The trend and predicted crossing of one parameter (see the module docstring)."""
    order = np.argsort(t_s)
    t, y = np.asarray(t_s, float)[order], np.asarray(rel, float)[order]
    s = np.maximum(np.asarray(std_rel, float)[order], STD_FLOOR_REL)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y, s = t[ok], y[ok], s[ok]
    nan = math.nan
    if len(t) < 3:
        cur = float(y[-1]) if len(t) else nan
        return Trend(threshold_rel, side, "none", "insufficient", len(t), cur, nan, nan, nan,
                     nan, (nan, nan, nan))
    t_ref = float(t[0])
    keep = _outliers(t, y, s, t_ref)
    t, y, s = t[keep], y[keep], s[keep]
    n = len(t)
    d = (t - t_ref) / DAY_S
    f = _fit(t, y, s, t_ref)
    beta, cov, (k, m0, m1), use_step = f.beta, f.cov, f.step, f.use_step
    tq = float(stats.t.ppf(0.5 + CONFIDENCE / 2, n - 2))
    line = (t_ref, float(beta[0]), float(beta[1]))
    if use_step and bool(_beyond(m1, threshold_rel, side)) and not bool(
            _beyond(m0, threshold_rel, side)):
        lo, hi = float(t[k - 1]), float(t[k])
        return Trend(threshold_rel, side, "step", "crossed", n, m1, 0.0, 0.5 * (lo + hi), lo,
                     hi, line)
    a, b = float(beta[0]), float(beta[1])
    cur = a + b * float(d[-1])
    grid = np.arange(d[0] - 1.0, d[-1] + HORIZON_DAYS, 0.01)
    X = np.column_stack([np.ones_like(grid), grid])
    fit = X @ beta
    se = np.sqrt(np.einsum("ij,jk,ik->i", X, cov, X))
    inside = (fit - tq * se <= threshold_rel) & (threshold_rel <= fit + tq * se)
    significant = abs(b) > tq * math.sqrt(cov[1, 1])
    toward = significant and ((b < 0) if side == "low" else (b > 0))
    d_cross = (threshold_rel - a) / b if b != 0 else math.inf
    if not toward or not math.isfinite(d_cross) or d_cross > d[-1] + HORIZON_DAYS:
        status = "crossed" if bool(_beyond(cur, threshold_rel, side)) else "stable"
        return Trend(threshold_rel, side, "line", status, n, cur, b, nan, nan, nan, line)
    j = int(np.clip(np.searchsorted(grid, d_cross), 0, len(grid) - 1))
    lo_j = j
    while lo_j > 0 and inside[lo_j - 1]:
        lo_j -= 1
    hi_j = j
    while hi_j < len(grid) - 1 and inside[hi_j + 1]:
        hi_j += 1
    lo_s = t_ref + grid[lo_j] * DAY_S
    hi_s = t_ref + grid[hi_j] * DAY_S if hi_j < len(grid) - 1 else math.inf
    status = "crossed" if bool(_beyond(cur, threshold_rel, side)) else "trending"
    return Trend(threshold_rel, side, "line", status, n, cur, b, t_ref + d_cross * DAY_S,
                 lo_s, hi_s, line)
