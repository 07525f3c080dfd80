"""The fault bank's look-back: what it keeps, and where a replay may start."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.errors import EstimatorError
from gateway.estimator.lookback import SNAP_EVERY, Lookback
from gateway.model.coordinates import NZ

NY, D = 3, 3


def _fed(blocks: list[int], window: int = 400, seed: int = 0, extra: int = 0
         ) -> tuple[Lookback, np.ndarray]:
    """A look-back fed 1000 samples in ``blocks`` (sizes summing to 1000), with a
    snapshot (state and theta filled with its count) at every multiple of SNAP_EVERY,
    as the bank makes them."""
    Y = np.random.default_rng(seed).standard_normal((1000, NY))
    lb = Lookback(window, NY, D, extra)
    lb.reset(np.full(NZ, -1.0), np.ones(D))
    c = 0
    for k in blocks:
        for n in range(c + 1, c + k + 1):
            if n % SNAP_EVERY == 0:
                lb.snapshot(n, np.full(NZ, float(n)), np.full(D, float(n)))
        lb.commit(Y[c:c + k], np.ones(k, dtype=bool))
        c += k
    return lb, Y


def test_the_look_back_does_not_depend_on_how_samples_came_in_blocks() -> None:
    one, _ = _fed([1000])
    many, _ = _fed([1] * 37 + [263, 50, 1, 649])
    for key, arr in one.arrays().items():
        np.testing.assert_array_equal(many.arrays()[key], arr, err_msg=key)


def test_a_replay_may_start_at_any_snapshot_within_the_window() -> None:
    lb, Y = _fed([1000])
    starts = lb.starts()
    assert lb.count == 1000
    # window 400 and one snapshot's spacing: 550 ... 1000, oldest first
    assert [n for n, _, _ in starts] == list(range(550, 1001, SNAP_EVERY))
    for n, x, ref in starts:
        assert np.all(x == n) and np.all(ref == n)
    got_y, got_full = lb.samples(600)
    np.testing.assert_array_equal(got_y, Y[600:])   # the ring, unwrapped, in order
    assert got_full.all()


def test_extra_samples_let_a_replay_start_before_an_earlier_count() -> None:
    """A runner-up's replay: the snapshots within the window before count 700, with
    every sample since kept by the extra 300; without the extra, those that fell out
    of the ring are not offered."""
    lb, Y = _fed([700], extra=300)
    lb.commit(Y[700:], np.ones(300, dtype=bool))   # located, no snapshots
    assert [n for n, _, _ in lb.starts(700)] == list(range(250, 701, SNAP_EVERY))
    np.testing.assert_array_equal(lb.samples(250)[0], Y[250:])
    assert [n for n, _, _ in lb.starts()] == list(range(550, 701, SNAP_EVERY))
    plain, _ = _fed([700])
    plain.commit(Y[700:], np.ones(300, dtype=bool))
    assert [n for n, _, _ in plain.starts(700)] == list(range(550, 701, SNAP_EVERY))


def test_a_restart_forgets_what_came_before_it() -> None:
    lb, _ = _fed([1000])
    lb.restart(np.full(NZ, 7.0), np.full(D, 7.0))  # at a regular snapshot's count
    (n, x, ref), = lb.starts()
    assert n == 1000 and np.all(x == 7.0) and np.all(ref == 7.0)
    assert len(lb.samples(n)[0]) == 0


def test_no_window_keeps_nothing() -> None:
    lb = Lookback(0, NY, D)
    lb.reset(np.zeros(NZ), np.ones(D))
    lb.commit(np.zeros((10, NY)), np.ones(10, dtype=bool))
    assert not lb.on and lb.starts() == [] and lb.count == 10


def test_a_checkpoint_of_another_shape_is_refused() -> None:
    lb, _ = _fed([1000])
    other = Lookback(200, NY, D)
    with pytest.raises(EstimatorError, match="expected bank_lb_y of shape"):
        other.load(lb.arrays())
