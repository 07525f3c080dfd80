"""Per-node clock model: a node's sample index and receive times -> its sample times.

A sensor node numbers its samples ``k`` (16-bit on the bus, unwrapped here) on its own
oscillator, so on the gateway's receive clock sample ``k`` is taken at::

    t(k) = offset_s + (k - k_ref) * period_s,   period_s = nominal * (1 + drift)

and its frame is received at ``t_rx = t_true(k) + latency`` with ``latency >= L_min``
and jittered upwards (queueing, arbitration). The model is therefore fitted to the
*lower envelope* of the receive times, not through their middle:

1. Frames are grouped in segments of ``segment_samples`` arrivals; each segment keeps
   only its earliest frame relative to the current model (its minimum latency).
2. The last ``window_segments`` segment minima are the envelope points. The fitted
   line is the support line of their lower convex hull at their mean index: among the
   lines below every point it minimises the summed vertical distance (the classic
   linear-programming skew estimator; it converges like 1/n, least squares like
   1/sqrt(n)).
3. Before two segments exist, the line has the nominal period and drops to every new
   minimum (a running lower envelope).

``t(k)`` is then the true sample time plus the minimum latency ``L_min``: a constant
shift, the same for nodes on the same bus, which the grid does not care about.
A frame far from the model (``|t_rx - t(k)| > resync_s``) is an *outlier*: its receive
time is not believed, and it joins the node's current *outlier run*. A run is
*consistent* while its residuals ``u = t_rx - t(k)`` stay within ``run_spread_s`` of
each other (a clock step or a node restart: every frame off by the same amount); an
outlier that does not fit starts a new run. An inlier closes the run: it was a
timestamp glitch, and the caller may still place its frames by sample index. A run
whose sample indices span ``resync_hold_s`` of the node's own time (and holds at least
``resync_after`` frames) is *ripe*: :func:`observe` returns :data:`Observation.STEP`,
and the caller decides whether the receive clock stepped (re-base every node) or this
node restarted (:func:`restart`). Nothing is decided on fewer frames than that, so a
burst of glitched timestamps never moves the model, and a real step or restart is
followed within ``resync_hold_s`` of data.
Pure functions over a plain, picklable :class:`ClockState`; no I/O, no clock reads.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

from gateway.errors import ConfigError

SAMPLE_INDEX_MODULUS = 1 << 16
"""The bus carries the sample index modulo this (16 bits)."""
MAX_DRIFT_PPM = 500.0
"""A fitted drift beyond this is clamped: no crystal is that bad, the fit must be."""


@dataclass(frozen=True)
class ClockParams:
    """Settings of the envelope fit (all nodes)."""

    segment_samples: int = 32
    window_segments: int = 32
    resync_s: float = 0.1
    """Residual beyond which a receive time is not believed, s."""
    resync_after: int = 3
    """Fewest frames in a ripe outlier run."""
    resync_hold_s: float = 0.03
    """Span of sample indices (node time) a consistent outlier run needs to be ripe, s."""
    run_spread_s: float = 0.02
    """Largest spread of residuals within one consistent outlier run, s."""

    def __post_init__(self) -> None:
        if self.segment_samples < 2 or self.window_segments < 2 or self.resync_after < 1:
            raise ConfigError(f"expected segment_samples >= 2, window_segments >= 2 and "
                              f"resync_after >= 1, got {self}")
        if not (math.isfinite(self.resync_s) and self.resync_s > 0):
            raise ConfigError(f"expected resync_s > 0 s, got {self.resync_s}")
        if not (math.isfinite(self.resync_hold_s) and self.resync_hold_s > 0):
            raise ConfigError(f"expected resync_hold_s > 0 s, got {self.resync_hold_s}")
        if not (math.isfinite(self.run_spread_s) and 0 < self.run_spread_s < self.resync_s):
            raise ConfigError(f"expected 0 < run_spread_s < resync_s, got "
                              f"{self.run_spread_s} s")


@dataclass
class ClockState:
    """One node's clock model and envelope fit (explicit streaming state)."""

    period_nominal_s: float
    started: bool = False
    fitted: bool = False
    k_ref: int = 0
    offset_s: float = 0.0
    """Receive-clock time of sample ``k_ref`` (includes the minimum latency)."""
    period_s: float = 0.0
    k_max: int = 0
    seg_count: int = 0
    seg_best_u_s: float = math.inf
    seg_best_k: int = 0
    seg_best_t_s: float = 0.0
    env_k: list[int] = field(default_factory=list)
    env_t_s: list[float] = field(default_factory=list)
    outliers_in_row: int = 0
    """Frames in the current outlier run (0: no run open)."""
    run_k0: int = 0
    """Unwrapped index of the run's first frame."""
    run_k_lo: int = 0
    run_k_hi: int = 0
    run_u_min_s: float = math.inf
    run_u_max_s: float = -math.inf
    run_t0_s: float = 0.0
    """Receive time of the run's first frame, s."""

    def time_s(self, k: int) -> float:
        """Sample time of unwrapped index ``k`` on the receive clock, s."""
        return self.offset_s + (k - self.k_ref) * self.period_s

    def index_at(self, t_s: float) -> float:
        """Fractional sample index at receive-clock time ``t_s``."""
        return self.k_ref + (t_s - self.offset_s) / self.period_s

    @property
    def drift_ppm(self) -> float:
        """Fitted period relative to nominal, ppm of the receive clock; NaN until fitted."""
        if not self.fitted:
            return math.nan
        return (self.period_s / self.period_nominal_s - 1.0) * 1e6


