"""``advance`` and ``run`` from ``step``, for the estimator test doubles of the worker tests.

The :class:`gateway.records.Estimator` protocol asks for all three; a double that only
counts or records its samples implements ``step`` and takes the other two from here.
"""

from __future__ import annotations

from collections.abc import Iterable

from gateway.records import Estimate, Sample


class SteppedRuns:
    """Mixin: ``advance`` and ``run`` are ``step`` on every sample."""

    def step(self, sample: Sample) -> Estimate:  # pragma: no cover - the double's own
        raise NotImplementedError

    def advance(self, sample: Sample) -> None:
        self.step(sample)

    def noise_check(self) -> None:
        """A double makes no sensor-noise test."""
        return None

    def run(self, samples: Iterable[Sample], output_every: int | None = None
            ) -> list[Estimate]:
        out = [self.step(s) for s in samples]
        every = output_every or 1
        return [e for k, e in enumerate(out) if (k + 1) % every == 0 or k == len(out) - 1]
