"""The state directory: everything the service persists, written durably, read back at start.

Over 400 lines, on purpose: the state directory's one API (every file's name and
write rule); its file primitives, segments, ledger and codec are separate modules.

Files (in ``state_dir``; see ``docs/alerts.md``)::

    checkpoint.bin      estimator checkpoint, latest only            atomic replace
    alert_policy.json   alert-policy snapshot                        atomic replace
    alert_seq.bin       alert seqs reserved so far (two slots)       in-place write + fsync
    console_lockout.json  the console's PIN lockout                  atomic replace
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
from gateway.sinks.store import codec
from gateway.sinks.store.codec import (
    AlertEntry,
    AuditEntry,
    BaselineEntry,
    Checkpoint,
    EstimateEntry,
)
from gateway.sinks.store.files import (
    TMP_SUFFIX,
    atomic_write,
    file_kind,
    first_line,
    fsync_dir,
    read_records,
    read_regular,
)
from gateway.sinks.store.ledger import SeqLedger, read_ledger
from gateway.sinks.store.segments import LogBounds, SegmentedLog

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
CONSOLE_LOCKOUT = "console_lockout.json"
"""The console's PIN-lockout state (owned by gateway.console), atomically replaced."""
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
    The estimate history keeps one point per ``history_interval_s`` of data time; its
    current segment is also rotated once its first point is ``history_keep_s`` old, and
    readers return at most ``history_keep_s`` of it. ``bounds`` overrides
    :data:`DEFAULT_BOUNDS` per log; ``history_max_bytes`` (if given) bounds the estimate
    history's total. Thread-safe: one lock around every file operation.
    """

    def __init__(self, state_dir: str | os.PathLike[str], *,
                 clock: Callable[[], float] = time.time, history_interval_s: float = 10.0,
                 history_keep_s: float = 7 * 86400.0, history_max_bytes: int | None = None,
                 bounds: Mapping[str, LogBounds] | None = None,
                 on_corrupt: Literal["raise", "quarantine"] = "raise") -> None:
        if on_corrupt not in ("raise", "quarantine"):
            raise StateError(f"expected on_corrupt 'raise' or 'quarantine', got {on_corrupt!r}")
        self.path = Path(state_dir)
        self._clock = clock
        self._interval_s = history_interval_s
        self._keep_s = history_keep_s
        self._on_corrupt = on_corrupt
        self._lock = threading.Lock()
        self.failures: dict[str, int] = {}
        """Failed writes per file name since start (for health reporting)."""
        self.problems: list[str] = []
        """Human-readable problems met while loading (corrupt files set aside, ...)."""
        self._quarantined: list[str] = []
        self._failing: set[str] = set()
        self._closed = False
        all_bounds = dict(DEFAULT_BOUNDS)
        if history_max_bytes is not None:
            keep = all_bounds[ESTIMATES].keep_segments
            all_bounds[ESTIMATES] = LogBounds(max(256, history_max_bytes // (keep + 1)), keep)
        all_bounds.update(bounds or {})
        unknown = sorted(set(all_bounds) - set(DEFAULT_BOUNDS))
        if unknown:
            raise StateError(f"expected bounds for logs in {sorted(DEFAULT_BOUNDS)}, "
                             f"got {unknown}")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            if (self.path / LOCK).is_dir():
                os.replace(self.path / LOCK, self.path / f"{LOCK}.corrupt-1")
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
            try:
                leftover.unlink(missing_ok=True)
            except OSError:                         # a directory, ...: set it aside
                self._set_aside(leftover.name, "a leftover temporary that is not a file")
        self._logs = {name: SegmentedLog(self.path, name, all_bounds[name])
                      for name in (ALERTS, ESTIMATES, BASELINES, AUDIT)}
        self._ledger: SeqLedger | None = None
        self._seq_reserved: int | None = 0
        if on_corrupt == "quarantine":
            self._check_at_start()
        else:
            for lg in self._logs.values():
                lg.recover()
            self._seq_reserved = read_ledger(self.path / SEQ_LEDGER) or 0
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
            for closer in [lg.close for lg in self._logs.values()] + (
                    [self._ledger.close] if self._ledger else []):
                try:
                    closer()
                except OSError as err:
                    log.warning("state: closing a file in %s: %s", self.path, err)
            os.close(self._lock_fd)

    @property
    def write_failures(self) -> int:
        """Total failed writes since start (health: ``failures`` has them per file)."""
        return sum(self.failures.values())

    @property
    def quarantined(self) -> tuple[str, ...]:
        """Names of the files set aside (as ``<name>.corrupt-N``) since start, in order;
        non-empty means the service started without some of its state (a health flag).
        :attr:`problems` says why, one line each."""
        return tuple(self._quarantined)

    def bounds(self, name: str) -> LogBounds:
        """The rotation bound of log ``name`` (``ALERTS``, ``ESTIMATES``, ...)."""
        return self._logs[name].bounds

    def log_paths(self, name: str) -> list[Path]:
        """Every file of log ``name``, oldest first (rotated segments, then current)."""
        return self._logs[name].paths()

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

    def quarantine(self, name: str, why: str) -> None:
        """Set file ``name`` aside as ``name.corrupt-N`` (a journal line, an entry in
        :attr:`problems` and :attr:`quarantined`): for callers that find a file unusable
        for reasons the store cannot see (an alert-policy snapshot of the wrong shape)."""
        with self._lock:
            self._set_aside(name, why)

    def _set_aside(self, name: str, why: str) -> None:
        src = self.path / name
        for lg in self._logs.values() if hasattr(self, "_logs") else ():
            lg.close()
        if name == SEQ_LEDGER and self._ledger is not None:
            self._ledger.close()
            self._ledger = None
        olds = sorted((int(p.name.rsplit("-", 1)[1]), p)
                      for p in self.path.glob(f"{name}.corrupt-*")
                      if p.name.rsplit("-", 1)[1].isdigit())
        n = olds[-1][0] + 1 if olds else 1
        try:
            os.replace(src, self.path / f"{name}.corrupt-{n}")
            for _, old in olds[:max(0, len(olds) + 1 - QUARANTINE_KEEP)]:
                if old.is_dir() and not old.is_symlink():
                    old.rmdir() if not any(old.iterdir()) else None
                else:
                    old.unlink(missing_ok=True)
            fsync_dir(self.path)
        except OSError as err:
            why += f" (could not set it aside: {err.strerror})"
        self.problems.append(f"{name}: {why}")
        self._quarantined.append(name)
        log.error("state: %s set aside as %s.corrupt-%d: %s", name, name, n, why)

    def _check_at_start(self) -> None:
        """Quarantine mode: set aside every file that is not a regular file, repair the
        logs' torn tails and check the current file of each log line by line (bounded by
        its segment size); alerts are checked as :meth:`read_alerts` reads them."""
        names = [CHECKPOINT, POLICY, SEQ_LEDGER, CONSOLE_LOCKOUT]
        names += [p.name for lg in self._logs.values() for p in lg.paths()]
        for name in names:
            try:
                mode = os.lstat(self.path / name).st_mode
            except FileNotFoundError:
                continue
            except OSError as err:
                mode, name = 0, f"{name}"
                self._set_aside(name, f"cannot be examined: {err.strerror}")
                continue
            if not stat.S_ISREG(mode):
                kind = file_kind(mode)
                self._set_aside(name, f"expected a regular file, got {kind}")
        for name, lg in self._logs.items():
            try:
                lg.recover()
            except (OSError, StateError) as err:
                self._set_aside(name, f"cannot be repaired: {err}")
        decoders: dict[str, Callable[[dict[str, Any]], object]] = {
            ESTIMATES: codec.estimate_from_json, BASELINES: codec.baseline_from_json,
            AUDIT: codec.audit_from_json}
        for name, decode in decoders.items():
            self._read_file(self.path / name, name, decode)
        try:
            self._seq_reserved = read_ledger(self.path / SEQ_LEDGER) or 0
        except (OSError, StateError) as err:
            self._set_aside(SEQ_LEDGER, f"unusable: {err}; one seq block is skipped")
            self._seq_reserved = None

    def _read_file(self, path: Path, name: str, decode: Callable[[dict[str, Any]], T]
                   ) -> list[T]:
        try:
            return read_records(path, f"a {name}", decode)
        except (StateError, OSError) as err:
            if self._on_corrupt == "raise":
                if isinstance(err, OSError):
                    raise StateError(f"expected a readable {path}, got {err.strerror}") from err
                raise
            self._set_aside(path.name, str(err) if isinstance(err, StateError)
                            else f"unreadable: {err.strerror}")
            return []

    def _read_lines(self, name: str, decode: Callable[[dict[str, Any]], T]) -> list[T]:
        return [x for path in self._logs[name].paths() for x in self._read_file(path, name, decode)]

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
                data = read_regular(self.path / CHECKPOINT)
                return codec.decode_checkpoint(data)
            except FileNotFoundError:
                return None
            except (OSError, ValueError, StateError) as err:
                self._set_aside(CHECKPOINT, f"unusable checkpoint, estimator starts fresh: {err}")
                return None

    # -- alert policy, seq ledger and history ---------------------------------------------
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
                snapshot = json.loads(read_regular(path))
                if not isinstance(snapshot, dict):
                    raise ValueError(f"a {type(snapshot).__name__}")
                return snapshot
            except FileNotFoundError:
                return None
            except (OSError, ValueError, RecursionError, StateError) as err:
                why = "nesting too deep" if isinstance(err, RecursionError) else str(err)
                if self._on_corrupt == "raise":
                    raise StateError(f"{path}: expected a JSON object, got {why}") from err
                self._set_aside(POLICY, why)
                return None

    def seq_reserved_upto(self) -> int | None:
        """Seqs below this may have been used (0: no ledger yet; None: the ledger was
        unusable and set aside, so the caller should skip a block)."""
        return self._seq_reserved

    def reserve_seqs(self, upto: int) -> bool:
        """Durably record that seqs below ``upto`` may be used (before using them)."""
        def write() -> None:
            if self._ledger is None:
                self._ledger = SeqLedger(self.path / SEQ_LEDGER, upto)
            self._ledger.reserve(upto)
        ok = self._write(SEQ_LEDGER, write)
        if ok:
            self._seq_reserved = upto
        return ok

    def append_alert(self, alert: Alert) -> bool:
        """Append one alert event to the history, fsynced before returning."""
        return self.append_alerts([alert])

    def append_alerts(self, alerts: Iterable[Alert]) -> bool:
        """Append alert events to the history, fsynced before returning."""
        now = self._clock()
        lines = [codec.alert_to_json(a, now) for a in alerts]
        return not lines or self._write(ALERTS, lambda: self._logs[ALERTS].append(lines))

    def read_alerts(self, last: int | None = None,
                    since_seq: int | None = None) -> list[AlertEntry]:
        """Persisted alert events, oldest first (a torn last line is skipped): all of them,
        or, if ``last`` or ``since_seq`` is given, only the tail holding the ``last`` newest
        events and every event with ``seq >= since_seq``, read backwards from the end."""
        with self._lock:
            if last is None and since_seq is None:
                return self._read_lines(ALERTS, codec.alert_from_json)
            for _ in range(len(self._logs[ALERTS].paths()) + 1):
                try:
                    return self._tail_alerts(last or 0, since_seq)
                except StateError as err:
                    if self._on_corrupt == "raise":
                        raise
                    bad = err.args[0].split(":", 1)[0]
                    self._set_aside(Path(bad).name, str(err))
            return []

    def _tail_alerts(self, last: int, since_seq: int | None) -> list[AlertEntry]:
        out: list[AlertEntry] = []
        for path, off, obj in self._logs[ALERTS].backwards():
            try:
                entry = codec.alert_from_json(obj)
            except (KeyError, TypeError, ValueError, RecursionError) as err:
                raise StateError(f"{path}: expected an alerts record at byte {off}, got "
                                 f"{json.dumps(obj)[:80]} ({err!r})") from err
            if len(out) >= last and (since_seq is None or entry.alert.seq < since_seq):
                break
            out.append(entry)
        return out[::-1]

    # -- estimate history -------------------------------------------------------------
    def record_estimate(self, estimate: Estimate) -> bool:
        """Keep ``estimate`` if ``history_interval_s`` of data time have passed since the
        last kept one (or data time went back). False only if the write failed."""
        last = self._last_history_t_s
        if last is not None and last <= estimate.t_s < last + self._interval_s:
            return True
        now = self._clock()
        line = codec.estimate_to_json(estimate, now)
        history = self._logs[ESTIMATES]

        def append() -> None:
            seg = self._segment_wall_s
            if history.size_bytes() and seg is not None and now - seg >= self._keep_s:
                history.rotate()
                self._segment_wall_s = None
            rotations = history.rotations
            history.append([line])
            if self._segment_wall_s is None or history.rotations != rotations:
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
            entries = self._read_lines(ESTIMATES, codec.estimate_from_json)
        return [e for e in entries if not e.wall_time_s < floor]

    # -- baselines and audit ------------------------------------------------------------
    def append_baseline(self, parameter: str, t_s: float, note: str = "") -> bool:
        """Record a baseline reset of ``parameter`` at data time ``t_s``."""
        line = codec.baseline_to_json(BaselineEntry(parameter, t_s, self._clock(), note))
        return self._write(BASELINES, lambda: self._logs[BASELINES].append([line]))

    def read_baselines(self) -> list[BaselineEntry]:
        """Every retained baseline reset, oldest first."""
        with self._lock:
            return self._read_lines(BASELINES, codec.baseline_from_json)

    def append_audit(self, command: str, ok: bool, detail: str = "",
                     t_s: float | None = None) -> bool:
        """Record a console write command (``ok``: carried out), with optional data time."""
        line = codec.audit_to_json(AuditEntry(self._clock(), command, ok, detail, t_s))
        return self._write(AUDIT, lambda: self._logs[AUDIT].append([line]))

    def read_audit(self, last: int | None = None) -> list[AuditEntry]:
        """The retained audit log, oldest first; only the ``last`` entries if given."""
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
                state = json.loads(read_regular(path))
                if not isinstance(state, dict):
                    raise ValueError(f"a {type(state).__name__}")
                return state
            except FileNotFoundError:
                return None
            except (OSError, ValueError, RecursionError, StateError) as err:
                why = "nesting too deep" if isinstance(err, RecursionError) else str(err)
                if self._on_corrupt == "quarantine":
                    self._set_aside(CONSOLE_LOCKOUT, why)
                raise StateError(f"{path}: expected a JSON object, got {why}") from err
