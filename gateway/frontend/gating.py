"""Gating on operating conditions: GridSample in, the estimator's records.Sample out.

:meth:`Gate.apply` turns each grid point into a :class:`~gateway.records.Sample` with
the estimator's sensors (3 -> acc_b, gyro_b, acc_bd; 5 -> SENSORS_5), their values NaN
unless the quality is OK (or SUSPECT, if ``use_suspect``). ``update`` is True only when
all of these hold, checked in this order; the first that fails is the sample's gating
*reason*:

1. ``no_speed``: the speed is known (finite). Otherwise the sample carries the last
   valid speed, or the default speed before any, because the estimator must
   predict with some speed; it never updates until a valid speed arrives.
2. ``speed_low`` / ``speed_high``: ``speed_min_mps <= v <= speed_max_mps``.
3. ``no_yaw_rate``: the low-passed yaw rate was finite within the last ``yaw_hold_s``.
   A shorter yaw-rate gap keeps the last straight/curve decision.
4. ``curve``: straight track. The curve detector watches the low-passed yaw rate
   through the curve-level ``max(|yaw_rate_lp| * v / curve_lat_acc_mps2,
   |yaw_rate_lp| / curve_yaw_rate_max_radps)`` (terms set to None are left out;
   ``|yaw_rate_lp| * v`` is the lateral acceleration, m/s^2). It enters a curve when
   the level reaches 1 and leaves it when the level falls below ``curve_exit_ratio``
   (hysteresis); after leaving, the track counts as straight only once
   ``straight_hold_s`` has passed.
5. ``no_sensor``: at least one of the estimator's sensors is usable.

Otherwise the reason is ``updated``. Counts by reason are kept; the state is a plain
picklable dataclass. No I/O, no clocks: time is the sample's ``t_s``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from gateway.errors import ConfigError, StateError
from gateway.model.vehicle import SENSORS_5, sensor_set
from gateway.records import GridSample, Quality, Sample

REASONS: tuple[str, ...] = ("updated", "no_speed", "speed_low", "speed_high", "no_yaw_rate",
                            "curve", "no_sensor")
"""Gating reasons, in the order they are checked (``updated``: not gated)."""


@dataclass(frozen=True)
class GateConfig:
    """Gating settings. ``sensors`` 3 or 5. ``default_speed_mps`` is the speed handed to
    the estimator before any valid speed was received; None means the middle of the
    speed window (45 m/s with the defaults)."""

    sensors: int
    speed_min_mps: float = 20.0
    speed_max_mps: float = 70.0
    curve_lat_acc_mps2: float | None = 0.25
    curve_yaw_rate_max_radps: float | None = None
    curve_exit_ratio: float = 0.5
    straight_hold_s: float = 2.0
    yaw_hold_s: float = 1.0
    default_speed_mps: float | None = None
    use_suspect: bool = False

    def __post_init__(self) -> None:
        if self.sensors not in (3, 5):
            raise ConfigError(f"expected sensors 3 or 5, got {self.sensors}")
        if not 0 <= self.speed_min_mps < self.speed_max_mps:
            raise ConfigError(f"expected 0 <= speed_min_mps < speed_max_mps, got "
                              f"{self.speed_min_mps}, {self.speed_max_mps}")
        if self.default_speed_mps is not None and not self.default_speed_mps > 0:
            raise ConfigError(f"expected default_speed_mps > 0 or None, got "
                              f"{self.default_speed_mps}")
        limits = (self.curve_lat_acc_mps2, self.curve_yaw_rate_max_radps)
        if all(x is None for x in limits) or any(x is not None and not x > 0 for x in limits):
            raise ConfigError(f"expected curve_lat_acc_mps2 and/or curve_yaw_rate_max_radps "
                              f"> 0, got {limits}")
        if not 0 < self.curve_exit_ratio <= 1:
            raise ConfigError(f"expected 0 < curve_exit_ratio <= 1, got {self.curve_exit_ratio}")
        if self.straight_hold_s < 0 or self.yaw_hold_s < 0:
            raise ConfigError(f"expected straight_hold_s >= 0 and yaw_hold_s >= 0, got "
                              f"{self.straight_hold_s}, {self.yaw_hold_s}")


@dataclass
class GatingState:
    """What the gate carries between samples (pickle it to checkpoint)."""

    config: GateConfig
    last_speed_mps: float = math.nan
    in_curve: bool = False
    straight_since_s: float = -math.inf
    """When the last curve was left; the hold runs from here."""
    yaw_seen_s: float = -math.inf
    """Data time of the last finite low-passed yaw rate."""
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REASONS, 0))


class Gate:
    """Turns grid samples into estimator samples, deciding update vs predict-only."""

    def __init__(self, config: GateConfig, state: GatingState | None = None) -> None:
        if state is None:
            state = GatingState(config)
        elif state.config != config:
            raise StateError(f"expected a gating state saved with {config}, "
                             f"got one saved with {state.config}")
        self.config = config
        self._st = state
        self._cols = np.array([SENSORS_5.index(s) for s in sensor_set(config.sensors)])
        self._use_suspect = config.use_suspect
        self._default_speed_mps = config.default_speed_mps if config.default_speed_mps \
            is not None else 0.5 * (config.speed_min_mps + config.speed_max_mps)

    @property
    def counts(self) -> dict[str, int]:
        """Samples seen per reason (a copy)."""
        return dict(self._st.counts)

    def snapshot(self) -> GatingState:
        """A deep copy of the state, for checkpoints (restore: ``Gate(config, state)``)."""
        return copy.deepcopy(self._st)

    def reason(self, g: GridSample, usable: np.ndarray) -> str:
        """Advance the curve detector with ``g`` and name its gating reason.

        ``usable`` (ny,) bool marks the estimator's sensors with a usable value.
        """
        cfg, st = self.config, self._st
        v = g.speed_mps
        speed_ok = math.isfinite(v)
        if speed_ok:
            st.last_speed_mps = v
        v_used = st.last_speed_mps if math.isfinite(st.last_speed_mps) \
            else self._default_speed_mps
        yaw = abs(g.yaw_rate_lp_radps)
        if math.isfinite(yaw):
            st.yaw_seen_s = g.t_s
            level = 0.0
            if cfg.curve_lat_acc_mps2 is not None:
                level = yaw * v_used / cfg.curve_lat_acc_mps2
            if cfg.curve_yaw_rate_max_radps is not None:
                level = max(level, yaw / cfg.curve_yaw_rate_max_radps)
            if st.in_curve and level < cfg.curve_exit_ratio:
                st.in_curve, st.straight_since_s = False, g.t_s
            elif not st.in_curve and level >= 1.0:
                st.in_curve = True
        if not speed_ok:
            return "no_speed"
        if v < cfg.speed_min_mps:
            return "speed_low"
        if v > cfg.speed_max_mps:
            return "speed_high"
        if g.t_s - st.yaw_seen_s > cfg.yaw_hold_s:
            return "no_yaw_rate"
        if st.in_curve or g.t_s - st.straight_since_s < cfg.straight_hold_s:
            return "curve"
        if not usable.any():
            return "no_sensor"
        return "updated"

    def apply(self, g: GridSample) -> Sample:
        """The estimator's sample for grid point ``g``; counts its reason."""
        quality = g.quality[self._cols]
        usable = quality == Quality.OK
        if self._use_suspect:
            usable |= quality == Quality.SUSPECT
        values = np.where(usable, g.values[self._cols], np.nan)
        why = self.reason(g, usable)
        self._st.counts[why] += 1
        v = self._st.last_speed_mps
        speed = v if math.isfinite(v) else self._default_speed_mps
        return Sample(g.t_s, values, speed, why == "updated")
