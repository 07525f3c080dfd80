"""The alert-seq ledger: how far alert seqs are reserved, durable even on a full disk.

``alert_seq.bin`` is 1024 bytes: two 512-byte slots, each
``MAGIC | u64 LE generation | u64 LE reserved_upto | u32 LE CRC-32 of the 24 bytes before``.
A reservation overwrites the older slot in place (``pwrite`` then ``fsync``) and the
reader takes the valid slot with the higher generation, so a torn write leaves the other
slot good. Overwriting blocks the file already owns needs no new space, so reservations
still succeed when the disk is full and appends fail (tested on a full tmpfs).
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

from gateway.errors import StateError
from gateway.sinks.store.files import atomic_write, open_regular

MAGIC = b"RGWSEQ01"
SLOT_BYTES = 512
_BODY = struct.Struct("<8sQQ")
_CRC = struct.Struct("<I")


def _slot(generation: int, reserved_upto: int) -> bytes:
    body = _BODY.pack(MAGIC, generation, reserved_upto)
    return (body + _CRC.pack(zlib.crc32(body))).ljust(SLOT_BYTES, b"\0")


def _parse(slot: bytes) -> tuple[int, int] | None:
    body = slot[:_BODY.size]
    if len(slot) < _BODY.size + _CRC.size:
        return None
    (crc,) = _CRC.unpack_from(slot, _BODY.size)
    magic, generation, upto = _BODY.unpack(body)
    if magic != MAGIC or crc != zlib.crc32(body):
        return None
    return generation, upto


def read_ledger(path: Path) -> int | None:
    """``reserved_upto`` from the ledger; None if there is no ledger yet. StateError if
    it exists but no slot is valid (or it is not a regular file)."""
    try:
        fd = open_regular(path)
    except FileNotFoundError:
        return None
    with os.fdopen(fd, "rb") as f:
        data = f.read(2 * SLOT_BYTES + 1)
    if len(data) != 2 * SLOT_BYTES:
        raise StateError(f"{path}: expected {2 * SLOT_BYTES} bytes, got {len(data)}")
    slots = [s for s in (_parse(data[:SLOT_BYTES]), _parse(data[SLOT_BYTES:])) if s]
    if not slots:
        raise StateError(f"{path}: expected a valid seq-ledger slot, got none (bad magic "
                         f"or CRC in both)")
    return max(slots)[1]


class SeqLedger:
    """Writes reservations to ``path``; :meth:`reserve` raises OSError on I/O failure."""

    def __init__(self, path: Path, reserved_upto: int) -> None:
        self.path = path
        self.reserved_upto = reserved_upto
        self._generation = 0
        self._fd: int | None = None

    def _open(self) -> int:
        if self._fd is None:
            if not self.path.exists():          # first use: both slots, atomically
                atomic_write(self.path, _slot(0, self.reserved_upto) * 2)
            fd = os.open(self.path, os.O_RDWR | os.O_CLOEXEC)
            data = os.pread(fd, 2 * SLOT_BYTES, 0)
            slots = [s for s in (_parse(data[:SLOT_BYTES]), _parse(data[SLOT_BYTES:])) if s]
            self._generation = max(slots)[0] if slots else 0
            self._fd = fd
        return self._fd

    def reserve(self, upto: int) -> None:
        """Durably record that seqs below ``upto`` may have been used."""
        fd = self._open()
        gen = self._generation + 1
        os.pwrite(fd, _slot(gen, upto), SLOT_BYTES * (gen % 2))
        os.fsync(fd)
        self._generation, self.reserved_upto = gen, upto

    def close(self) -> None:
        """Close the file; idempotent."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)
