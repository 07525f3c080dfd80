"""The service's prior box: the dampers' lower edge by particle count, and what it is for, a
fresh filter on a vehicle whose damper failed before it started (docs/estimator.md "The
thirteenth session")."""

from __future__ import annotations

from dataclasses import replace

import pytest

from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.detection_alerts import alerts
from firmware_sim.studies.filtering import FilterOptions, run, service_filter
from gateway.config import EstimatorConfig
from gateway.estimator.rbpf_config import (
    WIDE_PRIOR_LO,
    WIDE_PRIOR_MIN_PARTICLES,
    RBPFConfig,
    prior_lo_for,
)
from gateway.runtime.pipeline import estimator_config

PAPER_LO = (0.3, 0.3, 0.3)


@pytest.mark.parametrize("particles, lo", [
    (64, PAPER_LO), (100, PAPER_LO), (WIDE_PRIOR_MIN_PARTICLES - 1, PAPER_LO),
    (WIDE_PRIOR_MIN_PARTICLES, WIDE_PRIOR_LO), (1000, WIDE_PRIOR_LO), (8000, WIDE_PRIOR_LO)])
def test_the_service_draws_from_the_wider_box_only_with_enough_particles(
        particles: int, lo: tuple[float, float, float]) -> None:
    """The bare filter keeps the paper's box; the service's takes the dampers from 0.1 x
    nominal from 500 particles on (lambda's edge and every upper edge stay the paper's)."""
    assert RBPFConfig(fs_hz=1000.0).prior_lo == PAPER_LO
    assert prior_lo_for(particles) == lo
    cfg = estimator_config(replace(EstimatorConfig(), particles=particles), 1000.0)
    assert cfg.prior_lo == lo and cfg.prior_hi == RBPFConfig(fs_hz=1000.0).prior_hi
    assert WIDE_PRIOR_LO == (0.1, 0.1, 0.3)


@pytest.mark.slow
def test_a_fresh_filter_on_a_vehicle_whose_anti_yaw_damper_failed_before_it_started() -> None:
    """Seed 6040, 5 sensors, Csay at 0.1 x nominal from the first sample, 6 s, the
    service's filter at its default m = 1000: the Csay ALARM at the first judged estimate
    (2.5 s) and nothing on a healthy parameter. The same record with the paper's box
    (0.3 x, below which the truth lies) fits the data with Csy and lambda first and
    alerts a healthy parameter too (the eleventh session's false alert, 6 of 10 records)."""
    _, Y = fault_data(1, 0.1, 5, 6040, 6.0, 0.0)
    assert EstimatorConfig().particles >= WIDE_PRIOR_MIN_PARTICLES
    wide, _, filt = run(Y, service_filter(5, 6040), replaced=[])
    assert filt.config.prior_lo == WIDE_PRIOR_LO
    raised = alerts(wide)
    assert [a for a in raised if a[1] != "csay_ns_per_m"] == [], raised
    assert ("csay_ns_per_m", "ALARM") in [(n, sev) for t, n, sev in raised if t <= 2.5], raised
    paper, _, _ = run(Y, service_filter(5, 6040, FilterOptions(prior_lo=PAPER_LO)),
                      replaced=[])
    assert [a for a in alerts(paper) if a[1] != "csay_ns_per_m"], alerts(paper)
