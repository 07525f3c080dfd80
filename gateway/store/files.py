"""Durable file primitives of the state directory: atomic replace and fsynced JSON Lines.

Writes go straight to file descriptors (``os.write``, no user-space buffer to flush),
then ``os.fsync``. Every function here raises ``OSError`` on I/O failure; the store
decides what a failure means. Corrupt content raises :class:`StateError`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from pathlib import Path
from typing import Any

from gateway.errors import StateError

log = logging.getLogger(__name__)

TMP_SUFFIX = ".tmp"
"""Temporary files are ``.<name>.tmp`` next to their target; leftovers are removed on open."""
TAIL_BYTES = 65536
"""How far back from the end a torn JSON Lines tail is looked for (lines are < 1 KiB)."""


def fsync_dir(path: Path) -> None:
    """fsync a directory, so that a rename or a new file in it is durable."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def atomic_write(path: Path, data: bytes) -> None:
    """Replace ``path`` by ``data``: temp file in the same directory, write, fsync, rename,
    fsync the directory. On failure the previous file is untouched and the temp removed."""
    tmp = path.with_name(f".{path.name}{TMP_SUFFIX}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
    try:
        try:
            _write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    fsync_dir(path.parent)


def dumps_line(obj: Any) -> bytes:
    """One JSON Lines record: compact, strict JSON (no NaN), newline-terminated."""
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode() + b"\n"


def _parses(line: bytes) -> bool:
    try:
        return isinstance(json.loads(line), dict)
    except ValueError:
        return False


def repair_tail(path: Path) -> int:
    """Drop a torn last line (no newline, or not a JSON object) so that appends start on a
    clean line; returns the number of bytes dropped (0 if the file is clean or missing)."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        return 0
    with open(path, "rb") as f:
        start = max(0, size - TAIL_BYTES)
        f.seek(start)
        tail = f.read()
    keep = len(tail)
    if not tail.endswith(b"\n"):
        keep = tail.rfind(b"\n") + 1
    body = tail[:keep]
    last_nl = body.rstrip(b"\n").rfind(b"\n") + 1
    last = body[last_nl:].strip()
    if last and not _parses(last):
        keep = last_nl
    dropped = len(tail) - keep
    if dropped:
        log.warning("state: %s: dropped a torn last line (%d bytes)", path, dropped)
        os.truncate(path, start + keep)
        with open(path, "rb+") as f:
            os.fsync(f.fileno())
    return dropped


def read_jsonl(path: Path) -> list[tuple[int, dict[str, Any]]]:
    """``[(line_number, object), ...]`` of a JSON Lines file ([] if missing). A torn or
    unparsable *last* line is skipped with a warning; any other bad line is a StateError."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    lines = data.split(b"\n")
    last = max((i for i, line in enumerate(lines) if line.strip()), default=-1)
    out = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except ValueError:
            obj = None
        if isinstance(obj, dict):
            out.append((i + 1, obj))
        elif i == last:
            log.warning("state: %s:%d: skipped a torn last line", path, i + 1)
        else:
            raise StateError(f"{path}:{i + 1}: expected a JSON object per line, "
                             f"got {line[:60]!r}")
    return out


def first_line(path: Path) -> dict[str, Any] | None:
    """The first record of a JSON Lines file, or None if missing, empty or unparsable."""
    try:
        with open(path, "rb") as f:
            line = f.readline(TAIL_BYTES)
        obj = json.loads(line)
    except (OSError, ValueError):
        return None
    return obj if isinstance(obj, dict) else None


class JsonlWriter:
    """An append-only JSON Lines file: each append is written and fsynced before returning.

    A failed append is rolled back (truncated) so no half line is left for the next one;
    if even that fails, the file is reopened, and its tail repaired, before the next append.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def _open(self) -> int:
        if self._fd is None:
            repair_tail(self.path)
            existed = self.path.exists()
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC,
                               0o600)
            if not existed:
                fsync_dir(self.path.parent)
        return self._fd

    def append(self, objects: list[dict[str, Any]]) -> None:
        """Append records (one line each) durably; raises OSError with nothing half-written."""
        data = b"".join(dumps_line(o) for o in objects)
        if not data:
            return
        fd = self._open()
        start = os.fstat(fd).st_size
        try:
            _write_all(fd, data)
            os.fsync(fd)
        except OSError:
            try:
                os.ftruncate(fd, start)
            except OSError:
                self.close()
            raise

    def size_bytes(self) -> int:
        """Current file size in bytes (0 if missing)."""
        try:
            return self.path.stat().st_size
        except FileNotFoundError:
            return 0

    def close(self) -> None:
        """Close the descriptor; idempotent. The next append reopens the file."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)
