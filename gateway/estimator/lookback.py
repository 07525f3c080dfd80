"""The fault bank's look-back: recent samples and reference states its location replays.

The bank's CUSUM crosses its threshold some time after a change began: with little
information in the data (2 x sensor noise, Csy x 0.5, 3 sensors: 15-66 nats/s) up to
several seconds. Its location grid used to start at the confirmation and sum only the
samples after it, so the evidence that made the CUSUM cross was thrown away and the
location then took at least another ``locate_s``. With this look-back the grid starts
at the sample where a change most likely began (the generalised likelihood ratio's
change time), from the reference filter's state there (the nearest snapshot before it,
stepped on), and replays the buffered samples up to the confirmation before it sums on
(:meth:`gateway.estimator.faultbank.FaultBank._glr_start`).

Kept, for at most ``window`` samples back:

- every sample the bank watched (values (ny,), full or predicted), in a ring;
- the reference filter's state (16,) and theta (d,) every :data:`SNAP_EVERY` samples,
  and at each (re)start of the bank's filters;

Samples are counted from the bank's start; counts and snapshots are set by the sample
count, never by how samples were grouped into blocks, so ``run`` and ``step`` keep the
same look-back. A restart of the bank's filters (a detection, a location that found no
change, a new speed band) starts a new look-back: samples before it were filtered under
another model. All state is arrays (:meth:`Lookback.arrays`) for bit-exact checkpoints;
no I/O.
"""

from __future__ import annotations

import numpy as np

from gateway.errors import EstimatorError
from gateway.model.coordinates import NZ

SNAP_EVERY = 50
"""Samples between snapshots of the reference filter's state (50 ms at 1 kHz): a
replay starts at most this many samples before the change point."""

_COUNT, _FROM, _SLOT = range(3)


class Lookback:
    """Ring buffers of the last ``window`` watched samples (module docstring), and of
    ``extra`` samples more for a replay from an earlier count (:meth:`starts`'s ``at``);
    ``window`` 0: nothing is kept and :meth:`starts` is always empty."""

    def __init__(self, window: int, ny: int, n_params: int, extra: int = 0) -> None:
        self.window = int(window)
        self.cap = self.capacity(window, extra)
        n_snap = self.cap // SNAP_EVERY + 4 if self.window else 0
        self.y = np.zeros((self.cap, ny))                # values (cap, ny)
        self.full = np.zeros(self.cap, dtype=bool)       # updated (cap,)
        self.snap_x = np.zeros((n_snap, NZ))             # reference states
        self.snap_ref = np.zeros((n_snap, n_params))     # their thetas
        self.snap_n = np.full(n_snap, -1.0)              # their sample counts (-1: none)
        self.vec = np.zeros(3)                           # count, first count, next slot

    @staticmethod
    def capacity(window: int, extra: int = 0) -> int:
        """Samples the ring keeps for a ``window`` and ``extra`` (0 without a window)."""
        return int(window) + int(extra) + SNAP_EVERY if window else 0

    @property
    def on(self) -> bool:
        return self.window > 0

    @property
    def count(self) -> int:
        """Samples watched since the bank's start."""
        return int(self.vec[_COUNT])

    def reset(self, x_ref: np.ndarray, ref: np.ndarray) -> None:
        """The bank starts: nothing kept, then a snapshot of the reference state
        ``x_ref`` (16,) at theta ``ref`` (d,) at count 0."""
        self.vec[:] = 0.0
        self.snap_n[:] = -1.0
        self.restart(x_ref, ref)

    def restart(self, x_ref: np.ndarray, ref: np.ndarray) -> None:
        """The bank's filters restart here, at ``x_ref`` under ``ref``: nothing before is
        replayed."""
        self.vec[_FROM] = self.vec[_COUNT]
        self.snapshot(self.count, x_ref, ref)

    def snapshot(self, n: int, x_ref: np.ndarray, ref: np.ndarray) -> None:
        """Keep the reference state ``x_ref`` (16,) at theta ``ref`` after ``n`` samples
        (the latest for that ``n``)."""
        if not self.on:
            return
        same = np.flatnonzero(self.snap_n == n)     # a restart at a regular snapshot's
        if len(same):                               # count replaces it
            self.snap_x[same[0]], self.snap_ref[same[0]] = x_ref, ref
            return
        slot = int(self.vec[_SLOT])
        self.snap_x[slot], self.snap_ref[slot], self.snap_n[slot] = x_ref, ref, n
        self.vec[_SLOT] = (slot + 1) % len(self.snap_n)

    def until_snapshot(self, n: int) -> int:
        """Samples from count ``n`` to the next regular snapshot (1..SNAP_EVERY)."""
        return SNAP_EVERY - n % SNAP_EVERY

    def commit(self, Y: np.ndarray, full: np.ndarray) -> None:
        """Keep the watched samples ``Y`` (k, ny) with ``full`` (k,): the ring and the
        count."""
        k, c = len(Y), self.count
        self.vec[_COUNT] = c + k
        if not self.on or k == 0:
            return
        idx = np.arange(c, c + k)[-self.cap:] % self.cap
        self.y[idx], self.full[idx] = Y[-self.cap:], full[-self.cap:]

    def starts(self, at: int | None = None) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Every snapshot a replay may start from, oldest first: (count, reference state
        (16,), its theta (d,)), since the last restart and within ``window`` (and one
        snapshot's spacing) before count ``at`` (None: the current count), whose samples
        since are all still kept."""
        if not self.on:
            return []
        n, c = self.snap_n, self.count
        at = c if at is None else at
        ok = np.flatnonzero((n >= 0) & (n >= self.vec[_FROM])
                            & (n >= at - self.window - SNAP_EVERY) & (n <= at)
                            & (n >= c - self.cap))
        return [(int(n[s]), self.snap_x[s].copy(), self.snap_ref[s].copy())
                for s in ok[np.argsort(n[ok], kind="stable")]]

    def samples(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The samples after count ``n`` up to the current count: values (k, ny), full
        (k,)."""
        idx = np.arange(n, self.count) % self.cap
        return np.ascontiguousarray(self.y[idx]), np.ascontiguousarray(self.full[idx])

    def arrays(self) -> dict[str, np.ndarray]:
        """The state to checkpoint."""
        return {"bank_lb_y": self.y, "bank_lb_full": self.full, "bank_lb_snap_x": self.snap_x,
                "bank_lb_snap_ref": self.snap_ref, "bank_lb_snap_n": self.snap_n,
                "bank_lb_vec": self.vec}

    def load(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore :meth:`arrays` output; a checkpoint from before the look-back has
        none, and the look-back then starts empty (no replay before the next snapshot)."""
        for key, attr in (("bank_lb_y", "y"), ("bank_lb_full", "full"),
                          ("bank_lb_snap_x", "snap_x"), ("bank_lb_snap_ref", "snap_ref"),
                          ("bank_lb_snap_n", "snap_n"), ("bank_lb_vec", "vec")):
            if key not in arrays:
                continue
            old = getattr(self, attr)
            if arrays[key].shape != old.shape:
                raise EstimatorError(f"expected {key} of shape {old.shape}, got "
                                     f"{arrays[key].shape}")
            setattr(self, attr, np.array(arrays[key], dtype=old.dtype))

    def copy(self) -> Lookback:
        """An independent copy (the estimator's scan-ahead snapshot)."""
        new = Lookback.__new__(Lookback)
        new.window, new.cap = self.window, self.cap
        for attr in ("y", "full", "snap_x", "snap_ref", "snap_n", "vec"):
            setattr(new, attr, getattr(self, attr).copy())
        return new
