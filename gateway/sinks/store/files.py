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
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

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


def loads_object(line: bytes) -> dict[str, Any] | None:
    """The JSON object on ``line``, or None if it is not one (bad JSON, another type, or
    nesting deep enough to raise RecursionError)."""
    try:
        obj = json.loads(line)
    except (ValueError, RecursionError):
        return None
    return obj if isinstance(obj, dict) else None


def _parses(line: bytes) -> bool:
    return loads_object(line) is not None


def file_kind(mode: int) -> str:
    """What a non-regular file is, for messages: "a directory", "a FIFO", ..."""
    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISLNK, "a symbolic link"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device")):
        if test(mode):
            return kind
    return f"file type {stat.S_IFMT(mode):#o}"


def open_regular(path: Path) -> int:
    """A read-only descriptor on ``path``; StateError if it is not a regular file (a
    directory, a FIFO that would block the reader, a device). FileNotFoundError passes."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = file_kind(mode)
        raise StateError(f"{path}: expected a regular file, got {kind}")
    return fd


def read_regular(path: Path) -> bytes:
    """The whole content of a regular file (see :func:`open_regular`)."""
    fd = open_regular(path)
    with os.fdopen(fd, "rb") as f:
        return f.read()


def repair_tail(path: Path) -> int:
    """Drop a torn last line (no newline, or not a JSON object) so that appends start on a
    clean line; returns the number of bytes dropped (0 if the file is clean or missing)."""
    try:
        fd = open_regular(path)
    except FileNotFoundError:
        return 0
    with os.fdopen(fd, "rb") as f:
        size = os.fstat(f.fileno()).st_size
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
        data = read_regular(path)
    except FileNotFoundError:
        return []
    lines = data.split(b"\n")
    last = max((i for i, line in enumerate(lines) if line.strip()), default=-1)
    out = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        obj = loads_object(line)
        if obj is not None:
            out.append((i + 1, obj))
        elif i == last:
            log.warning("state: %s:%d: skipped a torn last line", path, i + 1)
        else:
            raise StateError(f"{path}:{i + 1}: expected a JSON object per line, "
                             f"got {line[:60]!r}")
    return out


T = TypeVar("T")


def read_records(path: Path, what: str, decode: Callable[[dict[str, Any]], T]) -> list[T]:
    """:func:`read_jsonl`, each object through ``decode``; a record it rejects is a
    StateError "<path>:<line>: expected <what> record, got ..."."""
    out = []
    for line_no, obj in read_jsonl(path):
        try:
            out.append(decode(obj))
        except (KeyError, TypeError, ValueError, RecursionError) as err:
            raise StateError(f"{path}:{line_no}: expected {what} record, got "
                             f"{json.dumps(obj)[:80]} ({err!r})") from err
    return out


def read_jsonl_backwards(path: Path, block_bytes: int = TAIL_BYTES
                         ) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(byte_offset, object)`` of a JSON Lines file from the last line to the first,
    reading ``block_bytes`` at a time from the end (nothing if missing). A torn last line
    is skipped with a warning; any other bad line is a StateError naming its byte offset."""
    try:
        fd = open_regular(path)
    except FileNotFoundError:
        return
    try:
        end = os.fstat(fd).st_size
        carry = b""                          # the start of a line cut by a block edge
        first = True
        while end > 0 or carry:
            start = max(0, end - block_bytes)
            chunk = os.pread(fd, end - start, start) + carry if end > 0 else carry
            lines = chunk.split(b"\n")
            carry = lines.pop(0) if start > 0 else b""
            offset = start + len(carry) + (1 if start > 0 else 0)
            found = []
            for line in lines:
                found.append((offset, line))
                offset += len(line) + 1
            for off, line in reversed(found):
                if not line.strip():
                    continue
                obj = loads_object(line)
                if obj is None:
                    if not first:
                        raise StateError(f"{path}: expected a JSON object per line, got "
                                         f"{line[:60]!r} at byte {off}")
                    log.warning("state: %s: skipped a torn last line", path)
                    first = False
                    continue
                first = False
                yield off, obj
            end = start
            if start == 0:
                break
    finally:
        os.close(fd)


def first_line(path: Path) -> dict[str, Any] | None:
    """The first record of a JSON Lines file, or None if missing, empty or unparsable."""
    try:
        fd = open_regular(path)
        with os.fdopen(fd, "rb") as f:
            line = f.readline(TAIL_BYTES)
    except (OSError, StateError):
        return None
    return loads_object(line)


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
