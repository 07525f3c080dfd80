"""CAN log files as a frame source: any log python-can reads, errors as InputError."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import can
from can.io.blf import BLFParseError

from gateway.errors import InputError


def read_log(path: str | Path) -> Iterator[can.Message]:
    """Frames of a CAN log; InputError for a missing or unreadable file."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"expected a CAN log file, got {str(p)!r} (not found)")
    try:
        reader = can.LogReader(str(p))
    except (ValueError, ImportError, OSError, struct.error, BLFParseError, zlib.error) as err:
        raise InputError(f"expected a CAN log python-can can read (.log, .asc, .blf, ...), "
                         f"got {str(p)!r}: {err or type(err).__name__}") from err
    try:
        yield from reader
    except (ValueError, OSError, IndexError, struct.error, BLFParseError, zlib.error) as err:
        raise InputError(f"expected a well-formed CAN log, got an error in {str(p)!r}: "
                         f"{err or type(err).__name__}") from err
