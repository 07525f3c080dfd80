"""Data lost on the way in reaches the journal: where, how much, rate-limited."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from test_service import Running, _wait

from gateway.service.losses import LossCounts, LossLog


def test_the_first_loss_is_said_at_once_then_at_most_once_per_interval():
    log = LossLog(every_s=60.0)
    assert log.line(LossCounts(0, 0, 0), 0.0) is None            # nothing lost
    first = log.line(LossCounts(12, 0, 0), 1.0)
    assert first is not None and first.startswith("data lost: 12 CAN frames dropped by "
                                                  "the kernel")
    assert "queue" not in first
    assert log.line(LossCounts(40, 3, 0), 30.0) is None          # inside the interval
    later = log.line(LossCounts(40, 3, 7), 61.0)                  # what grew since 1.0 s
    assert later is not None and later.startswith("data lost in the last 60 s: 28 CAN "
                                                  "frames dropped by the kernel")
    assert "; 3 CAN frames dropped at the full receive queue" in later
    assert "; 7 grid samples dropped at the full estimator queue" in later
    assert log.line(LossCounts(40, 3, 7), 200.0) is None          # nothing new: silent


def test_a_bad_interval_is_refused():
    with pytest.raises(ValueError, match="expected a positive warning interval in s, got 0"):
        LossLog(every_s=0.0)


def test_the_live_service_writes_kernel_drops_to_its_log(tmp_path: Path, caplog):
    caplog.set_level(logging.WARNING, logger="gateway.service.daemon")

    def said() -> list[str]:
        return [r.getMessage() for r in caplog.records if r.getMessage().startswith("data lost")]

    with Running(tmp_path, "losses", particles=32) as run:
        # what BusSource does when SO_MEMINFO reports drops for its socket
        run.service.source.stats.dropped_kernel += 5
        assert _wait(lambda: bool(said()), 10)
    assert said()[0].startswith("data lost: 5 CAN frames dropped by the kernel")
