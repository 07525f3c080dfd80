"""CAN-log input for identification: a python-can log through the gateway's own front end.

The frames of any log python-can reads (candump ``.log``, ``.asc``, ``.blf``, ``.trc``,
``.mf4``) go through exactly the service's stages (:class:`gateway.frontend.chain.FrontEnd`:
decode and E2E validation, the fixed-rate resampler on each node's reconstructed
clock, the operating-condition gate) and come out as the
:class:`~gateway.offline.interchange.Recording` an interchange CSV gives:

- **Time.** Seconds since the log's first frame, on the resampler's grid
  (``[resampler] fs_hz``, 1 kHz by default).
- **Span.** From the first to the last grid point the gate passes (speed known and in
  the window, yaw rate present, straight track). Grid points it refuses inside that
  span become dropouts of every sensor, bridged like any dropout up to 1 % of the
  span; more is an error naming the gate's reasons.
- **Signals.** A sensor whose grid value is not OK (missing frame, NotAvailable) is a
  dropout. Sensors never seen (e.g. no wheelset node) are absent. The speed is the
  gate's (``VEH_Speed``), unless ``speed_mps`` is given, which then stands in for it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from gateway.can.codec import default_codec
from gateway.can.logs import read_log
from gateway.config import Config, with_overrides
from gateway.errors import InputError
from gateway.frontend.chain import FrontEnd
from gateway.identify.data import MAX_MISSING_FRACTION
from gateway.model.vehicle import SENSORS_5
from gateway.offline.interchange import Recording
from gateway.records import Sample

log = logging.getLogger(__name__)

CAN_LOG_SUFFIXES = (".log", ".asc", ".blf", ".trc", ".mf4")
"""File endings read as CAN logs (python-can's readers)."""


def _counts(counter: dict[str, int]) -> str:
    items = [f"{k} {v}" for k, v in sorted(counter.items()) if v]
    return ", ".join(items) if items else "none"


def read_can_log(path: str | Path, cfg: Config | None = None,
                 speed_mps: float | None = None) -> Recording:
    """Decode, validate, resample and gate a CAN log into a Recording (rules above).

    ``cfg`` gives the resampler and gating settings (default: built-in); the estimator
    sensor count is forced to 5 so every sensor in the log is kept. Raises InputError
    for an unreadable or empty log, a log without valid sensor frames, or one the gate
    refuses throughout.
    """
    p = Path(path)
    source = str(p)
    base = cfg if cfg is not None else Config()
    cfg5 = base if base.estimator.sensors == 5 else with_overrides(base,
                                                                   {"estimator.sensors": 5})
    front = FrontEnd(cfg5, default_codec(), speed_mps=speed_mps)
    samples: list[Sample] = []
    frames = 0
    t_first = np.nan
    for msg in read_log(p):
        if msg.is_error_frame:
            continue
        if frames == 0:
            t_first = float(msg.timestamp)
        frames += 1
        samples.extend(front.on_frame(msg))
    samples.extend(front.finish())
    stats = front.validator.stats
    if frames == 0:
        raise InputError(f"{source}: expected CAN frames, got an empty log")
    if stats.accepted == 0:
        raise InputError(f"{source}: expected valid sensor frames "
                         f"({', '.join(front.validator.messages)}), got none in {frames} "
                         f"frames (rejected: {_counts(dict(stats.rejected))})")
    used = [k for k, s in enumerate(samples) if s.update]
    if not used:
        raise InputError(f"{source}: expected grid points the gate passes (speed in the "
                         f"window, yaw rate present, straight track), got none of "
                         f"{len(samples)} (reasons: {_counts(front.gate.counts)})")
    kept = samples[used[0]:used[-1] + 1]
    fs_hz = cfg5.resampler.fs_hz
    t_s = (kept[0].t_s - t_first) + np.arange(len(kept)) / fs_hz
    values = np.array([s.values for s in kept])
    update = np.array([s.update for s in kept])
    values[~update] = np.nan
    signals = {name: values[:, i] for i, name in enumerate(SENSORS_5)
               if np.isfinite(values[:, i]).any()}
    signals["speed"] = np.array([s.speed_mps for s in kept])
    gated = int((~update).sum())
    if gated > MAX_MISSING_FRACTION * len(kept):
        raise InputError(f"{source}: expected the gate to pass the run between its first and "
                         f"last usable grid point (at most {MAX_MISSING_FRACTION:.0%} refused), "
                         f"got {gated / len(kept):.1%} refused (reasons: "
                         f"{_counts(front.gate.counts)}); cut the log to straight track "
                         f"in the speed window")
    log.info("%s: %d frames (%d accepted), %d grid points at %g Hz, %d gated inside the "
             "span; gate reasons: %s", source, frames, stats.accepted, len(kept), fs_hz,
             gated, _counts(front.gate.counts))
    return Recording(t_s=t_s, signals=signals, source=source)
