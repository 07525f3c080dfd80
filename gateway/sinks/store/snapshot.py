"""Read a copied state directory without touching it: its estimate and alert histories.

For offline tools (``railgw fleet ingest``) that gather state directories copied off
vehicles. Unlike :class:`~gateway.sinks.store.store.StateStore` it takes no lock, creates
and repairs nothing, and reads every retained segment regardless of age; the records are
decoded by the same codec the service writes with. A torn last line is skipped (as the
service does at start); any other bad record is a :class:`StateError` naming file and line.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from gateway.errors import StateError
from gateway.sinks.store import codec
from gateway.sinks.store.codec import AlertEntry, EstimateEntry
from gateway.sinks.store.files import read_records
from gateway.sinks.store.segments import SegmentedLog
from gateway.sinks.store.store import ALERTS, DEFAULT_BOUNDS, ESTIMATES

T = TypeVar("T")
LOGS = (ESTIMATES, ALERTS)
"""The logs a snapshot reads (with their rotated segments)."""


@dataclass(frozen=True)
class StateSnapshot:
    """What a state directory holds of the past, oldest first; ``sha256`` of the bytes of
    every file read (name and content), so an unchanged copy is recognised."""

    path: Path
    estimates: tuple[EstimateEntry, ...]
    alerts: tuple[AlertEntry, ...]
    sha256: str


def is_state_dir(path: Path) -> bool:
    """True if ``path`` is a directory holding an estimate or alert history."""
    return path.is_dir() and any(files_of(path, name) for name in LOGS)


def files_of(directory: Path, name: str) -> list[Path]:
    """The existing files of one log, oldest first (rotated segments, then the current)."""
    log = SegmentedLog(directory, name, DEFAULT_BOUNDS[name])
    return [p for p in log.paths() if p.is_file()]


def read_snapshot(directory: str | Path) -> StateSnapshot:
    """The estimate and alert histories of a state directory; StateError if unreadable."""
    path = Path(directory)
    if not path.is_dir():
        raise StateError(f"expected a state directory, got {str(path)!r} (not a directory)")
    h = hashlib.sha256()
    estimates = _read(path, ESTIMATES, "an estimate-history", codec.estimate_from_json, h)
    alerts = _read(path, ALERTS, "an alert-history", codec.alert_from_json, h)
    return StateSnapshot(path, tuple(estimates), tuple(alerts), h.hexdigest())


def _read(directory: Path, name: str, what: str, decode: Callable[[dict[str, Any]], T],
          h: Any) -> list[T]:
    out: list[T] = []
    for f in files_of(directory, name):
        try:
            h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
            out += read_records(f, what, decode)
        except OSError as err:
            raise StateError(f"expected a readable {f}, got {err.strerror}") from err
    return out
