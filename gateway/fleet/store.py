"""The fleet's Parquet store: ingest logs once (idempotent by content hash), list and read runs.

Layout of a store directory (hive partitions, so pyarrow, Dask and DuckDB read it as one
dataset)::

    manifest.jsonl                                   one line per ingested file
    samples/vehicle=V/bogie=B/day=YYYY-MM-DD/run-<id>.parquet     front-end output
    results/estimator=<ver>/vehicle=V/bogie=B/day=D/run-<id>.parquet   replay output
    state-manifest.jsonl, onboard/...     copied state directories (gateway.fleet.onboard)

A run's id is the first 16 hex digits of the SHA-256 of the log's bytes: a file seen
before (under any name) is skipped, so re-ingesting counts nothing twice, unless its
samples were made by another front end (``frontend``, :func:`gateway.fleet.runs.frontend_version`):
then its samples are made again and replace the old ones (the manifest's last line for
a file wins). Every file
is written to a temporary name and renamed into place; the manifest line is appended
(and fsynced) after the rename, and a crash in between only means the same file is
rewritten identically next time. One ingest at a time per store (a lock file).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import hashlib
import json
import logging
import os
import re
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gateway.config import Config
from gateway.errors import InputError
from gateway.fleet.onboard import STATE_MANIFEST, StateInfo, new_parts, state_infos
from gateway.fleet.runs import RunSamples, frontend_version, log_samples
from gateway.sinks.store.snapshot import is_state_dir, read_snapshot

log = logging.getLogger(__name__)

LOG_SUFFIXES = (".log", ".asc", ".blf")
MANIFEST = "manifest.jsonl"
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
INGEST_RETRIES = 2
"""Re-runs of an ingest task that raised (a lost worker is rescheduled anyway)."""
EPOCH_MIN_S = 946_684_800.0
"""2000-01-01 UTC: a log whose clock starts before this has relative timestamps."""


@dataclass(frozen=True)
class RunInfo:
    """One ingested log (a manifest line). ``t0_s``/``t1_s`` first and last grid time,
    s since the Unix epoch; ``grid_points`` 0 when the front end made no sample."""

    run_id: str
    sha256: str
    source: str
    vehicle: str
    bogie: str
    day: str
    t0_s: float
    t1_s: float
    grid_points: int
    frames: int
    sensors: tuple[str, ...]
    frontend: str = ""
    """The front end that made the samples (:func:`gateway.fleet.runs.frontend_version`);
    empty for a run ingested before front ends were versioned."""

    @property
    def samples_path(self) -> str:
        """Relative to the store."""
        return (f"samples/vehicle={self.vehicle}/bogie={self.bogie}/day={self.day}/"
                f"run-{self.run_id}.parquet")


@dataclass(frozen=True)
class IngestReport:
    """What one ingest did: runs added, state-directory copies added, files and copies
    skipped as already stored (by hash); ``replaced`` the run ids among ``added`` whose
    older samples, made by another front end, were replaced."""

    added: tuple[RunInfo, ...]
    skipped: tuple[str, ...]
    states: tuple[StateInfo, ...] = ()
    replaced: tuple[str, ...] = ()


def check_name(kind: str, text: str) -> str:
    """A vehicle or bogie name safe as a path part; InputError otherwise."""
    if not NAME.match(text) or "=" in text:
        raise InputError(f"expected a {kind} name of letters, digits, '_', '.', '-' "
                         f"(at most 64), got {text!r}")
    return text


def write_atomic_table(table: pa.Table, path: Path) -> None:
    """Write a Parquet file under a unique temporary name, fsync, rename into ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        pq.write_table(table, tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class Store:
    """A store directory (created on first ingest)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise InputError(f"expected a fleet store directory, got file {str(self.root)!r}")

    # ---------------------------------------------------------------- manifest
    def runs(self) -> list[RunInfo]:
        """Every ingested run, once, in first-ingest order; of several lines for one file
        (samples made again by a newer front end) the last wins. A torn last line is
        ignored."""
        path = self.root / MANIFEST
        if not path.is_file():
            return []
        out: dict[str, RunInfo] = {}
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            try:
                d = json.loads(line)
                d["sensors"] = tuple(d["sensors"])
                info = RunInfo(**d)
            except (ValueError, TypeError, KeyError) as err:
                log.warning("%s:%d: unreadable manifest line skipped (%s)", path, n, err)
                continue
            out[info.sha256] = info
        return list(out.values())

    def _append(self, info: RunInfo | StateInfo) -> None:
        name = MANIFEST if isinstance(info, RunInfo) else STATE_MANIFEST
        with open(self.root / name, "a", encoding="utf-8") as f:
            f.write(json.dumps(asdict(info), sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the store's ingest lock (one writer at a time)."""
        self.root.mkdir(parents=True, exist_ok=True)
        with open(self.root / ".lock", "w") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise InputError(f"expected no other ingest running on {self.root}, got its "
                                 f"lock held") from None
            yield

    # ------------------------------------------------------------------ ingest
    def ingest(self, paths: Sequence[str | Path], cfg: Config, *, vehicle: str | None = None,
               bogie: str | None = None, client: Any = None,
               progress: Callable[[int, int], None] | None = None) -> IngestReport:
        """Ingest CAN logs (files, or directories searched for .log/.asc/.blf) and gateway
        state directories (given, or found in those directories). With a Dask ``client``
        the logs are decoded one per task on its workers (which must see the logs and the
        store at the same paths); the manifest is written here, as each task finishes."""
        files = discover(paths, vehicle, bogie)
        states = discover_states(paths, vehicle, bogie)
        added: list[RunInfo] = []
        skipped: list[str] = []
        new_states: list[StateInfo] = []
        with self.locked():
            known_states = {s.sha256 for s in state_infos(self.root)}
            for path, veh, bog in states:
                snap = read_snapshot(path)
                if snap.sha256 in known_states:
                    skipped.append(str(path))
                    continue
                parts, sinfo = new_parts(self.root, snap, veh, bog)
                for rel, table in parts:
                    write_atomic_table(table, self.root / rel)
                self._append(sinfo)
                known_states.add(snap.sha256)
                new_states.append(sinfo)
            known = {r.sha256: r for r in self.runs()}
            frontend = frontend_version(cfg)
            todo: list[tuple[str, str, str, str]] = []
            queued: set[str] = set()
            for path, veh, bog in files:
                sha = file_sha256(path)
                old = known.get(sha)
                if sha in queued or old is not None and old.frontend == frontend:
                    skipped.append(str(path))
                    continue
                if old is not None:     # samples of another front end: make them again
                    veh, bog = old.vehicle, old.bogie
                queued.add(sha)
                todo.append((str(path.resolve()), sha, veh, bog))
            root = str(self.root.resolve())
            replaced: list[str] = []
            for info in _ingest_all(root, todo, cfg, client):
                self._append(info)
                added.append(info)
                old = known.get(info.sha256)
                if old is not None:
                    replaced.append(info.run_id)
                    if old.samples_path != info.samples_path:   # another day: not overwritten
                        with contextlib.suppress(FileNotFoundError):
                            (self.root / old.samples_path).unlink()
                if progress is not None:
                    progress(len(added), len(todo))
        return IngestReport(tuple(added), tuple(skipped), tuple(new_states), tuple(replaced))

    # -------------------------------------------------------------------- read
    def samples(self, info: RunInfo) -> RunSamples:
        """The stored front-end output of a run."""
        return read_samples(self.root / info.samples_path)


def _ingest_all(root: str, todo: list[tuple[str, str, str, str]], cfg: Config,
                client: Any) -> Iterator[RunInfo]:
    """:func:`ingest_log` over ``todo`` (path, sha256, vehicle, bogie): here, in order, or
    one Dask task per log, yielded as they finish (the rest cancelled if one fails)."""
    if client is None:
        for path, sha, veh, bog in todo:
            yield ingest_log(root, path, sha, veh, bog, cfg)
        return
    from distributed import as_completed

    futures = [client.submit(ingest_log, root, path, sha, veh, bog, cfg,
                             key=f"railgw-ingest-{sha[:16]}", retries=INGEST_RETRIES,
                             pure=False) for path, sha, veh, bog in todo]
    try:
        for fut in as_completed(futures):
            yield fut.result()
    except BaseException:
        client.cancel(futures)
        raise


def ingest_log(root: str, path: str, sha: str, vehicle: str, bogie: str,
               cfg: Config) -> RunInfo:
    """One log through the service's front end into ``root``'s samples (written
    atomically under the run id, so a retried task rewrites the same file); its manifest
    line is the caller's to write."""
    s = log_samples(path, cfg)
    if len(s.t_s) and not s.t_s[0] >= EPOCH_MIN_S:
        raise InputError(f"expected absolute (Unix epoch) timestamps in {path!r} to "
                         f"date the run, got a clock starting at {s.t_s[0]:.3f} s")
    t0 = float(s.t_s[0]) if len(s.t_s) else float("nan")
    day = (dt.datetime.fromtimestamp(t0, dt.UTC).date().isoformat() if len(s.t_s)
           else "unknown")
    info = RunInfo(run_id=sha[:16], sha256=sha, source=path, vehicle=vehicle,
                   bogie=bogie, day=day, t0_s=t0,
                   t1_s=float(s.t_s[-1]) if len(s.t_s) else float("nan"),
                   grid_points=len(s.t_s), frames=s.frames, sensors=s.sensors,
                   frontend=frontend_version(cfg))
    if len(s.t_s):
        write_atomic_table(samples_table(s, info), Path(root) / info.samples_path)
    else:
        log.warning("%s: no grid sample (frames %d, rejected %s)", path, s.frames,
                    s.rejected)
    return info


def samples_table(s: RunSamples, info: RunInfo) -> pa.Table:
    cols = {"t_s": s.t_s, "speed_mps": s.speed_mps, "update": s.update}
    cols.update({name: s.values[:, j] for j, name in enumerate(s.sensors)})
    meta = {"railgw.run_id": info.run_id, "railgw.sensors": json.dumps(list(s.sensors)),
            "railgw.frames": str(s.frames), "railgw.rejected": json.dumps(s.rejected),
            "railgw.source": info.source}
    return pa.table(cols).replace_schema_metadata(meta)


def read_samples(path: Path) -> RunSamples:
    table = pq.read_table(path)
    meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
    sensors = tuple(json.loads(meta["railgw.sensors"]))
    values = np.column_stack([table.column(n).to_numpy() for n in sensors])
    return RunSamples(t_s=table.column("t_s").to_numpy(),
                      values=np.ascontiguousarray(values, dtype=np.float64),
                      speed_mps=table.column("speed_mps").to_numpy(),
                      update=table.column("update").to_numpy(zero_copy_only=False),
                      sensors=sensors, frames=int(meta["railgw.frames"]),
                      rejected=json.loads(meta["railgw.rejected"]))


def discover(paths: Sequence[str | Path], vehicle: str | None,
             bogie: str | None) -> list[tuple[Path, str, str]]:
    """(file, vehicle, bogie) for every log under ``paths``, sorted. Inside a directory a
    log at ``VEHICLE/BOGIE/.../file`` (relative to it) is named by those two folders;
    ``vehicle``/``bogie`` override them (and name loose files)."""
    out: list[tuple[Path, str, str]] = []
    for p in map(Path, paths):
        found: list[tuple[Path, tuple[str, ...]]]
        if p.is_file():
            found = [(p, ())]
        elif p.is_dir():
            found = [(f, f.relative_to(p).parts[:-1]) for f in sorted(p.rglob("*"))
                     if f.is_file() and f.suffix.lower() in LOG_SUFFIXES]
        else:
            raise InputError(f"expected a CAN log, a directory of logs or a gateway state "
                             f"directory, got {str(p)!r} (not found)")
        for f, parts in found:
            if f.suffix.lower() not in LOG_SUFFIXES:
                raise InputError(f"expected a CAN log ending in {list(LOG_SUFFIXES)}, "
                                 f"got {str(f)!r}")
            out.append((f, *unit_of(repr(str(f)), parts, vehicle, bogie)))
    return out


def unit_of(what: str, folders: tuple[str, ...], vehicle: str | None,
            bogie: str | None) -> tuple[str, str]:
    """(vehicle, bogie) of a file or directory from its first two ``folders`` below the
    directory given, ``vehicle``/``bogie`` overriding them; InputError if neither."""
    veh = vehicle or (folders[0] if len(folders) >= 2 else None)
    bog = bogie or (folders[1] if len(folders) >= 2 else None)
    if veh is None or bog is None:
        raise InputError(f"expected {what} under VEHICLE/BOGIE/ folders, or --vehicle and "
                         f"--bogie, got neither")
    return check_name("vehicle", veh), check_name("bogie", bog)


def discover_states(paths: Sequence[str | Path], vehicle: str | None,
                    bogie: str | None) -> list[tuple[Path, str, str]]:
    """(state directory, vehicle, bogie) for every gateway state directory among or under
    ``paths`` (one holding ``estimates.jsonl`` or ``alerts.jsonl``), sorted; named like
    logs: ``VEHICLE/BOGIE/...`` below the directory given, or ``--vehicle``/``--bogie``."""
    out: list[tuple[Path, str, str]] = []
    for p in map(Path, paths):
        if not p.is_dir():
            continue
        for d in [p, *sorted(x for x in p.rglob("*") if x.is_dir())]:
            if not is_state_dir(d):
                continue
            out.append((d, *unit_of(f"state directory {str(d)!r}", d.relative_to(p).parts,
                                    vehicle, bogie)))
    return out
