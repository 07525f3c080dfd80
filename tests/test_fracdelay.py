"""The band-limited fractional delay (gateway.frontend.fracdelay): what its docstring claims.

Against the ideal delay exp(i w f) of a node's samples, at every tabulated fraction: the
complex response within 1 % up to 0.43 of the node rate; white noise keeps at least
93 % of its variance (linear interpolation keeps 50 % at f = 1/2); unit DC gain; the
sample itself at f = 0. And the values: a band-limited signal sampled between grid
points comes back at the grid point.
"""

from __future__ import annotations

import numpy as np
import pytest

from gateway.frontend import fracdelay as fd

FRACTIONS = np.arange(fd.PHASES + 1) / fd.PHASES


def response(h: np.ndarray, w: np.ndarray) -> np.ndarray:
    """H(w) of taps h on the samples k0 + OFFSETS, for x[n] = exp(i w n): (len(w),)."""
    return np.exp(1j * np.outer(w, fd.OFFSETS)) @ h


def test_unit_dc_gain_and_the_sample_itself_at_zero():
    np.testing.assert_allclose(fd.TABLE.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(fd.taps(0.0), fd.OFFSETS == 0)
    np.testing.assert_array_equal(fd.taps(1.0), fd.OFFSETS == 1)


def test_close_to_the_ideal_delay_up_to_043_of_the_node_rate():
    w = 2 * np.pi * np.linspace(0.0, 0.43, 200)
    worst = max(np.abs(response(fd.taps(f), w) - np.exp(1j * w * f)).max()
                for f in FRACTIONS[::8])
    assert worst < 0.01, worst


@pytest.mark.parametrize("f", [0.1, 0.25, 0.5, 0.75])
def test_white_noise_keeps_its_variance_where_linear_halves_it(f):
    sinc = (fd.taps(f) ** 2).sum()
    linear = (1 - f) ** 2 + f ** 2
    assert 0.93 < sinc <= 1.0 + 1e-12
    assert sinc > linear + 0.4 * (1 - linear) - 1e-12     # much closer to white than linear


def test_a_band_limited_signal_between_grid_points_comes_back_on_the_grid():
    rng = np.random.default_rng(7)
    freqs = rng.uniform(0.0, 0.4, 12)                  # cycles per sample
    phases = rng.uniform(0, 2 * np.pi, 12)

    def signal(t: np.ndarray) -> np.ndarray:
        return np.cos(2 * np.pi * freqs[None, :] * t[:, None] + phases).sum(axis=1)

    for f in (0.13, 0.5, 0.87):
        k = np.arange(200)
        node = signal(k - f)                           # node samples f behind the grid
        k0 = np.arange(50, 150) - 1                    # grid point j = node index k0 + f
        got = np.array([fd.taps(f) @ node[j + fd.OFFSETS] for j in k0])
        want = signal(k0.astype(float))                # node index k0 + f is time k0
        lin = (1 - f) * node[k0] + f * node[k0 + 1]
        assert np.abs(got - want).max() < 0.02 * np.abs(want).max()
        assert np.abs(lin - want).max() > 5 * np.abs(got - want).max()
