"""A damper the confirmation's search picks over the crossing's keeps a runner-up.

The detection study's record of seed 6908 (Csy x 0.25 at 8.025 s, 5 sensors, the
service's filter at m = 1000; fresh in 2026-11-30's seventeenth session): the watch
confirmed a Csy drop a quarter second after the step, and the change-time search over
the look-back summed 116 nats for a Csay drop, more than for any Csy grid. Until that
session the search's pick was located as a runner-up is, with none after it: the Csay
location found nothing, the bank watched again from scratch with its look-back
restarted after the change, and Csy was detected 2.27 s after the step, located at 0.41
x its value, its likelihood interval (0-0.117 of nominal) missing the truth. Now a
runner-up stays pending for it: the Csy drop's search from the same look-back, with the
second since, sums 1067 nats and is located from its change time.
"""

from __future__ import annotations

import pytest

from firmware_sim.studies.detection import fault_row
from gateway.estimator.faultbank import FaultBankConfig


@pytest.mark.slow
def test_a_location_the_search_picked_that_finds_nothing_hands_over_to_the_runner_up(
        ) -> None:
    assert FaultBankConfig().located_by == "search" and FaultBankConfig().runner_up
    row = fault_row(0, 0.25, 5, 6908, seconds=12.0, fault_at_s=8.025)
    assert [d[1] for d in row["detections"]] == ["csy_ns_per_m"], row   # Csy, once
    assert row["detect_s"] <= 1.5 and row["alert_s"] <= 1.5, row
    assert row["alarm_s"] is not None and row["alarm_s"] <= 1.5, row   # x 0.25 warrants one
    assert 0.8 <= row["located_rel"] <= 1.25, row
    lo, hi = row["located_like"]                       # the first interval holds the truth
    assert lo <= 0.25 <= hi, row
    assert row["wrong"] == 0 and row["alerts_healthy"] == 0 and row["before"] == 0, row
