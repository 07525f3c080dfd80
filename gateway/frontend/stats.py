"""The front end's counters as one frozen record (replay report, health, console)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class NodeTiming:
    """The front end's view of one sensor node (one sending message): its fitted clock
    and what became of its samples, so timing can be checked from outside
    (``docs/resampler.md``, "Per-node timing").

    ``drift_ppm``: the node's fitted sample period against nominal, ppm of the receive
    clock (NaN until the envelope fit has two segments). ``grid_phase_us``: where the
    node's sample instants sit between grid points: the time from the grid point at or
    before the node's newest sample to that sample, on the fitted model, us, in
    ``[0, 1e6 / fs_hz)`` (NaN before the node's first frame); it includes the bus's
    minimum latency, common to all nodes, and moves by ``drift_ppm`` x 1e-6 of a node
    period per sample. ``late_samples``: samples dropped because the grid had passed them
    (all reasons). ``missing_samples``: holes in the node's sample-index sequence, samples
    never received (lost on the bus, rejected by validation); a late sample is received,
    not missing; counted from the node's first to its newest sample, per model run
    (across node restarts). ``reordered_samples``: samples received after a newer sample
    of the same node.
    """

    message: str
    drift_ppm: float
    grid_phase_us: float
    late_samples: int
    missing_samples: int
    reordered_samples: int

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON types (non-finite floats stay; the writers map them to null)."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FrontEndStats:
    """What the front end made of the traffic so far: for the replay report, the health
    frame and the console (``docs/resampler.md``, "Front-end statistics").

    Counts are totals since start. ``rejected``: frames refused by validation, by reason
    (incl. ``two_senders``). ``late``: frames dropped because the grid had passed their
    sample, by reason (:data:`gateway.frontend.resample.LATE_REASONS`). ``gaps``: per lateral
    message, grid points with its entries MISSING, by reason
    (:data:`gateway.frontend.resample.GAP_REASONS`). ``gating``: samples per gating reason
    (``updated`` = measurement updates). ``clock_steps``: receive-clock steps re-based
    (``rx_offset_s`` the correction in force, s); ``resyncs``: node clock models
    restarted; ``retimed_frames``: frames with a disbelieved receive time placed by
    their SampleIdx; ``outlier_frames``: such frames that fitted nowhere and were
    dropped. ``sample_idx_jumps``: per message, SampleIdx breaks the alive counter does
    not explain, by reason (:data:`gateway.can.e2e.IDX_JUMP_REASONS`). ``two_senders``: the
    messages flagged now (two interleaved counter/SampleIdx sequences on one id; their
    frames are rejected, so they are excluded from the estimator); ``two_sender_events``:
    per message, times that flag was raised. ``horizon``: receive times beyond a horizon,
    by reason (:data:`gateway.frontend.resample.HORIZON_REASONS`); ``grid_jump_points``: grid
    points skipped by grid jumps over empty time (never emitted). ``nodes``: per sending
    message, the node's fitted drift and grid phase and its late, missing and reordered
    samples (:class:`NodeTiming`).
    """

    frames: int
    accepted: int
    rejected: dict[str, int]
    grid_points: int
    late: dict[str, int]
    gaps: dict[str, dict[str, int]]
    gating: dict[str, int]
    clock_steps: int
    rx_offset_s: float
    resyncs: int
    retimed_frames: int
    outlier_frames: int
    duplicate_frames: int
    sample_idx_jumps: dict[str, dict[str, int]]
    two_senders: tuple[str, ...]
    two_sender_events: dict[str, int]
    horizon: dict[str, int] = field(default_factory=dict)
    grid_jump_points: int = 0
    nodes: dict[str, NodeTiming] = field(default_factory=dict)

    @property
    def late_total(self) -> int:
        """Frames dropped as late, all reasons."""
        return sum(self.late.values())

    @property
    def gap_points(self) -> int:
        """Grid points x messages with MISSING entries, all reasons."""
        return sum(sum(g.values()) for g in self.gaps.values())

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON types (the replay report's ``front_end``)."""
        out = dataclasses.asdict(self)
        out["two_senders"] = list(self.two_senders)
        return out
