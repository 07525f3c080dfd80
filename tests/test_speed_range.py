"""Faults found, and healthy running quiet, at the edges of the gate's speed range.

Every other detection test runs at the paper's 42.5 m/s. The service estimates from
15 to 70 m/s (``[gating]``), and the information a record carries changes with the
speed (the track input grows with v², the creep terms fall with 1/v). The campaign's
short form at 20 and 70 m/s: simulator truth, the service's filter (fast mode,
m = 1000, fault bank), fresh data seeds, the issue's targets as bounds
(docs/estimator.md "Other speeds").
"""

from __future__ import annotations

import pytest

from firmware_sim.scenarios import V_PAPER
from firmware_sim.studies.detection import fault_row, nominal_row
from firmware_sim.studies.detection_report import summary


def test_the_detection_summary_keeps_speeds_apart() -> None:
    """Rows at two speeds are two cases; a row written before the speed column counts
    at the paper's speed."""
    def row(speed_mps: float | None, alert_s: float) -> dict:
        r = {"what": "fault", "parameter": "csy_ns_per_m", "factor": 0.5, "sensors": 3,
             "detect_s": 1.0, "track_s": 2.0, "alert_s": alert_s, "alarm_s": None,
             "alert_estimates_only_s": alert_s, "wrong": 0, "before": 0}
        return r if speed_mps is None else {**r, "speed_mps": speed_mps}

    out = summary([row(20.0, 4.0), row(20.0, 6.0), row(None, 1.0), row(42.5, 2.0)])
    assert [(c["speed_mps"], c["runs"], c["alert_s_median"], c["alert_s_worst"])
            for c in out] == [(20.0, 2, 5.0, 6.0), (V_PAPER, 2, 1.5, 2.0)]


def test_the_detection_summary_counts_intervals_that_hold_the_truth_and_overstated_levels(
        ) -> None:
    """Csy at 0.6 of nominal warrants an ADVISORY (below 0.75), not a WARNING (0.55): a
    run that raised a WARNING counts as past the truth, under the rule that raised it;
    an interval that misses 0.6 does not count as held."""
    base = {"what": "fault", "parameter": "csy_ns_per_m", "factor": 0.6, "sensors": 3,
            "speed_mps": 42.5, "detect_s": 1.0, "track_s": 2.0, "alert_s": 1.1,
            "alarm_s": None, "alert_estimates_only_s": 1.6, "alert_on_range_s": 1.1,
            "alarm_on_range_s": None, "wrong": 0, "before": 0}
    rows = [{**base, "located_like": [0.4, 0.7], "severity_max": "ADVISORY",
             "severity_max_on_range": "WARNING"},
            {**base, "located_like": [0.62, 0.9], "severity_max": None,
             "severity_max_on_range": "ADVISORY"},
            {**base, "located_like": None, "severity_max": None,
             "severity_max_on_range": None}]
    (case,) = summary(rows)
    assert (case["located"], case["like_held"]) == (2, 1)
    assert (case["severity_past_truth"], case["severity_past_truth_on_range"]) == (0, 1)
    assert case["alert_on_range_s_median"] == 1.1


@pytest.mark.slow
@pytest.mark.parametrize("speed_mps, parameter, factor, seed",
                         [(20.0, 0, 0.25, 791), (70.0, 1, 0.3, 792)])
def test_a_failed_damper_is_alerted_and_tracked_at_the_speed_limits(
        speed_mps: float, parameter: int, factor: float, seed: int) -> None:
    """A damper step at 8 s, 3 sensors: the first alert on the right parameter within 5 s,
    none on a healthy one, and the estimate within 15 % of the new value from +10 s at
    the latest (issue 15's worst-case targets)."""
    row = fault_row(parameter, factor, 3, seed, seconds=18.0, fault_at_s=8.0,
                    speed_mps=speed_mps)
    assert row["speed_mps"] == speed_mps
    assert row["detect_s"] is not None, row
    assert row["alert_s"] is not None and row["alert_s"] <= 5.0, row
    assert row["wrong"] == 0 and row["before"] == 0, row
    assert row["alerts_healthy"] == 0 and row["alerts_before"] == 0, row
    assert row["track_s"] is not None and row["track_s"] <= 10.0, row


@pytest.mark.slow
@pytest.mark.parametrize("speed_mps, seed", [(20.0, 793), (70.0, 794)])
def test_a_healthy_vehicle_raises_nothing_at_the_speed_limits(speed_mps: float,
                                                              seed: int) -> None:
    """60 s of nominal data, 3 sensors: no detection, no alert, no monitor alarm, and the
    estimate ends within 3 sigma of the truth."""
    row = nominal_row(3, seed, seconds=60.0, speed_mps=speed_mps)
    assert row["detections"] == 0 and row["alerts"] == 0, row
    assert row["monitor_alarms"] == 0, row
    assert max(abs(z) for z in row["final_z"]) < 3.0, row
