"""A change-time search hands its change times to the location it picks.

From the watch (``located_by = "search"``) a confirmation first runs the change-time
search of each damper's drop and rise over the look-back (:meth:`FaultBank._best_search`)
and then locates the winner, replaying from its change time; a runner-up is searched
for and located the same way. Before 2026-11-30's seventeenth session the location
searched that change time again (the same grid, the same snapshots, the same samples):
one repeated search per location. This checks, on two records of the detection study
(Csy x 0.25 at 8.025 s, 5 sensors, the service's filter at m = 1000): seed 6611, located
at once by the search, and seed 6908, whose search picked Csay and whose runner-up then
located Csy (tests/test_search_keeps_a_runner_up.py), that no location searches again,
and that every location and the row come out exactly as with the search repeated.
Since 2026-11-30's twentieth session a search tries the Page starts of every grid it
compares (:meth:`FaultBank._glr_best`), so the repeated search is given the same ones.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np
import pytest

from firmware_sim.studies.detection import fault_row
from firmware_sim.studies.filtering import FilterOptions
from gateway.estimator.faultbank import FaultBank


def _run(monkeypatch: pytest.MonkeyPatch, seed: int, gain_fit: bool | None, repeat: bool
         ) -> tuple[dict, list, int, int]:
    """The record's row, every location's outcome, the change-time searches run, and the
    locations that replayed from a search's change time (``repeat``: searched again)."""
    located: list[Any] = []
    calls = {"search": 0, "handed": 0}
    glr_best, glr_start, locate_now = (FaultBank._glr_best, FaultBank._glr_start,
                                       FaultBank._locate_now)

    pages: list[Any] = [()]

    def counted_best(self: FaultBank, starts: list, *args: Any) -> tuple[int, float]:
        calls["search"] += 1
        if args:                               # a search's: the grids' Page starts
            pages[0] = args[0]
        return glr_best(self, starts, *args)

    def start(self: FaultBank, starts: list, change_at: int | None = None) -> Any:
        calls["handed"] += change_at is not None
        if repeat and change_at is not None:   # the same search again, from its pages
            change_at = counted_best(self, starts, pages[0])[0]
        return glr_start(self, starts, change_at)

    def recorded(self: FaultBank, *args: Any) -> Any:
        det = locate_now(self, *args)
        located.append(det)
        return det

    monkeypatch.setattr(FaultBank, "_glr_best", counted_best)
    monkeypatch.setattr(FaultBank, "_glr_start", start)
    monkeypatch.setattr(FaultBank, "_locate_now", recorded)
    row = fault_row(0, 0.25, 5, seed, seconds=10.0, fault_at_s=8.025,
                    options=FilterOptions(gain_fit=gain_fit))
    monkeypatch.undo()
    return row, located, calls["search"], calls["handed"]


@pytest.mark.slow
@pytest.mark.parametrize("seed, locations, gain_fit", [
    (6611, 1, None),     # the first location
    (6908, 2, False)])   # the runner-up's: found with every particle's gains solved
def test_the_location_starts_at_the_searchs_change_time_without_searching_again(
        monkeypatch: pytest.MonkeyPatch, seed: int, locations: int,
        gain_fit: bool | None) -> None:
    row, located, searches, handed = _run(monkeypatch, seed, gain_fit, repeat=False)
    old_row, old_located, old_searches, old_handed = _run(monkeypatch, seed, gain_fit,
                                                          repeat=True)
    assert row["detect_s"] is not None and row["detect_s"] <= 1.5, row   # found at once
    assert row["wrong"] == 0 and row["alerts_healthy"] == 0, row
    # every location computed (a rescan computes one again) started where a search ended
    assert len(located) == len(old_located) == handed == old_handed >= locations
    assert searches == old_searches - handed                    # one search fewer each
    for det, old in zip(located, old_located, strict=True):
        assert (det is None) == (old is None)
        for f in fields(det) if det is not None else ():
            a, b = getattr(det, f.name), getattr(old, f.name)
            assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, f.name
    for key in set(row) | set(old_row):
        if key != "wall_s":
            assert row.get(key) == old_row.get(key), key