class Observation(enum.IntEnum):
    """What :func:`observe` made of a frame."""

    OK = 0
    OUTLIER = 1
    """Too far from the model: the frame joined the current outlier run."""
    NEW_RUN = 2
    """Too far from the model and inconsistent with the open run: the old run is over
    (not ripe) and this frame starts a new one."""
    STEP = 3
    """The frame joined the run and made it ripe: re-base or :func:`restart`."""


def unwrap(clock: ClockState, raw_idx: int, t_rx_s: float) -> int:
    """The unwrapped index congruent to ``raw_idx`` nearest the index the model expects at
    ``t_rx_s`` (so gaps and reordering up to half a wrap, 32 s at 1 kHz, are fine)."""
    if not clock.started:
        return raw_idx
    k_pred = clock.index_at(t_rx_s)
    return raw_idx + SAMPLE_INDEX_MODULUS * round((k_pred - raw_idx) / SAMPLE_INDEX_MODULUS)


def restart(clock: ClockState, k: int, t_rx_s: float) -> None:
    """Forget the fit and start again from one frame (nominal period)."""
    clock.started, clock.fitted = True, False
    clock.k_ref, clock.offset_s, clock.period_s = k, t_rx_s, clock.period_nominal_s
    clock.k_max = k
    clock.seg_count, clock.seg_best_u_s = 0, math.inf
    clock.env_k.clear()
    clock.env_t_s.clear()
    close_run(clock)


def close_run(clock: ClockState) -> None:
    """Forget the outlier run (it was a glitch, or the caller has dealt with it)."""
    clock.outliers_in_row = 0
    clock.run_u_min_s, clock.run_u_max_s = math.inf, -math.inf


def shift(clock: ClockState, dt_s: float) -> None:
    """Move the model and its envelope by ``dt_s`` on the receive clock (a re-base)."""
    clock.offset_s += dt_s
    clock.seg_best_t_s += dt_s
    clock.env_t_s[:] = [t + dt_s for t in clock.env_t_s]


