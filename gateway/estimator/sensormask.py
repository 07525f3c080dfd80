"""Which sensors the filters leave out: a dead one, until it has been back a while.

A sensor whose value is missing from ``DEAD_AFTER_S`` of consecutive samples with data
(a dead node, a vehicle without it) is *left out*: its row of H becomes zero, so each
sample with the other sensors is a full sample of a smaller sensor set, and fast mode's
steady gains, the fault bank and the innovation monitor work on what the vehicle still
has. Without this, every sample lacked a sensor: fast mode ran the exact recursion for
good and the fault bank never ran. With the wheelset node of a 5-sensor vehicle dead, 12
of 12 damper failures went undetected (fresh seeds, 2026-11-27); now 40 of 40 are found
on their parameter, alerted within 4.1 s (docs/estimator.md "Dead sensors"). What the
remaining sensors cannot tell is not recovered: with the body node dead (3 sensors), a
Csy failure is rarely found.

A left-out sensor has y = 0 against a zero row: its innovation is 0 with variance r,
so it moves no state and no covariance, adds 0 to the NIS, and adds the same constant
to every particle's log-likelihood (weights, CUSUMs and likelihood ratios unchanged):
the exact recursion is the one that skips the sensor. A sensor left out comes back once
it has had a value in ``BACK_AFTER_S`` of consecutive samples with data (until then its
values are not used). A lone lost frame never leaves a sensor out, and the last sensor
in use is never left out.

The counts are arrays the filter checkpoints; no I/O.
"""

from __future__ import annotations

import numpy as np

DEAD_AFTER_S = 0.5
"""Consecutive samples with data (s) without a sensor's value before it is left out."""
BACK_AFTER_S = 0.5
"""Consecutive samples with data (s) with its value before a left-out sensor is used
again."""


def tally(absent: np.ndarray, present: np.ndarray, finite: np.ndarray, n: int = 1) -> None:
    """``n`` more samples with data, each with values where ``finite`` (ny,): count, in
    place, each sensor's run of samples without (``absent``) and with (``present``) a
    value (int64, (ny,))."""
    absent[:] = np.where(finite, 0, absent + n)
    present[:] = np.where(finite, present + n, 0)


def next_mask(left_out: np.ndarray, absent: np.ndarray, present: np.ndarray,
              dead_n: int, back_n: int) -> np.ndarray:
    """The sensors to leave out (bool (ny,)) after the counts: those back for ``back_n``
    samples return, those missing for ``dead_n`` go, the last one in use stays."""
    out = left_out & (present < back_n)
    for s in np.flatnonzero(~out & (absent >= dead_n)):
        if np.count_nonzero(~out) > 1:
            out[s] = True
    return out
