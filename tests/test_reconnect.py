"""The one reopen-with-backoff rule (gateway.reconnect), driven by a recording wait."""

from __future__ import annotations

import threading

import pytest

from gateway.reconnect import Backoff


def _recorder() -> tuple[list[float], Backoff]:
    waited: list[float] = []
    return waited, Backoff(0.2, 1.0, wait=waited.append)


def test_pauses_double_from_min_and_stop_at_max() -> None:
    waited, backoff = _recorder()
    for _ in range(6):
        backoff.pause()
    assert waited == [0.2, 0.4, 0.8, 1.0, 1.0, 1.0]
    assert backoff.delay_s == 1.0


def test_reset_after_a_success_starts_again_at_min() -> None:
    waited, backoff = _recorder()
    backoff.pause()
    backoff.pause()
    backoff.reset()
    backoff.pause()
    assert waited == [0.2, 0.4, 0.2]


def test_delay_s_is_the_next_pause_so_it_can_be_logged_first() -> None:
    waited, backoff = _recorder()
    logged = []
    for _ in range(3):
        logged.append(backoff.delay_s)
        backoff.pause()
    assert logged == waited == [0.2, 0.4, 0.8]


@pytest.mark.parametrize(("min_s", "max_s"), [(0.0, 1.0), (-1.0, 1.0), (2.0, 1.0)])
def test_bad_bounds_are_refused_with_the_values(min_s: float, max_s: float) -> None:
    with pytest.raises(ValueError, match=rf"expected 0 < reopen_min_s <= reopen_max_s, "
                                         rf"got {min_s}, {max_s}"):
        Backoff(min_s, max_s, wait=lambda _s: None)


def test_a_stop_event_cuts_the_pause_short() -> None:
    stop = threading.Event()
    stop.set()
    backoff = Backoff(600.0, 600.0, wait=stop.wait)   # would hang for 10 min if not cut
    backoff.pause()
    assert backoff.delay_s == 600.0


def test_both_reopening_threads_use_it() -> None:
    """The CAN source and the console port take their delays from this one rule."""
    from gateway.can.source import BusSource
    from gateway.console.port import ConsolePort

    with pytest.raises(ValueError, match="expected 0 < reopen_min_s"):
        BusSource(lambda: None, reopen_min_s=0.0)  # type: ignore[arg-type, return-value]
    with pytest.raises(ValueError, match="expected 0 < reopen_min_s"):
        ConsolePort(None, "/dev/null", reopen_min_s=3.0,  # type: ignore[arg-type]
                    reopen_max_s=1.0)