def observe(clock: ClockState, k: int, t_rx_s: float, params: ClockParams) -> Observation:
    """Feed one (unwrapped index, receive time) pair, not a duplicate; updates the fit."""
    if not clock.started:
        restart(clock, k, t_rx_s)
        return Observation.OK
    u = t_rx_s - (clock.offset_s + (k - clock.k_ref) * clock.period_s)
    if u > params.resync_s or u < -params.resync_s:
        fresh = clock.outliers_in_row == 0 or (
            max(u, clock.run_u_max_s) - min(u, clock.run_u_min_s) > params.run_spread_s)
        if fresh:
            result = Observation.OUTLIER if clock.outliers_in_row == 0 else Observation.NEW_RUN
            clock.outliers_in_row = 0
            clock.run_k0 = clock.run_k_lo = clock.run_k_hi = k
            clock.run_u_min_s = clock.run_u_max_s = u
            clock.run_t0_s = t_rx_s
        else:
            result = Observation.OUTLIER
            clock.run_u_min_s, clock.run_u_max_s = min(u, clock.run_u_min_s), max(
                u, clock.run_u_max_s)
            clock.run_k_lo, clock.run_k_hi = min(k, clock.run_k_lo), max(k, clock.run_k_hi)
        clock.outliers_in_row += 1
        if (clock.outliers_in_row >= params.resync_after and
                (clock.run_k_hi - clock.run_k_lo) * clock.period_nominal_s
                >= params.resync_hold_s):
            return Observation.STEP
        return result
    clock.outliers_in_row = 0
    if k > clock.k_max:
        clock.k_max = k
    if u < 0.0 and not clock.fitted:     # running envelope: the line drops to the point
        clock.offset_s += u
        clock.seg_best_u_s -= u
        u = 0.0
    if u < clock.seg_best_u_s:
        clock.seg_best_u_s, clock.seg_best_k, clock.seg_best_t_s = u, k, t_rx_s
    clock.seg_count += 1
    if clock.seg_count >= params.segment_samples:
        clock.env_k.append(clock.seg_best_k)
        clock.env_t_s.append(clock.seg_best_t_s)
        if len(clock.env_k) > params.window_segments:
            del clock.env_k[0], clock.env_t_s[0]
        clock.seg_count, clock.seg_best_u_s = 0, math.inf
        if len(clock.env_k) >= 2:
            clock.k_ref, clock.offset_s, clock.period_s = fit_lower_envelope(
                clock.env_k, clock.env_t_s, clock.period_nominal_s)
            clock.fitted = True
    return Observation.OK


def fit_lower_envelope(k: list[int], t_s: list[float],
                       period_nominal_s: float) -> tuple[int, float, float]:
    """Support line of the lower convex hull of the points (k, t_s) at their mean k.

    ``k`` and ``t_s`` are (n,) with n >= 2 distinct indices. Returns ``(k_ref, offset_s,
    period_s)`` with ``k_ref`` the newest index: ``t(k) = offset_s + (k - k_ref) *
    period_s``. The period is clamped to nominal +- :data:`MAX_DRIFT_PPM`.
    """
    k0, t0 = k[0], t_s[0]
    lowest: dict[int, float] = {}
    for ki, ti in zip(k, t_s, strict=True):
        x = ki - k0
        y = ti - t0 - x * period_nominal_s      # detrended: microseconds, well conditioned
        if x not in lowest or y < lowest[x]:
            lowest[x] = y
    pts = sorted(lowest.items())
    hull: list[tuple[int, float]] = []
    for p in pts:
        while len(hull) >= 2:
            (ox, oy), (ax, ay) = hull[-2], hull[-1]
            if (ax - ox) * (p[1] - oy) - (ay - oy) * (p[0] - ox) <= 0.0:
                hull.pop()
            else:
                break
        hull.append(p)
    x_mean = sum(x for x, _ in pts) / len(pts)
    if len(hull) == 1:
        slope, y_mean = 0.0, hull[0][1]
    else:
        i = 0
        while i < len(hull) - 2 and hull[i + 1][0] < x_mean:
            i += 1
        (x1, y1), (x2, y2) = hull[i], hull[i + 1]
        slope = (y2 - y1) / (x2 - x1)
        y_mean = y1 + slope * (x_mean - x1)
    limit = MAX_DRIFT_PPM * 1e-6 * period_nominal_s
    slope = min(max(slope, -limit), limit)
    k_ref = max(k)
    x_ref = k_ref - k0
    offset_s = t0 + x_ref * period_nominal_s + y_mean + slope * (x_ref - x_mean)
    return k_ref, offset_s, period_nominal_s + slope
