"""The innovation monitor on known input: chi-square NIS (no alarm), a shifted NIS (alarm)."""

from __future__ import annotations

import numpy as np

from gateway.estimator.monitor import MonitorConfig, after_reseed, cusum, initial_state, update


def feed(cfg: MonitorConfig, state: np.ndarray, nis: np.ndarray, dof: int) -> list[int]:
    return [k for k, v in enumerate(nis) if update(cfg, state, float(v), dof)]


def test_ten_minutes_of_calibrated_innovations_raise_no_alarm() -> None:
    cfg = MonitorConfig()
    state = initial_state()
    nis = np.random.default_rng(0).chisquare(3, size=600_000)       # 10 min at 1 kHz
    assert feed(cfg, state, nis, 3) == []
    assert cusum(state) < cfg.h_sigma


def test_a_twenty_percent_rise_is_flagged_within_three_seconds() -> None:
    cfg = MonitorConfig()
    state = initial_state()
    rng = np.random.default_rng(1)
    settle = (cfg.warmup_blocks + cfg.learn_blocks) * cfg.block_len
    assert feed(cfg, state, rng.chisquare(3, size=settle + 5000), 3) == []
    alarms = feed(cfg, state, 1.2 * rng.chisquare(3, size=3000), 3)
    assert alarms and alarms[0] < 3000


def test_an_imperfect_model_raises_the_baseline_not_alarms() -> None:
    """A constant 10 % excess (model mismatch) from the start is learned, not flagged."""
    cfg = MonitorConfig()
    state = initial_state()
    nis = 1.1 * np.random.default_rng(2).chisquare(3, size=120_000)
    assert feed(cfg, state, nis, 3) == []


def test_after_reseed_keeps_the_learned_baseline() -> None:
    cfg = MonitorConfig()
    state = initial_state()
    rng = np.random.default_rng(3)
    feed(cfg, state, 1.1 * rng.chisquare(3, size=60_000), 3)
    mu = state[5]
    after_reseed(state)
    assert state[5] == mu and cusum(state) == 0.0
    # no learning phase again: the same excess is tested right after the warm-up
    nis = 1.1 * rng.chisquare(3, size=(cfg.warmup_blocks + 5) * cfg.block_len)
    assert feed(cfg, state, nis, 3) == []
