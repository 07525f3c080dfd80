"""Parameter drift: the random-walk evolution lets the filter follow a slow change.

Truth: Csy ramps from nominal (40 kNs/m) to 60 % of it over 30 s, then holds (other
parameters nominal), 3 sensors, the paper's noise and Ar. The static filter of the paper
(drift 0) lags the ramp; with the service's drift the lag is smaller and the estimate
reaches the new value. Checked against the truth that generated the data, on four
realisations.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.accuracy import make_data, run_filter
from gateway.estimator.rbpf import RBPFConfig
from gateway.model.vehicle import THETA_NOMINAL

FS_HZ = 1000.0
T_WARM_S, T_RAMP_S, T_HOLD_S = 15.0, 30.0, 10.0


def _truth() -> np.ndarray:
    t_s = np.arange(int((T_WARM_S + T_RAMP_S + T_HOLD_S) * FS_HZ)) / FS_HZ
    theta = np.tile(THETA_NOMINAL.as_array(), (len(t_s), 1))
    theta[:, 0] *= np.interp(t_s, [T_WARM_S, T_WARM_S + T_RAMP_S], [1.0, 0.6])
    return theta


SEEDS = (1, 2, 3, 4)
"""Four realisations (data and filter seed): one run's lag ratio varies by about +-0.1
from seed to seed (0.37-0.51 over seeds 1-8 with the service's moves; 0.42-0.61 without
the static-yaw step, docs/estimator.md "Slow change"), so the bound is on the mean."""


@pytest.fixture(scope="module")
def runs() -> dict[tuple[int, float], tuple[np.ndarray, np.ndarray]]:
    theta = _truth()
    out = {}
    for seed in SEEDS:
        Y = make_data(theta, 3, seed=seed)
        for drift in (0.0, 0.01):
            cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=300, sensors=3, seed=seed,
                             walk_rel_per_sqrt_s=(drift,) * 3)
            est, _, _ = run_filter(Y, cfg, every=500)
            t = np.array([e.t_s for e in est])
            csy = np.array([e.mean[0] for e in est])
            truth = theta[np.round(t * FS_HZ).astype(int) - 1, 0]
            out[seed, drift] = (t, csy / truth - 1.0)
    return out


@pytest.mark.slow
def test_drift_follows_a_ramp_better_than_the_static_filter(runs):
    ratios = []
    for seed in SEEDS:
        t, err_static = runs[seed, 0.0]
        _, err_drift = runs[seed, 0.01]
        on_ramp = (t > T_WARM_S + 10.0) & (t <= T_WARM_S + T_RAMP_S)
        # the static filter lags: over-estimates the falling Csy along the ramp
        assert np.mean(err_static[on_ramp]) > 0.03, seed
        ratios.append(np.mean(np.abs(err_drift[on_ramp])) / np.mean(np.abs(err_static[on_ramp])))
        # and the drifting filter ends on the new value
        assert abs(err_drift[-1]) < 0.05, (seed, err_drift[-1])
    # with drift the mean lag along the ramp is at most half the static filter's
    assert np.mean(ratios) < 0.5, np.round(ratios, 3)
