"""The gate's holds of the updates (a curve and its straight hold) as a mask of samples.

Sample k of a study's record is at (k + 1) / fs_hz s; a held sample keeps its values but
carries ``update=False``, as the gate sends it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def holds(n: int, fs_hz: float, starts_s: Sequence[float], length_s: float) -> np.ndarray:
    """Which of ``n`` samples are held: ``length_s`` from each of ``starts_s``. (n,) bool."""
    t_s = np.arange(1, n + 1) / fs_hz
    held = np.zeros(n, dtype=bool)
    for t0 in starts_s:
        held |= (t_s >= t0) & (t_s < t0 + length_s)
    return held


def periodic_holds(n: int, fs_hz: float, every_s: float | None, length_s: float
                   ) -> np.ndarray | None:
    """:func:`holds` at every multiple of ``every_s`` (None: no holds)."""
    if every_s is None:
        return None
    return holds(n, fs_hz, np.arange(every_s, n / fs_hz, every_s).tolist(), length_s)
