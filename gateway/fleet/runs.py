"""One run through the gateway's own stages: a CAN log to grid samples, samples to estimates.

The fleet tool's only seam to the gateway: ingest uses :func:`log_samples` (the
service's front end: decode, validate, resample, gate, driven as ``gateway replay``
drives it), replay uses :func:`estimate_run` (the service's estimator worker and alert
policy, fed exactly as the pipeline feeds them). Everything else in ``gateway.fleet``
works on :class:`RunSamples` and :class:`RunEstimates`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway import __version__
from gateway.alerts.policy import AlertPolicy, ParamPolicy, default_params
from gateway.can.codec import default_codec
from gateway.can.logs import read_log
from gateway.config import Config
from gateway.frontend.chain import FrontEnd
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL, Theta
from gateway.offline.replay import alert_json
from gateway.records import Alert, Estimate, Sample
from gateway.runtime.pipeline import worker_settings
from gateway.runtime.worker import BLOCK_SAMPLES, WorkerLink

PARAMS: tuple[str, ...] = PARAM_NAMES
"""Csy (N s/m), Csay (N s/m), conicity (-), in the estimator's order."""
NOMINAL: dict[str, float] = dict(zip(PARAM_NAMES, THETA_NOMINAL.as_array(), strict=True))
ON_TIME_FRAMES = 1000
"""Frames between ``on_time`` calls, as ``gateway.offline.replay.replay``."""

__all__ = ["NOMINAL", "PARAMS", "RunEstimates", "RunSamples", "Theta", "estimate_run",
           "estimator_version", "frontend_version", "log_samples", "thresholds", "unit_alerts"]


@dataclass(frozen=True)
class RunSamples:
    """The front end's output for one log. ``t_s`` (K,) receive time, s (the log's clock);
    ``values`` (K, ny) SI units, NaN = missing; ``speed_mps`` (K,); ``update`` (K,) bool;
    ``sensors`` the ny sensor names; ``frames`` read, ``rejected`` by reason."""

    t_s: np.ndarray
    values: np.ndarray
    speed_mps: np.ndarray
    update: np.ndarray
    sensors: tuple[str, ...]
    frames: int
    rejected: dict[str, int]


@dataclass(frozen=True)
class RunEstimates:
    """What the estimator made of one run: ``t_s`` (E,), ``mean``/``std`` (E, 3) in
    :data:`PARAMS` order and units; ``alerts`` as ``gateway replay`` reports them;
    ``unresolved`` (E, 3) bool: the sensors in use could not resolve that parameter
    (``Estimate.unresolved``: a dead node, a low speed)."""

    t_s: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    ess: np.ndarray
    alerts: tuple[dict[str, object], ...]
    unresolved: np.ndarray


def thresholds() -> dict[str, ParamPolicy]:
    """The gateway's alert thresholds (``gateway.alerts.policy.default_params``), by parameter."""
    return default_params()


RESULT_CODE = ("estimator", "model", "alerts", "runtime")
"""The gateway packages whose code makes a replay result from stored samples (besides
the settings; the samples' own front end is in :func:`frontend_version`)."""
FRONTEND_CODE = ("can", "frontend")
"""The gateway packages whose code makes a run's grid samples from its log."""


def frontend_version(cfg: Config) -> str:
    """The gateway version plus a hash of the front end's settings (resampler, gating)
    and of its code (:data:`FRONTEND_CODE`): a run's stored samples carry it, and ingest
    makes a run's samples again when it differs (an improved front end re-processes the
    store, as an improved estimator does)."""
    settings = json.dumps({"resampler": dataclasses.asdict(cfg.resampler),
                           "gating": dataclasses.asdict(cfg.gating)}, sort_keys=True)
    h = hashlib.sha256(settings.encode())
    h.update(code_digest(FRONTEND_CODE).encode())
    return f"{__version__}-{h.hexdigest()[:10]}"


def estimator_version(cfg: Config) -> str:
    """The gateway version plus a hash of every estimator setting, of the front end that
    made the samples (:func:`frontend_version`) and of the code that makes a result from
    them (:data:`RESULT_CODE`): results are keyed by it, so a changed estimator or front
    end (even within one release) or new settings re-process every run, and old results
    stay. Replay uses only runs whose samples this front end made."""
    settings = json.dumps({"estimator": dataclasses.asdict(cfg.estimator),
                           "frontend": frontend_version(cfg)}, sort_keys=True)
    h = hashlib.sha256(settings.encode())
    h.update(code_digest(RESULT_CODE).encode())
    return f"{__version__}-{h.hexdigest()[:10]}"


