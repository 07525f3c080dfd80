"""The exact-posterior study (``firmware_sim.studies.grid_posterior``): the static-theta
posterior on a log grid, the reference for the filter's stated sigma (issue 15)."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.calibration import SEED_OFFSET, record
from firmware_sim.studies.grid_posterior import grid_posterior, main, summary
from gateway.model.vehicle import THETA_SEC42


def test_the_grid_posterior_holds_the_truth_that_made_the_record() -> None:
    """5 sensors, 2 s of the paper's scenario (fresh data seed), an 8^3 grid over about
    six sigma each way: the exact posterior's mean lies within 3 sd of the truth for
    every parameter, its sd is a few per cent (the data speak; not the window's width),
    the window holds the posterior, and the truth's marginal probabilities are proper."""
    theta = THETA_SEC42.as_array()
    Y = record(theta, 5, SEED_OFFSET["paper"] + 901, 2.0)
    half = (0.19, 0.11, 0.16)
    post = grid_posterior(Y, 5, theta, half, points=8)
    z = (post.mean - theta) / post.std
    assert np.all(np.abs(z) < 3.0), z
    rel = post.std / theta
    assert np.all((rel > 0.003) & (rel < 0.05)), rel
    # the window's own sd (uniform over +-half) is far wider: the likelihood decides
    assert np.all(rel < 0.5 * np.array(half)), rel
    assert np.all(post.face_mass < 1e-3), post.face_mass
    assert np.all((post.below > 0) & (post.below < 1)), post.below


def test_grid_posterior_refuses_an_odd_grid() -> None:
    """The truth must sit between the two middle values, so the grid is even."""
    with pytest.raises(ValueError, match="even number of grid points"):
        grid_posterior(np.zeros((10, 3)), 3, THETA_SEC42.as_array(), (0.1, 0.1, 0.1), 7)


def test_summary_counts_the_shares_per_case() -> None:
    """Two records: one inside 2 sd and the central 95 %, one outside both."""
    base = {"sensors": 3, "from_rest": False, "t_s": 5.0, "face_mass": [0.0, 0.0, 0.0]}
    rows = [dict(base, z=[0.5, -1.0, 1.9], below=[0.3, 0.8, 0.03]),
            dict(base, z=[2.5, -2.1, 0.1], below=[0.99, 0.98, 0.5])]
    (row,) = summary(rows)
    assert row["records"] == 2
    assert row["csy_ns_per_m_within_2sd"] == 0.5
    assert row["csay_ns_per_m_within_95"] == 0.5
    assert row["conicity_within_95"] == 1.0
    assert row["csy_ns_per_m_max_abs_z"] == 2.5


@pytest.mark.parametrize("argv, says", [
    (["run", "--points", "7"], "even --points"),
    (["run", "--at-s", "0"], "--at-s > 0"),
    (["run", "--half-log", "0.1", "0", "0.1"], "positive --half-log"),
])
def test_the_command_refuses_bad_options_with_one_line(
        argv: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    """A bad option is an argparse error (exit 2) naming what was expected and got,
    before any record is made."""
    with pytest.raises(SystemExit) as stop:
        main(argv + ["--seeds", "1"])
    assert stop.value.code == 2
    assert says in capsys.readouterr().err
