"""State directories copied off vehicles into the store: on-board estimate and alert histories.

A gateway's state directory (``docs/alerts.md``) keeps what the vehicle itself said: an
estimate-history point every 10 s and every alert event. A fleet engineer copies it off
the vehicle again and again, so copies overlap. Ingest reads a copy read-only
(:func:`gateway.sinks.store.snapshot.read_snapshot`, the service's own codec) and keeps
each entry once:

- a copy whose bytes were ingested before (``state-manifest.jsonl``) is skipped;
- of a new copy, only entries not already stored for that unit are written: estimates
  keyed by (Unix time written, data time), alerts by (seq, data time), seq being unique
  and growing per service across restarts.

Layout in the store (hive partitions, read with the rest by pyarrow, Dask or DuckDB)::

    state-manifest.jsonl                                            one line per copy
    onboard/estimates/vehicle=V/bogie=B/day=D/part-<sha16>.parquet   new estimates
    onboard/alerts/vehicle=V/bogie=B/day=D/part-<sha16>.parquet      new alert events

``day`` is the UTC date of the Unix time the vehicle wrote the entry. Parts are written
atomically before the manifest line; a crash in between leaves entries that the next
ingest finds already stored, so nothing is counted twice.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gateway.fleet.runs import PARAMS
from gateway.jsonform import alert_json
from gateway.sinks.store.codec import AlertEntry, EstimateEntry
from gateway.sinks.store.snapshot import StateSnapshot

STATE_MANIFEST = "state-manifest.jsonl"
KINDS = ("estimates", "alerts")


@dataclass(frozen=True)
class StateInfo:
    """One ingested state-directory copy: its content hash, where it came from, whose it
    is, and how many entries it added (0 when all were stored already)."""

    sha256: str
    source: str
    vehicle: str
    bogie: str
    estimates: int
    alerts: int


@dataclass(frozen=True)
class OnboardHistory:
    """A unit's on-board history, oldest first. ``estimates``: ``wall_s`` (E,) Unix time
    written, ``mean``/``std`` (E, 3) in :data:`PARAMS` order and units; ``alerts`` in the
    :func:`gateway.jsonform.alert_json` form plus ``wall_time_s``; ``unresolved`` (E, 3)
    bool, the parameters the vehicle's sensors could not resolve (False in parts
    ingested before 2026-11-28)."""

    wall_s: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    alerts: tuple[dict[str, object], ...]
    unresolved: np.ndarray


def unit_dir(root: Path, kind: str, vehicle: str, bogie: str) -> Path:
    return root / "onboard" / kind / f"vehicle={vehicle}" / f"bogie={bogie}"


def state_infos(root: Path) -> list[StateInfo]:
    """Every ingested copy, in ingest order (a torn last line is ignored)."""
    path = root / STATE_MANIFEST
    if not path.is_file():
        return []
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            out.append(StateInfo(**json.loads(line)))
        except (ValueError, TypeError):
            continue
    return out


def onboard_units(root: Path) -> list[tuple[str, str]]:
    """(vehicle, bogie) of every unit with an ingested state directory, sorted."""
    return sorted({(s.vehicle, s.bogie) for s in state_infos(root)})


def daily_points(board: OnboardHistory
                 ) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """A unit's on-board history as one point per UTC day: its last estimate that day
    (``wall_s``, ``mean`` (3,), ``std`` (3,), ``unresolved`` (3,) bool), oldest first;
    the trend input for a unit whose logs were not kept."""
    last: dict[str, int] = {}
    for k, w in enumerate(board.wall_s):
        last[_day(float(w))] = k
    return [(float(board.wall_s[k]), board.mean[k], board.std[k], board.unresolved[k])
            for _, k in sorted(last.items())]


def _day(wall_s: float) -> str:
    return dt.datetime.fromtimestamp(wall_s, dt.UTC).date().isoformat()


def _stored_keys(root: Path, kind: str, vehicle: str, bogie: str,
                 cols: tuple[str, str]) -> set[tuple[float, float]]:
    d = unit_dir(root, kind, vehicle, bogie)
    keys: set[tuple[float, float]] = set()
    for f in sorted(d.glob("day=*/part-*.parquet")):
        t = pq.read_table(f, columns=list(cols))
        keys.update(zip(t.column(cols[0]).to_pylist(), t.column(cols[1]).to_pylist(),
                        strict=True))
    return keys


def _estimate_rows(entries: Iterable[EstimateEntry]) -> list[dict[str, float]]:
    rows = []
    for e in entries:
        row = {"wall_time_s": e.wall_time_s, "t_s": e.t_s, "ess": e.ess}
        for p in PARAMS:
            i = e.names.index(p) if p in e.names else -1
            row[f"{p}_mean"] = e.mean[i] if i >= 0 else float("nan")
            row[f"{p}_std"] = e.std[i] if i >= 0 else float("nan")
            row[f"{p}_unresolved"] = p in e.unresolved
        rows.append(row)
    return rows


def _alert_rows(entries: Iterable[AlertEntry]) -> list[dict[str, object]]:
    return [{**alert_json(a.alert), "wall_time_s": a.wall_time_s} for a in entries]


def new_parts(root: Path, snap: StateSnapshot, vehicle: str,
              bogie: str) -> tuple[list[tuple[Path, pa.Table]], StateInfo]:
    """The Parquet parts holding a copy's entries that the store lacks (paths relative to
    ``root``), and the copy's manifest line. The caller writes both, parts first."""
    seen_est = _stored_keys(root, "estimates", vehicle, bogie, ("wall_time_s", "t_s"))
    new_est = [r for r in _estimate_rows(snap.estimates)
               if (r["wall_time_s"], r["t_s"]) not in seen_est]
    seen_alerts = _stored_keys(root, "alerts", vehicle, bogie, ("seq", "t_s"))
    new_alerts = [r for r in _alert_rows(snap.alerts) if (r["seq"], r["t_s"]) not in seen_alerts]
    meta = {"railgw.source": str(snap.path.resolve()), "railgw.state_sha256": snap.sha256}
    parts = []
    for kind, rows in (("estimates", new_est), ("alerts", new_alerts)):
        by_day: dict[str, list[dict[str, object]]] = {}
        for r in rows:
            by_day.setdefault(_day(float(r["wall_time_s"])), []).append(r)  # type: ignore[arg-type]
        for day, part in sorted(by_day.items()):
            parts.append((unit_dir(Path(), kind, vehicle, bogie) / f"day={day}"
                          / f"part-{snap.sha256[:16]}.parquet",
                          pa.Table.from_pylist(part).replace_schema_metadata(meta)))
    return parts, StateInfo(snap.sha256, str(snap.path.resolve()), vehicle, bogie,
                            len(new_est), len(new_alerts))


