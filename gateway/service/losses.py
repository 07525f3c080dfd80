"""Journal warnings for data lost on the way in: frames and grid samples, rate-limited.

The health frame carries one summed ``dropped`` count; an integrator reading
``journalctl -u railgw`` needs to see *that* data is being lost and *where*: frames the
kernel dropped because the CAN socket's receive buffer was full (the service fell
behind the bus), frames dropped at the full receive queue, and grid samples dropped at
the full worker queue (the estimator fell behind). :class:`LossLog` is fed the
cumulative counters (monotonic) and says what grew since it last spoke, at most once
per ``every_s``: the first loss at once, then a summary of each later period with one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

LOSS_LOG_EVERY_S = 60.0
"""The shortest time between two loss warnings (s)."""


@dataclass(frozen=True)
class LossCounts:
    """Cumulative losses since the service started (monotonic counters)."""

    kernel_frames: int
    """Frames the kernel dropped: the CAN socket's receive buffer was full."""
    queue_frames: int
    """Frames dropped at the full receive queue (between the receive thread and the loop)."""
    worker_samples: int
    """Grid samples dropped at the full worker queue (live mode)."""


class LossLog:
    """Turns growing loss counters into at most one warning line per ``every_s``."""

    def __init__(self, every_s: float = LOSS_LOG_EVERY_S) -> None:
        if not every_s > 0:
            raise ValueError(f"expected a positive warning interval in s, got {every_s}")
        self.every_s = every_s
        self._said = LossCounts(0, 0, 0)
        self._said_at_s = -math.inf

    def line(self, counts: LossCounts, now_s: float) -> str | None:
        """The warning to log now (``now_s``: a monotonic clock), or None."""
        if now_s - self._said_at_s < self.every_s:
            return None
        grew = [(n - o, what) for n, o, what in (
            (counts.kernel_frames, self._said.kernel_frames,
             "CAN frames dropped by the kernel (socket receive buffer full: the service "
             "fell behind the bus)"),
            (counts.queue_frames, self._said.queue_frames,
             "CAN frames dropped at the full receive queue"),
            (counts.worker_samples, self._said.worker_samples,
             "grid samples dropped at the full estimator queue (the estimator fell "
             "behind)")) if n > o]
        if not grew:
            return None
        since = "" if math.isinf(self._said_at_s) else \
            f" in the last {now_s - self._said_at_s:.0f} s"
        self._said, self._said_at_s = counts, now_s
        return "data lost" + since + ": " + "; ".join(f"{d} {what}" for d, what in grew)
