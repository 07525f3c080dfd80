"""Byte encoding of estimator checkpoints: a JSON header and an npz body, bit-exact.

Layout: ``MAGIC``, the header length (uint64 little-endian), the UTF-8 JSON header
(scalars, configuration, the numpy Generator state), then an ``.npz`` archive of the
arrays. No pickle: loading a checkpoint never executes code. No I/O here; the caller
stores the bytes.
"""

from __future__ import annotations

import io
import json
import struct
from typing import Any

import numpy as np

from gateway.errors import EstimatorError

MAGIC = b"RBPF-CKPT-1\n"


def pack(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> bytes:
    """Encode a JSON-able ``meta`` and named arrays."""
    buf = io.BytesIO()
    named: dict[str, Any] = dict(arrays)
    np.savez(buf, **named)
    head = json.dumps(meta).encode()
    return MAGIC + struct.pack("<Q", len(head)) + head + buf.getvalue()


def unpack(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Decode :func:`pack` output; EstimatorError on anything else."""
    if not data.startswith(MAGIC):
        raise EstimatorError(f"expected a checkpoint starting {MAGIC!r}, "
                             f"got {bytes(data[:len(MAGIC)])!r}")
    try:
        off = len(MAGIC)
        (n,) = struct.unpack("<Q", data[off:off + 8])
        meta = json.loads(data[off + 8:off + 8 + n])
        with np.load(io.BytesIO(data[off + 8 + n:]), allow_pickle=False) as npz:
            arrays = {k: np.ascontiguousarray(npz[k]) for k in npz.files}
    except (ValueError, KeyError, TypeError, struct.error, OSError, EOFError) as err:
        raise EstimatorError(f"expected a readable checkpoint, got {err}") from err
    return meta, arrays


def generator_state(rng: np.random.Generator) -> dict[str, Any]:
    """The Generator's bit-generator state (JSON-able)."""
    return dict(rng.bit_generator.state)


def generator_from_state(state: dict[str, Any]) -> np.random.Generator:
    """A Generator that continues exactly from ``state``."""
    try:
        bitgen = getattr(np.random, state["bit_generator"])()
        bitgen.state = state
    except (AttributeError, KeyError, TypeError, ValueError) as err:
        raise EstimatorError(f"expected a numpy bit-generator state, got {err}") from err
    return np.random.Generator(bitgen)
