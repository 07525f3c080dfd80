"""When fast mode's exact recursion is back at the steady state after a lost frame.

Fast mode hands every sample without every sensor to the exact recursion, started from
each particle's steady P+ (:meth:`gateway.estimator.rbpf.RBPF._leave_steady`). After a
*partial* outage (some sensors reported: a lost or late CAN frame) the recursion comes
back to that steady state within tens of samples, because one missing scalar update
perturbs P only a little. A hold (no sensor at all, a curve) perturbs it far more and
keeps the time rule (``fast_warmup_s`` of full data).

:class:`RejoinTarget` measures how far the exact P+ still is from the steady P+ in what the
filter uses: the gains' observable part ``(I - v0 v0') P+ H'`` and ``H P+ H'`` (every
sequential gain and innovation variance of the next update is a function of ``P H'`` and
``H P H'``; the static-yaw direction ``v0`` is unobservable, ``H v0 = 0``, and the steady
P keeps no variance along it). The distance is the largest difference relative to the
particle's largest element, over the particles whose steady filter is alive.

Measured before the rule existed (16 particles at theta 0.9-1.1 x the paper's, the exact
recursion for 2 s against rejoining at a distance of :data:`REJOIN_TOL`, the
log-likelihood over the 4 s after the outage): one sensor out for 1 ms rejoins after
15-32 samples, for 20 ms after 28-291 (the 3-sensor set's yaw rate is the slow one),
with every particle's log-likelihood within 0.014 nats of the exact recursion's
(docs/estimator.md "Lost frames").
No I/O.
"""

from __future__ import annotations

import numpy as np

from gateway.estimator.kalman import from_lanes
from gateway.model.coordinates import NZ

__all__ = ["REJOIN_EVERY", "REJOIN_TOL", "SETTLE_S", "RejoinTarget"]

REJOIN_TOL = 1e-3
"""Relative distance of the exact P+ from the steady P+ (:class:`RejoinTarget`) at which the
steady gains take over again."""
SETTLE_S = 0.3
"""Full data the exact recursion runs at least after a lost frame before the time rule
(``fast_warmup_s``, at the start and after a hold) hands over to the steady gains: one
sensor out for 1-20 ms perturbs P by up to 0.17 (relative, as in :class:`RejoinTarget`),
decaying to :data:`REJOIN_TOL` within 15-291 samples (measured, 3 and 5 sensors); the
warm-up's own hand-over moves P by 0.23 after 2 s from the prior."""
REJOIN_EVERY = 16
"""Samples with every sensor between two distance checks (each check costs about one
exact step)."""


class RejoinTarget:
    """The steady P+ of every particle, as the rejoin test sees it.

    ``p_post`` (N, 16, 16) the steady updated covariance; ``v0`` (N, 16) the unit
    static-yaw null vectors; ``H`` (ny, 16) the sensor rows; ``alive`` (N,) the particles
    whose steady filter exists (a dead particle's exact P is not compared).
    ``p_post`` is kept: a move carries each particle's deviation from it.
    """

    def __init__(self, p_post: np.ndarray, v0: np.ndarray, H: np.ndarray,
                 alive: np.ndarray) -> None:
        self.p_post = p_post
        self._v0 = v0
        self._H = H
        self._alive = np.asarray(alive, dtype=bool)
        self._g, self._c = self._observed(p_post)
        self._g_scale = np.abs(self._g).max(axis=(1, 2))
        self._c_scale = np.abs(self._c).max(axis=(1, 2))

    def _observed(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(I - v0 v0') P H'`` (N, 16, ny) and ``H P H'`` (N, ny, ny) of ``P`` (N, 16, 16)."""
        G = P @ self._H.T
        G = G - self._v0[:, :, None] * np.einsum("mi,mij->mj", self._v0, G)[:, None, :]
        return G, self._H @ G

    def distance(self, p_lanes: np.ndarray) -> float:
        """The largest relative distance of the exact P+ ``p_lanes`` (lane layout) from
        the steady P+, over the live particles; +inf when a live particle's P is not
        finite."""
        m = len(self._v0)
        g, c = self._observed(from_lanes(p_lanes, m, (NZ, NZ)))
        d = np.maximum(np.abs(g - self._g).max(axis=(1, 2)) / self._g_scale,
                       np.abs(c - self._c).max(axis=(1, 2)) / self._c_scale)
        d = d[self._alive]
        if not d.size:
            return 0.0
        worst = float(d.max())
        return worst if np.isfinite(worst) else float("inf")

    def reached(self, p_lanes: np.ndarray) -> bool:
        """Whether the exact P+ ``p_lanes`` is within :data:`REJOIN_TOL` of the steady P+."""
        return self.distance(p_lanes) <= REJOIN_TOL
