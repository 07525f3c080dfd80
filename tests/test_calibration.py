"""The calibration study's short form (issue 15): the stated sigma against the truth
and against the maximum-likelihood sigma on the same record, and start-up inside the
prior box (``firmware_sim.studies.calibration``; the campaign is in docs/estimator.md,
"Calibration of the stated sigma")."""

from __future__ import annotations

import pytest

from firmware_sim.studies.calibration import box_theta, rows_for, summary
from gateway.estimator.rbpf_config import RBPFConfig


@pytest.mark.slow
@pytest.mark.parametrize("sensors, seed", [(3, 21), (5, 22)])
def test_stated_sigma_covers_the_truth_and_is_not_below_the_ml_sigma(sensors: int,
                                                                      seed: int) -> None:
    """Paper scenario, 20 s, the service's filter, fresh seeds: every parameter within
    3 stated sigma of the truth, and sigma at least 0.8 x the ML sigma on the same record
    (the issue's ratio criterion).

    The issue's 2-sigma criterion is a coverage share over >= 20 records (the campaign);
    a calibrated filter fails "all three within 2 sigma" on about 1 record in 7, so one
    record cannot test it (seed 22 here has Csay at -2.4 sigma). 3 sigma on one record
    fails about 1 in 120 when calibrated, and catches lock-in (6-7 sigma at 5 s)."""
    (row,) = rows_for("paper", seed, sensors, 1000, "fast", ml=True, at_s=(20.0,))
    assert all(abs(z) <= 3.0 for z in row["z"]), row
    assert all(r >= 0.8 for r in row["sigma_over_ml"]), row
    # the ML fit itself is sane on this record (else the ratio means nothing)
    assert all(abs(z) <= 3.0 for z in row["ml_z"]), row


@pytest.mark.slow
def test_the_service_filter_holds_a_start_up_outlier_record() -> None:
    """5 sensors, paper scenario, the campaign's worst record (seed 10, 20 s long) read at
    5 s. Without the start's likelihood ramp and with whole states at the moves (the
    service's filter until 2026-11-25) it is an outlier: Csy 6.6-7.1 sigma from the
    truth. The service's filter today (the ramp, the static-yaw component dropped at the
    moves) is within 4 sigma on every parameter, the issue's bound for a single case.

    Until 2026-11-26 this test also required the moves' static-yaw step alone (no ramp)
    to bring Csy within 3 sigma. That held with OpenBLAS's SkylakeX kernels (Csy 1.0,
    lambda 3.9 sigma) and not with its Haswell kernels (Csy 5.0, lambda 4.6 sigma): one
    record's Monte Carlo path, moved by the rounding of another BLAS kernel. The outcome
    of both the service's filter and the whole-state filter is the same with both
    kernels (docs/estimator.md "Calibration of the stated sigma")."""
    at = (5.0, 20.0)                      # the record's length decides its noise draw
    service = rows_for("paper", 10, 5, 1000, "fast", ml=False, at_s=at)[0]
    assert service["moves_drop_null"] and service["start_ramp_s"] > 0
    assert service["t_s"] == 5.0 and all(abs(z) <= 4.0 for z in service["z"]), service
    whole = rows_for("paper", 10, 5, 1000, "fast", ml=False, at_s=at, moves_drop_null=False,
                     start_ramp_s=0.0, start_ramp_m=0.0)[0]
    assert abs(whole["z"][0]) > 4.0, whole


@pytest.mark.slow
def test_start_up_anywhere_in_the_prior_box() -> None:
    """Two parameter sets drawn over the prior box, 3 and 5 sensors, 10 s: no parameter
    beyond 4 sigma of the truth (the issue's bound), and the summary counts them."""
    rows = [row for seed, ns in ((51, 3), (52, 5))
            for row in rows_for("box", seed, ns, 1000, "fast", ml=False)]
    assert len(rows) == 2
    for row in rows:
        assert all(abs(z) <= 4.0 for z in row["z"]), row
    assert {s["sensors"] for s in summary(rows)} == {3, 5}


def test_box_draws_lie_in_the_prior_box() -> None:
    cfg = RBPFConfig(fs_hz=1000.0)
    lo, hi = cfg.box(cfg.prior_lo, cfg.prior_hi)
    for seed in range(1, 40):
        th = box_theta(seed)
        assert ((th >= lo) & (th <= hi)).all(), (seed, th)
    assert not (box_theta(1) == box_theta(2)).all()


def test_a_record_from_rest_is_another_truth_start_and_the_default_is_unchanged() -> None:
    """``record`` gives the simulator's usual truth (stationary vibration from the first
    sample: ``measured``, bit for bit) unless ``from_rest``; then the truth starts at
    rest and the first samples are sensor noise about zero (the states build up), while
    the running vehicle's are not. The summary keeps the two apart."""
    import numpy as np

    from firmware_sim.studies.calibration import record
    from firmware_sim.truth import measured
    from gateway.model.vehicle import THETA_SEC42, measurement_noise, sensor_set

    theta, n = THETA_SEC42.as_array(), 500
    running = record(theta, 3, 7, n / 1000.0)
    same = measured(np.repeat(theta[None], n, 0), np.full(n, 42.5), 1000.0, sensor_set(3),
                    np.random.default_rng(7))
    assert np.array_equal(running, same)
    rest = record(theta, 3, 7, n / 1000.0, from_rest=True)
    noise_sd = np.sqrt(np.diag(measurement_noise(3)))
    first = slice(0, 5)           # 5 ms: a vehicle at rest has not moved yet
    assert np.all(np.abs(rest[first]) < 5 * noise_sd)
    assert np.sqrt(np.mean(running[first] ** 2, axis=0)).max() > \
        np.sqrt(np.mean(rest[first] ** 2, axis=0)).max()
    rows = [{"study": "paper", "sensors": 3, "t_s": 5.0, "z": [0.0, 0.0, 0.0],
             "from_rest": fr} for fr in (False, True)]
    assert [r["from_rest"] for r in summary(rows)] == [False, True]