def read_onboard(root: Path, vehicle: str, bogie: str) -> OnboardHistory:
    """A unit's stored on-board history (empty arrays when none was ingested)."""
    est = sorted((row for f in sorted(unit_dir(root, "estimates", vehicle, bogie).glob(
        "day=*/part-*.parquet")) for row in pq.read_table(f).to_pylist()),
        key=lambda r: (r["wall_time_s"], r["t_s"]))
    alerts = sorted((row for f in sorted(unit_dir(root, "alerts", vehicle, bogie).glob(
        "day=*/part-*.parquet")) for row in pq.read_table(f).to_pylist()),
        key=lambda r: (r["wall_time_s"], r["seq"]))
    n = len(est)
    return OnboardHistory(
        wall_s=np.array([r["wall_time_s"] for r in est], dtype=np.float64),
        mean=np.array([[r[f"{p}_mean"] for p in PARAMS] for r in est],
                      dtype=np.float64).reshape(n, 3),
        std=np.array([[r[f"{p}_std"] for p in PARAMS] for r in est],
                     dtype=np.float64).reshape(n, 3),
        unresolved=np.array([[bool(r.get(f"{p}_unresolved", False)) for p in PARAMS]
                             for r in est], dtype=bool).reshape(n, 3),
        alerts=tuple(alerts))
