"""The oracle study (:mod:`firmware_sim.studies.oracle`): a known change is found at once
by the true post-fault model and not by a wrong one; healthy data favour no change."""

from __future__ import annotations

import pytest

from firmware_sim.studies.oracle import H_NATS, main, oracle_rows


def test_the_true_change_crosses_and_a_wrong_direction_does_not():
    rows = oracle_rows(1, 0.3, 5, seed=1, hypotheses=[0.3, 2.5], fault_at_s=2.0,
                       after_s=1.0)
    true, wrong = rows
    assert true["hypothesis"] == 0.3 and true["cross_s"] is not None
    assert 0 < true["cross_s"] < 1.0 and true["llr_end"] > H_NATS
    assert wrong["cross_s"] is None and wrong["llr_end"] < 0


def test_healthy_data_favour_no_change():
    rows = oracle_rows(0, 1.0, 3, seed=2, hypotheses=[0.5, 2.0], fault_at_s=2.0,
                       after_s=1.0)
    for row in rows:
        assert row["cross_s"] is None and row["llr_end"] < 0, row


def test_ratios_against_the_true_value_favour_it():
    """Against the true post-fault model the truth sums to nothing and another value
    loses; against the old value the truth wins (the default baseline)."""
    same, other = oracle_rows(1, 0.3, 5, seed=1, hypotheses=[0.3, 0.6], fault_at_s=2.0,
                              after_s=1.0, against=0.3)
    assert same["against"] == 0.3 and same["llr_end"] == 0.0 and same["cross_s"] is None
    assert other["llr_end"] < -H_NATS
    (plain,) = oracle_rows(1, 0.3, 5, seed=1, hypotheses=[0.6], fault_at_s=2.0,
                           after_s=1.0)
    assert plain["against"] == 1.0 and plain["llr_end"] > other["llr_end"]


def test_bad_settings_are_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--after", "0"])
    assert exc.value.code == 2
    assert "expected --fault-at, --after, --h-nats and --noise-scale > 0" in \
        capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--against", "0"])
    assert "expected --against > 0, got 0.0" in capsys.readouterr().err
