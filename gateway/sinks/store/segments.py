"""A size-bounded append-only JSON Lines log: a current file plus numbered rotated segments.

``alerts.jsonl`` is the current file; once an append would take it past
``LogBounds.segment_bytes`` it is renamed to ``alerts.<N>.jsonl`` (N one more than the
newest segment, so numbers only grow) and a new current file is started; only the newest
``LogBounds.keep_segments`` segments are kept. Disk use per log stays under
``segment_bytes * (keep_segments + 1)`` plus one record.

Rotation is one ``rename`` (then an fsync of the directory), so a record is in exactly
one file at every instant: a SIGKILL anywhere leaves either the old layout or the new one,
never a lost or doubled line. :meth:`SegmentedLog.recover` (run on open) finishes what a
crash left: a torn last line is cut off, surplus old segments are deleted.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gateway.errors import StateError
from gateway.sinks.store.files import (
    JsonlWriter,
    dumps_line,
    fsync_dir,
    read_jsonl_backwards,
    repair_tail,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LogBounds:
    """Size bound of one log: rotate at ``segment_bytes``, keep ``keep_segments`` old ones."""

    segment_bytes: int
    keep_segments: int

    def __post_init__(self) -> None:
        if not (isinstance(self.segment_bytes, int) and self.segment_bytes >= 256):
            raise StateError(f"expected segment_bytes an integer >= 256, "
                             f"got {self.segment_bytes!r}")
        if not (isinstance(self.keep_segments, int) and 1 <= self.keep_segments <= 10000):
            raise StateError(f"expected keep_segments an integer in 1..10000, "
                             f"got {self.keep_segments!r}")

    @property
    def max_bytes(self) -> int:
        """Upper bound of the log's disk use, bytes (one record over a segment at most)."""
        return self.segment_bytes * (self.keep_segments + 1)


class SegmentedLog:
    """One bounded log named ``name`` (``<stem>.jsonl``) in ``directory``; not thread-safe
    (the store holds its lock around every call). Methods raise OSError on I/O failure."""

    def __init__(self, directory: Path, name: str, bounds: LogBounds) -> None:
        if not name.endswith(".jsonl"):
            raise StateError(f"expected a log name ending in .jsonl, got {name!r}")
        self.directory = directory
        self.name = name
        self.bounds = bounds
        self.path = directory / name
        self._pattern = re.compile(re.escape(name[:-len(".jsonl")]) + r"\.([0-9]+)\.jsonl")
        self._writer = JsonlWriter(self.path)
        self.rotations = 0
        """Rotations done by this process (for tests and health)."""

    def segments(self) -> list[tuple[int, Path]]:
        """The rotated segments ``[(N, path), ...]``, oldest (smallest N) first."""
        found = []
        for entry in os.scandir(self.directory):
            m = self._pattern.fullmatch(entry.name)
            if m:
                found.append((int(m.group(1)), self.directory / entry.name))
        return sorted(found)

    def paths(self) -> list[Path]:
        """Every file of the log, oldest first: the segments, then the current file."""
        return [p for _, p in self.segments()] + [self.path]

    def recover(self) -> None:
        """Finish what a crash left: cut a torn last line off the current file and the
        newest segment, and delete segments beyond ``keep_segments``."""
        segs = self.segments()
        for path in ([segs[-1][1]] if segs else []) + [self.path]:
            repair_tail(path)
        self._trim(segs)

    def _trim(self, segs: list[tuple[int, Path]]) -> None:
        surplus = segs[:max(0, len(segs) - self.bounds.keep_segments)]
        for _, path in surplus:
            path.unlink(missing_ok=True)
            log.info("state: retention: deleted %s", path.name)
        if surplus:
            fsync_dir(self.directory)

    def rotate(self) -> None:
        """Rename the current file to the next segment number (fsync of the directory),
        then apply retention. A new current file is created by the next append."""
        self._writer.close()
        segs = self.segments()
        n = segs[-1][0] + 1 if segs else 1
        target = self.directory / f"{self.name[:-len('.jsonl')]}.{n}.jsonl"
        os.replace(self.path, target)
        fsync_dir(self.directory)
        self.rotations += 1
        self._trim(segs + [(n, target)])

    def append(self, objects: list[dict[str, Any]]) -> None:
        """Append records durably (fsynced), rotating first if they would not fit."""
        data_len = sum(len(dumps_line(o)) for o in objects)
        if not data_len:
            return
        size = self._writer.size_bytes()
        if size and size + data_len > self.bounds.segment_bytes:
            self.rotate()
        self._writer.append(objects)

    def size_bytes(self) -> int:
        """Size of the current file, bytes."""
        return self._writer.size_bytes()

    def backwards(self, block_bytes: int = 65536) -> Iterator[tuple[Path, int, dict[str, Any]]]:
        """``(path, byte_offset, object)`` from the newest record to the oldest, reading
        each file from its end in blocks (StateError names the file of a bad line)."""
        for path in reversed(self.paths()):
            for off, obj in read_jsonl_backwards(path, block_bytes):
                yield path, off, obj

    def close(self) -> None:
        """Close the current file; idempotent (the next append reopens it)."""
        self._writer.close()
