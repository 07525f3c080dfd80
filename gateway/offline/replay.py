"""Replay: the same pipeline as the service, fed from a CAN log on a simulated clock.

Any log python-can reads (candump ``.log``, ``.asc``, ``.blf``, ...). The clock is the
log's own timestamps, so the output does not depend on the machine's speed: the
JSON Lines of estimates and alerts are byte-identical from run to run. ``speed``
paces the replay at N x real time (0 = as fast as possible).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from gateway import jsonform
from gateway.alerts.policy import AlertPolicy
from gateway.can.codec import default_codec
from gateway.can.logs import read_log
from gateway.config import Config
from gateway.errors import InputError
from gateway.frontend.stats import FrontEndStats
from gateway.records import Alert, Estimate, NoiseCheck
from gateway.runtime.pipeline import Pipeline

log = logging.getLogger(__name__)


# Replay lines are the one JSON form (gateway.jsonform) reshaped: a "type" tag, floats
# rounded (small files, stable from run to run), enum names in lower case and an
# estimate's parameters as top-level keys. They differ because that shape is a contract
# older than the one form: pinned byte for byte by tests/golden/replay.jsonl, and
# persisted in replay reports and the fleet view's Parquet metadata ("railgw.alerts").


def _time(t_s: float | None) -> float | None:
    return None if t_s is None else round(t_s, 6)


def _sig(x: float | None, digits: int) -> float | None:
    return None if x is None else float(f"{x:.{digits}g}")


def estimate_json(est: Estimate) -> dict[str, Any]:
    """An estimate as a replay line (rounded to keep files small and stable)."""
    j = jsonform.estimate_json(est)
    out: dict[str, Any] = {"type": "estimate", "t_s": _time(j["t_s"])}
    for name, p in j["params"].items():
        out[name] = {"mean": _sig(p["mean"], 9), "std": _sig(p["std"], 6)}
    out["ess"] = _sig(j["ess"], 6)
    out["updated"] = j["updated"]
    out["provisional"] = j["provisional"]
    for key in ("v_sy_mps", "v_say_mps"):
        out[key] = _sig(j[key], 6)
    if j["located"] is not None:            # only within 2 s after a bank detection
        out["located"] = j["located"]
    if j["left_out"]:                       # only while a sensor is left out (a dead node)
        out["left_out"] = j["left_out"]
    if j["unresolved"]:                     # only while the sensors in use cannot resolve some
        out["unresolved"] = j["unresolved"]
    return out


def alert_json(alert: Alert) -> dict[str, Any]:
    """An alert event as a replay line (the report's ``alerts`` entries)."""
    j = jsonform.alert_json(alert)
    return {**j, "type": "alert", "t_s": _time(j["t_s"]),
            "severity": j["severity"].lower(), "state": j["state"].lower(),
            "value_rel": _sig(j["value_rel"], 6)}


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
    noise_check: NoiseCheck | None = None
    """The estimator's sensor-noise test (None: not made, e.g. under 5 s of data)."""


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
    result.noise_check = pipe.stats().noise_check
    return result