@functools.cache
def code_digest(packages: tuple[str, ...]) -> str:
    """SHA-256 over the sources of the gateway's ``packages`` (relative path and bytes)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for f in sorted(p for pkg in packages for p in (root / pkg).rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def log_samples(path: str | Path, cfg: Config) -> RunSamples:
    """Frames of a CAN log through the service's front end; InputError for a bad log."""
    front = FrontEnd(cfg, default_codec())
    out: list[Sample] = []
    frames = 0
    for msg in read_log(path):
        if msg.is_error_frame:
            continue
        out += front.on_frame(msg)
        frames += 1
        if frames % ON_TIME_FRAMES == 0:
            out += front.on_time(msg.timestamp)
    out += front.finish()
    ny = len(out[0].values) if out else cfg.estimator.sensors
    from gateway.model.vehicle import SENSORS_3, SENSORS_5

    sensors = SENSORS_3 if ny == 3 else SENSORS_5
    return RunSamples(
        t_s=np.array([s.t_s for s in out], dtype=np.float64),
        values=np.array([s.values for s in out], dtype=np.float64).reshape(len(out), ny),
        speed_mps=np.array([s.speed_mps for s in out], dtype=np.float64),
        update=np.array([s.update for s in out], dtype=bool),
        sensors=sensors, frames=frames, rejected=dict(front.validator.stats.rejected))


def estimate_run(samples: RunSamples, cfg: Config) -> RunEstimates:
    """The service's estimator worker and alert policy over stored samples (replay-style:
    blocking queue, so the result does not depend on the machine's speed)."""
    estimates: list[Estimate] = []
    alerts: list[Alert] = []
    policy = AlertPolicy()

    def handle(batch: list[Estimate]) -> None:
        for est in batch:
            estimates.append(est)
            alerts.extend(policy.step(est))

    link = WorkerLink(worker_settings(cfg),
                      queue_blocks=max(2, cfg.estimator.queue_samples // BLOCK_SAMPLES),
                      blocking=True, keep_spare=False)
    try:
        for k in range(0, len(samples.t_s), BLOCK_SAMPLES):
            link.send([Sample(float(samples.t_s[i]), samples.values[i],
                              float(samples.speed_mps[i]), bool(samples.update[i]))
                       for i in range(k, min(k + BLOCK_SAMPLES, len(samples.t_s)))])
            handle(link.poll())
        handle(link.drain())
    finally:
        handle(link.close())
    n = len(estimates)
    return RunEstimates(
        t_s=np.array([e.t_s for e in estimates], dtype=np.float64),
        mean=np.array([e.mean[:3] for e in estimates], dtype=np.float64).reshape(n, 3),
        std=np.array([e.std[:3] for e in estimates], dtype=np.float64).reshape(n, 3),
        ess=np.array([e.ess for e in estimates], dtype=np.float64),
        alerts=tuple(alert_json(a) for a in alerts),
        unresolved=np.array([[p in e.unresolved for p in PARAMS] for e in estimates],
                            dtype=bool).reshape(n, 3))


def unit_alerts(runs: list[RunEstimates]) -> list[dict[str, object]]:
    """The gateway's alert policy (default thresholds and hold times) over one unit's runs
    in calendar order, one policy for all of them, as on a vehicle whose policy state
    survives between runs: an alarm raised in one run stays raised in the next until an
    estimate clears it; a parameter the sensors in use could not resolve is not judged,
    as on the vehicle. Events as ``gateway replay`` reports them."""
    policy = AlertPolicy()
    out: list[dict[str, object]] = []
    for r in runs:
        for k in range(len(r.t_s)):
            est = Estimate(float(r.t_s[k]), tuple(map(float, r.mean[k])),
                           tuple(map(float, r.std[k])), float(r.ess[k]),
                           unresolved=tuple(p for j, p in enumerate(PARAMS)
                                            if r.unresolved[k, j]))
            out.extend(alert_json(a) for a in policy.step(est))
    return out
