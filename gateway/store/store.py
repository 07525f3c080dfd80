"""The state directory: everything the service persists, written durably, read back at start.

Files (in ``state_dir``; see ``docs/alerts.md``)::

    checkpoint.bin      estimator checkpoint, latest only            atomic replace
    alert_policy.json   alert-policy snapshot                        atomic replace
    alert_seq.bin       alert seqs reserved so far (two slots)       in-place write + fsync
    alerts.jsonl        alert events, append-only                    fsync per append
    estimates.jsonl     estimate history, one point per 10 s data    fsync per append
    baselines.jsonl     baseline resets                              fsync per append
    audit.jsonl         console write commands                       fsync per append
    <log>.<N>.jsonl     rotated segments of each log (N grows)       rename; newest K kept
    .lock               flock: one store per directory
    *.corrupt-N         a file set aside because it could not be used (newest 3 kept)

Every log is bounded (:data:`DEFAULT_BOUNDS`, :class:`LogBounds`). Write methods never
raise ``OSError`` (a full disk, a read-only file system): they log, count the failure in
:attr:`StateStore.failures` and return False, so the service keeps running. Readers raise
:class:`StateError` for corrupt files (``on_corrupt="raise"``) or set them aside and carry
on (``"quarantine"``, which also checks every file when the store opens); the files set
aside are in :attr:`StateStore.quarantined`. A corrupt checkpoint is always set aside.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import stat
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar

from gateway.errors import StateError
from gateway.records import Alert, Estimate
from gateway.store import codec
from gateway.store.codec import AlertEntry, AuditEntry, BaselineEntry, Checkpoint, EstimateEntry
from gateway.store.files import TMP_SUFFIX, atomic_write, first_line, fsync_dir, read_jsonl, \
    read_regular
from gateway.store.ledger import SeqLedger, read_ledger
from gateway.store.segments import LogBounds, SegmentedLog

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.bin"
POLICY = "alert_policy.json"
SEQ_LEDGER = "alert_seq.bin"
ALERTS = "alerts.jsonl"
ESTIMATES = "estimates.jsonl"
ESTIMATES_PREVIOUS = "estimates.1.jsonl"
"""The first rotated estimate segment (the only one in versions before segment numbers)."""
BASELINES = "baselines.jsonl"
AUDIT = "audit.jsonl"
LOCK = ".lock"
QUARANTINE_KEEP = 3
"""Files set aside (``<name>.corrupt-N``) kept per name; older ones are deleted."""
MiB = 1 << 20
DEFAULT_BOUNDS: Mapping[str, LogBounds] = {
    ALERTS: LogBounds(1 * MiB, 8),          # ~4,000 events a segment, ~36,000 kept
    ESTIMATES: LogBounds(4 * MiB, 7),       # 32 MiB: ~14 days at one point per 10 s
    BASELINES: LogBounds(256 << 10, 3),
    AUDIT: LogBounds(1 * MiB, 8),
}
"""Rotation bound and retention of each log; disk use <= segment_bytes * (keep + 1)."""
T = TypeVar("T")


class StateStore:
    """The service's state directory. A context manager; :meth:`close` is idempotent.

    ``clock`` gives Unix time for the ``wall_time_s`` stamps (inject a fake in tests).
    The estimate history keeps one point per ``history_interval_s`` of data time and at
    least ``history_keep_s`` of wall time, in two segments of at most
    ``history_max_bytes / 2`` each. Thread-safe: one lock around every file operation.
    """

    def __init__(self, state_dir: str | os.PathLike[str], *,
                 clock: Callable[[], float] = time.time, history_interval_s: float = 10.0,
                 history_keep_s: float = 7 * 86400.0, history_max_bytes: int = 32 << 20,
                 on_corrupt: Literal["raise", "quarantine"] = "raise") -> None:
        if on_corrupt not in ("raise", "quarantine"):
            raise StateError(f"expected on_corrupt 'raise' or 'quarantine', got {on_corrupt!r}")
        self.path = Path(state_dir)
        self._clock = clock
        self._interval_s = history_interval_s
        self._keep_s = history_keep_s
        self._max_bytes = history_max_bytes
        self._on_corrupt = on_corrupt
        self._lock = threading.Lock()
        self.failures: dict[str, int] = {}
        """Failed writes per file name since start (for health reporting)."""
        self.problems: list[str] = []
        """Human-readable problems met while loading (corrupt files set aside, ...)."""
        self._failing: set[str] = set()
        self._closed = False
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock_fd = os.open(self.path / LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC,
                                    0o600)
        except OSError as err:
            raise StateError(f"expected a writable state directory, got {self.path}: "
                             f"{err.strerror}") from err
        try:
            fcntl.flock(self._lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            os.close(self._lock_fd)
            raise StateError(f"expected a state directory free for this service, got "
                             f"{self.path} locked by another process") from err
        for leftover in self.path.glob(f".*{TMP_SUFFIX}"):
            leftover.unlink(missing_ok=True)
        self._writers = {name: JsonlWriter(self.path / name)
                         for name in (ALERTS, ESTIMATES, BASELINES, AUDIT)}
        self._last_history_t_s: float | None = None
        first = first_line(self.path / ESTIMATES)
        self._segment_wall_s: float | None = None
        if first is not None and isinstance(first.get("wall_time_s"), int | float):
            self._segment_wall_s = float(first["wall_time_s"])

    # -- plumbing ------------------------------------------------------------------
    def __enter__(self) -> StateStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close every file and release the directory lock; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            for writer in self._writers.values():
                try:
                    writer.close()
                except OSError as err:
                    log.warning("state: closing %s: %s", writer.path, err)
            os.close(self._lock_fd)

    @property
    def write_failures(self) -> int:
        """Total failed writes since start."""
        return sum(self.failures.values())

    def _write(self, name: str, action: Callable[[], None]) -> bool:
        with self._lock:
            if self._closed:
                log.warning("state: %s not written: the store is closed", name)
                return False
            try:
                action()
            except OSError as err:
                self.failures[name] = self.failures.get(name, 0) + 1
                level = logging.DEBUG if name in self._failing else logging.ERROR
                log.log(level, "state: cannot write %s in %s: %s (failure %d; the service "
                        "keeps running)", name, self.path, err, self.failures[name])
                self._failing.add(name)
                return False
            if name in self._failing:
                self._failing.discard(name)
                log.info("state: writing %s works again after %d failures", name,
                         self.failures[name])
            return True

    def _set_aside(self, name: str, why: str) -> None:
        """Rename a corrupt file to ``name.corrupt-N`` and record the problem."""
        src = self.path / name
        n = 1
        while (self.path / f"{name}.corrupt-{n}").exists():
            n += 1
        writer = self._writers.get(name)
        if writer is not None:
            writer.close()
        try:
            os.replace(src, self.path / f"{name}.corrupt-{n}")
            fsync_dir(self.path)
        except OSError as err:
            why += f" (could not set it aside: {err.strerror})"
        self.problems.append(f"{name}: {why}")
        log.error("state: %s set aside as %s.corrupt-%d: %s", name, name, n, why)

    def _read_lines(self, name: str, decode: Callable[[dict[str, Any]], T]) -> list[T]:
        path = self.path / name
        try:
            out = []
            for line_no, obj in read_jsonl(path):
                try:
                    out.append(decode(obj))
                except (KeyError, TypeError, ValueError) as err:
                    raise StateError(f"{path}:{line_no}: expected a {name} record, got "
                                     f"{json.dumps(obj)[:80]} ({err!r})") from err
            return out
        except StateError as err:
            if self._on_corrupt == "raise":
                raise
            self._set_aside(name, str(err))
            return []
        except OSError as err:
            raise StateError(f"expected a readable {path}, got {err.strerror}") from err

    # -- estimator checkpoint ------------------------------------------------------
    def save_checkpoint(self, blob: bytes, t_s: float, version: str = "") -> bool:
        """Replace the checkpoint (``t_s``: its data time; ``version``: the estimator's
        format tag) atomically; False (logged) if it could not be written."""
        data = codec.encode_checkpoint(Checkpoint(bytes(blob), t_s, self._clock(), version))
        return self._write(CHECKPOINT, lambda: atomic_write(self.path / CHECKPOINT, data))

    def load_checkpoint(self) -> Checkpoint | None:
        """The latest checkpoint, or None if there is none or it is corrupt (then it is
        set aside and reported in :attr:`problems`: the estimator starts fresh)."""
        with self._lock:
            try:
                data = (self.path / CHECKPOINT).read_bytes()
                return codec.decode_checkpoint(data)
            except FileNotFoundError:
                return None
            except (OSError, ValueError) as err:
                self._set_aside(CHECKPOINT, f"unusable checkpoint, estimator starts fresh: {err}")
                return None

    # -- alert policy and history ----------------------------------------------------
    def save_policy(self, snapshot: Mapping[str, Any]) -> bool:
        """Replace the alert-policy snapshot (a JSON-compatible dict) atomically."""
        try:
            data = json.dumps(snapshot, allow_nan=False, indent=1).encode()
        except (TypeError, ValueError) as err:
            raise StateError(f"expected a JSON-compatible snapshot, got {err}") from err
        return self._write(POLICY, lambda: atomic_write(self.path / POLICY, data))

    def load_policy(self) -> dict[str, Any] | None:
        """The alert-policy snapshot, or None if there is none. StateError if corrupt
        (or None after setting it aside, with ``on_corrupt="quarantine"``)."""
        path = self.path / POLICY
        with self._lock:
            try:
                snapshot = json.loads(path.read_bytes())
                if not isinstance(snapshot, dict):
                    raise ValueError(f"a {type(snapshot).__name__}")
                return snapshot
            except FileNotFoundError:
                return None
            except (OSError, ValueError) as err:
                if self._on_corrupt == "raise":
                    raise StateError(f"{path}: expected a JSON object, got {err}") from err
                self._set_aside(POLICY, str(err))
                return None

    def append_alert(self, alert: Alert) -> bool:
        """Append one alert event to the history, fsynced before returning."""
        return self.append_alerts([alert])

    def append_alerts(self, alerts: Iterable[Alert]) -> bool:
        """Append alert events to the history, fsynced before returning."""
        now = self._clock()
        lines = [codec.alert_to_json(a, now) for a in alerts]
        return not lines or self._write(ALERTS, lambda: self._writers[ALERTS].append(lines))

    def read_alerts(self) -> list[AlertEntry]:
        """Every persisted alert event, oldest first (a torn last line is skipped)."""
        with self._lock:
            return self._read_lines(ALERTS, codec.alert_from_json)

    # -- estimate history -------------------------------------------------------------
    def record_estimate(self, estimate: Estimate) -> bool:
        """Keep ``estimate`` if ``history_interval_s`` of data time have passed since the
        last kept one (or data time went back). False only if the write failed."""
        last = self._last_history_t_s
        if last is not None and last <= estimate.t_s < last + self._interval_s:
            return True
        now = self._clock()
        line = codec.estimate_to_json(estimate, now)
        writer = self._writers[ESTIMATES]

        def append() -> None:
            seg, size = self._segment_wall_s, writer.size_bytes()
            if size and ((seg is not None and now - seg >= self._keep_s)
                         or size + len(dumps_line(line)) > self._max_bytes // 2):
                writer.close()
                os.replace(self.path / ESTIMATES, self.path / ESTIMATES_PREVIOUS)
                fsync_dir(self.path)
                self._segment_wall_s = None
            writer.append([line])
            if self._segment_wall_s is None:
                self._segment_wall_s = now

        ok = self._write(ESTIMATES, append)
        if ok:
            self._last_history_t_s = estimate.t_s
        return ok

    def read_estimates(self, since_wall_s: float | None = None) -> list[EstimateEntry]:
        """Estimate history, oldest first, within ``history_keep_s`` of now and not older
        than ``since_wall_s`` (Unix time) if given."""
        floor = self._clock() - self._keep_s
        if since_wall_s is not None:
            floor = max(floor, since_wall_s)
        with self._lock:
            entries = (self._read_lines(ESTIMATES_PREVIOUS, codec.estimate_from_json)
                       + self._read_lines(ESTIMATES, codec.estimate_from_json))
        return [e for e in entries if not e.wall_time_s < floor]

    # -- baselines and audit ------------------------------------------------------------
    def append_baseline(self, parameter: str, t_s: float, note: str = "") -> bool:
        """Record a baseline reset of ``parameter`` at data time ``t_s``."""
        line = codec.baseline_to_json(BaselineEntry(parameter, t_s, self._clock(), note))
        return self._write(BASELINES, lambda: self._writers[BASELINES].append([line]))

    def read_baselines(self) -> list[BaselineEntry]:
        """Every baseline reset, oldest first."""
        with self._lock:
            return self._read_lines(BASELINES, codec.baseline_from_json)

    def append_audit(self, command: str, ok: bool, detail: str = "",
                     t_s: float | None = None) -> bool:
        """Record a console write command (``ok``: carried out), with optional data time."""
        line = codec.audit_to_json(AuditEntry(self._clock(), command, ok, detail, t_s))
        return self._write(AUDIT, lambda: self._writers[AUDIT].append([line]))

    def read_audit(self, last: int | None = None) -> list[AuditEntry]:
        """The audit log, oldest first; only the ``last`` entries if given."""
        with self._lock:
            entries = self._read_lines(AUDIT, codec.audit_from_json)
        return entries[-last:] if last else entries

    # -- console PIN lockout (owned by gateway.console; a small separate file) ----------
    def save_console_lockout(self, state: Mapping[str, Any]) -> bool:
        """Replace the console's PIN-lockout state (a small JSON object) atomically."""
        data = json.dumps(dict(state), allow_nan=False).encode()
        return self._write(CONSOLE_LOCKOUT,
                           lambda: atomic_write(self.path / CONSOLE_LOCKOUT, data))

    def load_console_lockout(self) -> dict[str, Any] | None:
        """The console's PIN-lockout state, None if there is none; StateError if unusable
        (set aside first with ``on_corrupt="quarantine"``): the console then fails closed."""
        path = self.path / CONSOLE_LOCKOUT
        with self._lock:
            try:
                state = json.loads(path.read_bytes())
                if not isinstance(state, dict):
                    raise ValueError(f"a {type(state).__name__}")
                return state
            except FileNotFoundError:
                return None
            except (OSError, ValueError, RecursionError) as err:
                if self._on_corrupt == "quarantine":
                    self._set_aside(CONSOLE_LOCKOUT, str(err))
                raise StateError(f"{path}: expected a JSON object, got {err}") from err
