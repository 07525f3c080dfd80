"""Replay: the same pipeline as the service, fed from a CAN log on a simulated clock.

Any log python-can reads (candump ``.log``, ``.asc``, ``.blf``, ...). The clock is the
log's own timestamps, so the output does not depend on the machine's speed: the
JSON Lines of estimates and alerts are byte-identical from run to run. ``speed``
paces the replay at N x real time (0 = as fast as possible).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from gateway.alerts.policy import AlertPolicy
from gateway.can.codec import default_codec
from gateway.can.logs import read_log
from gateway.config import Config
from gateway.errors import InputError
from gateway.frontend.stats import FrontEndStats
from gateway.records import Alert, Estimate
from gateway.runtime.pipeline import Pipeline

log = logging.getLogger(__name__)


def estimate_json(est: Estimate) -> dict[str, Any]:
    """An estimate as a JSON object (rounded to keep files small and stable)."""
    out: dict[str, Any] = {"type": "estimate", "t_s": round(est.t_s, 6)}
    for name, m, s in zip(est.names, est.mean, est.std, strict=True):
        out[name] = {"mean": float(f"{m:.9g}"), "std": float(f"{s:.6g}")}
    out["ess"] = float(f"{est.ess:.6g}")
    out["updated"] = bool(est.updated)
    for key, value in (("v_sy_mps", est.v_sy_mps), ("v_say_mps", est.v_say_mps)):
        out[key] = float(f"{value:.6g}") if math.isfinite(value) else None
    return out


def alert_json(alert: Alert) -> dict[str, Any]:
    """An alert event as a JSON object (the report's ``alerts`` entries)."""
    return {"type": "alert", "t_s": round(alert.t_s, 6), "seq": alert.seq,
            "parameter": alert.parameter, "severity": alert.severity.name.lower(),
            "state": alert.state.name.lower(), "code": alert.code,
            "value_rel": float(f"{alert.value_rel:.6g}") if math.isfinite(alert.value_rel)
            else None, "message": alert.message}


@dataclass
class ReplayResult:
    """Everything a replay produced, in order."""

    estimates: list[Estimate] = field(default_factory=list)
    alerts: list[Alert] = field(default_factory=list)
    frames: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    grid_points: int = 0
    front_end: FrontEndStats | None = None
    """Late and gap samples by reason, clock steps, SampleIdx jumps, two senders."""


def replay(path: str | Path, cfg: Config, *, speed: float = 0.0, jsonl: IO[str] | None = None,
           progress: Callable[[int, float], None] | None = None) -> ReplayResult:
    """Run the pipeline over a log; write JSON Lines as they come if ``jsonl`` is given."""
    if speed < 0:
        raise InputError(f"expected --speed >= 0 (0 = as fast as possible), got {speed}")
    result = ReplayResult()

    def on_estimate(est: Estimate) -> None:
        result.estimates.append(est)
        if jsonl is not None:
            jsonl.write(json.dumps(estimate_json(est), sort_keys=True) + "\n")

    def on_alert(alert: Alert) -> None:
        result.alerts.append(alert)
        if jsonl is not None:
            jsonl.write(json.dumps(alert_json(alert), sort_keys=True) + "\n")

    pipe = Pipeline(cfg, default_codec(), policy=AlertPolicy(), blocking=True,
                    on_estimate=on_estimate, on_alert=on_alert, keep_spare=False)
    wall0 = time.monotonic()
    t0: float | None = None
    try:
        for msg in read_log(path):
            if msg.is_error_frame:
                continue
            if t0 is None:
                t0 = msg.timestamp
            if speed > 0:
                lag = (msg.timestamp - t0) / speed - (time.monotonic() - wall0)
                if lag > 0.002:
                    time.sleep(lag)
            pipe.on_frame(msg)
            result.frames += 1
            if result.frames % 1000 == 0:
                pipe.on_time(msg.timestamp)
                pipe.poll()
                if progress is not None:
                    progress(result.frames, msg.timestamp - t0)
        pipe.finish()
        pipe.drain()
    finally:
        pipe.close()
    result.rejected = dict(pipe.validator.stats.rejected)
    result.grid_points = pipe.samples_out
    result.front_end = pipe.front.stats()
    return result
