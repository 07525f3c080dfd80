"""The calibration study's short form (issue 15): the stated sigma against the truth
and against the maximum-likelihood sigma on the same record, and start-up inside the
prior box (``firmware_sim.studies.calibration``; the campaign is in docs/estimator.md,
"Calibration of the stated sigma")."""

from __future__ import annotations

import pytest

from firmware_sim.studies.calibration import box_theta, main, rows_for, summary, window
from gateway.estimator.rbpf_config import PAPER_DELTA, RBPFConfig


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
    service's filter until 2026-11-25, with the paper's kernel discount 0.99) it is an
    outlier: Csy 6.6-7.1 sigma from the truth. The service's filter today (the ramp, the
    static-yaw component dropped at the moves, the discount 0.999) is within 4 sigma on
    every parameter, the issue's bound for a single case. (The discount 0.999 alone,
    with whole states and no ramp, also brings this record's Csy to 2.0 sigma.) The
    control runs that old filter with its prior too, the paper's box from 0.3 x, pinned:
    with the dampers' edge at 0.1 (the service's from 500 particles since 2026-11-29's
    thirteenth session) its first draw, and so its path on this record, is another one
    (Csy 0.1 sigma).

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
                     start_ramp_s=0.0, start_ramp_m=0.0, kernel_delta=PAPER_DELTA,
                     prior_lo=(0.3, 0.3, 0.3))[0]
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


def _row(seed: int, t_s: float, z: list[float], theta_name: str = "nominal") -> dict:
    return {"study": "paper", "theta_name": theta_name, "sensors": 3, "seed": seed,
            "t_s": t_s, "z": z, "err_pct": [2 * v for v in z]}


def test_window_averages_each_record_over_its_check_times_then_over_records() -> None:
    """A bias over minutes is each record's z averaged over the window, then over the
    records: seed 1 averages -1 and 0 to -0.5, seed 2 averages 1 and 2 to 1.5, so the
    mean is 0.5 with a standard error of 1.0; the check at 10 s lies outside [60, 120]
    and the paper vehicle's rows are another case."""
    rows = [_row(1, 10.0, [9.0] * 3), _row(1, 60.0, [-1.0] * 3), _row(1, 120.0, [0.0] * 3),
            _row(2, 60.0, [1.0] * 3), _row(2, 120.0, [2.0] * 3),
            _row(3, 60.0, [-5.0] * 3, theta_name="paper")]
    nominal, paper = sorted(window(rows, 60.0, 120.0), key=lambda r: r["theta_name"])
    assert (nominal["records"], nominal["checks"], paper["records"]) == (2, 2, 1)
    assert nominal["conicity_mean_z"] == 0.5 and nominal["conicity_se_z"] == 1.0
    assert nominal["conicity_mean_err_pct"] == 1.0 and nominal["conicity_below"] == 1
    assert paper["conicity_mean_z"] == -5.0 and paper["conicity_se_z"] is None
    assert [r["theta_name"] for r in summary(rows)].count("nominal") == 3


@pytest.mark.parametrize("argv, expected", [
    (["window", "60"], "expected window LO HI"),
    (["window", "120", "60"], "expected window LO HI"),
    (["summary", "60", "120"], "expected LO HI only with window"),
    (["box", "--theta", "nominal"], "expected --theta only with paper")])
def test_the_study_refuses_a_wrong_window_or_vehicle_in_one_line(
        argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ex:
        main(argv)
    assert ex.value.code == 2
    assert expected in capsys.readouterr().err


def test_the_paper_study_runs_the_nominal_vehicle_when_asked() -> None:
    """``--theta nominal``: the record is made at the service's nominal vehicle and the
    row says so; the default stays the paper's Sec. 4.2 vehicle."""
    from gateway.model.vehicle import THETA_NOMINAL, THETA_SEC42

    (nominal,) = rows_for("paper", 5, 3, 64, "fast", ml=False, at_s=(0.5,),
                          theta_name="nominal")
    (paper,) = rows_for("paper", 5, 3, 64, "fast", ml=False, at_s=(0.5,))
    assert nominal["truth"] == THETA_NOMINAL.as_array().tolist()
    assert paper["truth"] == THETA_SEC42.as_array().tolist()
    assert (nominal["theta_name"], paper["theta_name"]) == ("nominal", "paper")
    assert nominal["mean"] != paper["mean"]


def test_the_study_runs_a_truth_whose_track_input_is_held_when_asked(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``--track-input held``: the record's truth takes the paper's literal input
    convention (another realisation: the draws differ), the row says so, and the
    summary keeps it apart from the default white input's rows."""
    import json

    rows = {}
    for track_input in ("held", "white"):
        assert main(["paper", "--seeds", "5", "--sensors", "3", "--particles", "64",
                     "--at-s", "0.5", "--no-ml", "--track-input", track_input]) == 0
        (rows[track_input],) = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert (rows["held"]["track_input"], rows["white"]["track_input"]) == ("held", "white")
    assert rows["held"]["mean"] != rows["white"]["mean"]
    assert sorted(r["track_input"] for r in summary(list(rows.values()))) == ["held", "white"]
