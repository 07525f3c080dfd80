"""The time-domain misfit: known answers on noise-free synthetic data, and bad input."""

import numpy as np
import pytest

from gateway.errors import InputError
from gateway.identify.data import Dataset
from gateway.identify.misfit import MisfitConfig, Section, TrackMisfit, check_sections
from gateway.identify.params import ParamPoint
from gateway.identify.synthetic import demo_case


@pytest.fixture(scope="module")
def clean_case():
    return demo_case(seed=3, section_s=8.0, noise_scale=0.0)


def _misfit(case, **config):
    return TrackMisfit(case.dataset, case.track, [Section(*s) for s in case.sections],
                       MisfitConfig(**config), case.offset_m)


def test_misfit_vanishes_at_the_truth_and_not_at_nominal(clean_case):
    """The truth was simulated at 2 kHz and decimated; the misfit simulates at 200 Hz.

    What is left at the truth (about 1e-5, mostly the wheelset accelerations) is the
    200 Hz discretisation of the track input: 1000x below the sensor-noise floor.
    """
    mf = _misfit(clean_case)
    assert mf(clean_case.truth) < 5e-5
    assert np.all(mf.per_signal(clean_case.truth) < 1e-4)
    assert mf(ParamPoint.nominal()) > 0.02


def test_misfit_is_one_for_a_model_that_predicts_nothing(clean_case):
    mf = _misfit(clean_case)
    zero = np.zeros_like(mf.meas_sections[0])
    e = np.sum(mf.meas_sections[0] ** 2, axis=0)
    assert np.allclose(np.sum((mf.meas_sections[0] - zero) ** 2, axis=0), e)
    assert mf.weights @ mf.denominator > 0


def test_misfit_does_not_depend_on_the_simulation_rate(clean_case):
    j200 = _misfit(clean_case)(ParamPoint.nominal())
    j100 = _misfit(clean_case, sim_rate_hz=100.0)(ParamPoint.nominal())
    assert j100 == pytest.approx(j200, rel=0.02)


def test_section_outside_the_data_is_an_input_error(clean_case):
    with pytest.raises(InputError, match=r"learn section 30-50 s: expected a range within "
                                         r"the recording 0-23.995 s"):
        check_sections(clean_case.dataset, [Section(30.0, 50.0)])


def test_band_above_the_simulation_nyquist_is_an_input_error(clean_case):
    with pytest.raises(InputError, match="below 0.8 x the simulation Nyquist"):
        _misfit(clean_case, sim_rate_hz=50.0)


def test_track_too_short_is_an_input_error(clean_case):
    ds: Dataset = clean_case.dataset
    with pytest.raises(InputError, match="expected positions within the track"):
        TrackMisfit(ds, clean_case.track, [Section(2.0, 10.0)], MisfitConfig(),
                    offset_m=clean_case.track.position_m[-1] - 100.0)
