"""The persisted record formats of the state directory and their JSON/binary codecs.

Decoders raise ``ValueError``/``KeyError``/``TypeError`` on malformed input; the store
turns those into :class:`gateway.errors.StateError` naming the file and line. JSON has no
NaN: non-finite floats are written as ``null`` and read back as NaN
(:func:`gateway.jsonform.finite`, :func:`gateway.jsonform.number`). Alert and estimate
lines are built from the one JSON form in :mod:`gateway.jsonform`.
"""

from __future__ import annotations

import hashlib
import json
import struct
from dataclasses import dataclass
from typing import Any

from gateway import jsonform
from gateway.jsonform import finite, number
from gateway.records import Alert, Estimate

CHECKPOINT_MAGIC = b"RGWCKPT1"
"""First 8 bytes of ``checkpoint.bin``; then u32 LE header length, JSON header, blob."""
CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class Checkpoint:
    """The estimator's latest checkpoint: an opaque ``blob`` and its metadata.

    ``t_s`` data time of the state; ``wall_time_s`` Unix time when saved; ``version`` the
    estimator's own format tag, so that it can refuse a checkpoint it cannot read.
    """

    blob: bytes
    t_s: float
    wall_time_s: float
    version: str


@dataclass(frozen=True)
class AlertEntry:
    """An alert event as persisted, with the Unix time it was written."""

    alert: Alert
    wall_time_s: float


@dataclass(frozen=True)
class EstimateEntry:
    """One estimate-history point: ``mean``/``std`` in ``names`` order (N s/m, N s/m, -);
    ``unresolved`` the parameters its sensors could not resolve (``Estimate.unresolved``)."""

    t_s: float
    wall_time_s: float
    names: tuple[str, ...]
    mean: tuple[float, ...]
    std: tuple[float, ...]
    ess: float
    unresolved: tuple[str, ...] = ()


@dataclass(frozen=True)
class BaselineEntry:
    """A baseline reset of one parameter (component replaced), at data and Unix time."""

    parameter: str
    t_s: float
    wall_time_s: float
    note: str = ""


@dataclass(frozen=True)
class AuditEntry:
    """One console write command: what was asked, whether it was done, and when."""

    wall_time_s: float
    command: str
    ok: bool
    detail: str = ""
    t_s: float | None = None


def alert_to_json(a: Alert, wall_time_s: float) -> dict[str, Any]:
    """An alert-history line: the one alert form plus the Unix time it was written."""
    return {**jsonform.alert_json(a), "wall_time_s": finite(wall_time_s)}


def alert_from_json(d: dict[str, Any]) -> AlertEntry:
    return AlertEntry(jsonform.alert_from_json(d), number(d["wall_time_s"]))


def estimate_to_json(e: Estimate, wall_time_s: float) -> dict[str, Any]:
    """An estimate-history line, derived from the one estimate form: only ``t_s``,
    ``ess`` and ``params``, each parameter as a ``[mean, std]`` pair, plus
    ``wall_time_s``, and ``unresolved`` only while there are any (since 2026-11-28). It
    differs because it is the persisted format (docs/alerts.md: files already written
    must load) and because it is compact: the history keeps 14 days at one point per 10
    s in 32 MiB; ``{"mean", "std"}`` objects make a line ~18 % longer. The alert line
    needs no such difference: it is the one form plus ``wall_time_s``."""
    j = jsonform.estimate_json(e)
    line = {"t_s": j["t_s"], "wall_time_s": finite(wall_time_s), "ess": j["ess"],
            "params": {n: [p["mean"], p["std"]] for n, p in j["params"].items()}}
    if j["unresolved"]:
        line["unresolved"] = j["unresolved"]
    return line


def estimate_from_json(d: dict[str, Any]) -> EstimateEntry:
    params = d["params"]
    names = tuple(str(n) for n in params)
    mean = tuple(number(params[n][0]) for n in names)
    std = tuple(number(params[n][1]) for n in names)
    return EstimateEntry(number(d["t_s"]), number(d["wall_time_s"]), names, mean, std,
                         number(d["ess"]), tuple(str(n) for n in d.get("unresolved", ())))


def baseline_to_json(b: BaselineEntry) -> dict[str, Any]:
    return {"parameter": b.parameter, "t_s": finite(b.t_s), "wall_time_s": finite(b.wall_time_s),
            "note": b.note}


def baseline_from_json(d: dict[str, Any]) -> BaselineEntry:
    return BaselineEntry(str(d["parameter"]), number(d["t_s"]), number(d["wall_time_s"]),
                         str(d.get("note", "")))


def audit_to_json(a: AuditEntry) -> dict[str, Any]:
    return {"wall_time_s": finite(a.wall_time_s), "command": a.command, "ok": a.ok,
            "detail": a.detail, "t_s": None if a.t_s is None else finite(a.t_s)}


def audit_from_json(d: dict[str, Any]) -> AuditEntry:
    if not isinstance(d["ok"], bool):
        raise TypeError(f"expected ok true/false, got {d['ok']!r}")
    return AuditEntry(number(d["wall_time_s"]), str(d["command"]), d["ok"],
                      str(d.get("detail", "")), None if d.get("t_s") is None else number(d["t_s"]))


def encode_checkpoint(c: Checkpoint) -> bytes:
    """``MAGIC | u32 LE header length | header JSON | blob``; the header holds the blob's
    size and SHA-256, so that a torn or bit-rotted checkpoint is detected on load."""
    header = json.dumps({"format": CHECKPOINT_FORMAT, "t_s": finite(c.t_s),
                         "wall_time_s": finite(c.wall_time_s), "version": c.version,
                         "size": len(c.blob), "sha256": hashlib.sha256(c.blob).hexdigest()},
                        allow_nan=False).encode()
    return CHECKPOINT_MAGIC + struct.pack("<I", len(header)) + header + c.blob


def decode_checkpoint(data: bytes) -> Checkpoint:
    """Inverse of :func:`encode_checkpoint`; ValueError ("expected ..., got ...") if corrupt."""
    n = len(CHECKPOINT_MAGIC)
    if data[:n] != CHECKPOINT_MAGIC:
        raise ValueError(f"expected magic {CHECKPOINT_MAGIC!r}, got {data[:n]!r}")
    if len(data) < n + 4:
        raise ValueError(f"expected a header length, got {len(data)} bytes in all")
    (hlen,) = struct.unpack_from("<I", data, n)
    try:
        h = json.loads(data[n + 4:n + 4 + hlen])
        blob = data[n + 4 + hlen:]
        if h["format"] != CHECKPOINT_FORMAT:
            raise ValueError(f"expected format {CHECKPOINT_FORMAT}, got {h['format']!r}")
        if len(blob) != h["size"] or hashlib.sha256(blob).hexdigest() != h["sha256"]:
            raise ValueError(f"expected a {h['size']}-byte blob with SHA-256 {h['sha256']}, "
                             f"got {len(blob)} bytes that do not match")
        return Checkpoint(blob, number(h["t_s"]), number(h["wall_time_s"]), str(h["version"]))
    except (KeyError, TypeError) as err:
        raise ValueError(f"expected a checkpoint header, got {data[n + 4:n + 4 + hlen]!r} "
                         f"({err!r})") from err
