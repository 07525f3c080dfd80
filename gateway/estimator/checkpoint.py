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


def pack(meta: dict[str, Any], arrays: dict[str, np.ndarray], magic: bytes = MAGIC) -> bytes:
    """Encode a JSON-able ``meta`` and named arrays, after ``magic``."""
    buf = io.BytesIO()
    named: dict[str, Any] = dict(arrays)
    np.savez(buf, **named)
    head = json.dumps(meta).encode()
    return magic + struct.pack("<Q", len(head)) + head + buf.getvalue()


def unpack(data: bytes, magic: bytes = MAGIC) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Decode :func:`pack` output made with ``magic``; EstimatorError on anything else."""
    if not data.startswith(magic):
        raise EstimatorError(f"expected a checkpoint starting {magic!r}, "
                             f"got {bytes(data[:len(magic)])!r}")
    try:
        off = len(magic)
        (n,) = struct.unpack("<Q", data[off:off + 8])
        meta = json.loads(data[off + 8:off + 8 + n])
        with np.load(io.BytesIO(data[off + 8 + n:]), allow_pickle=False) as npz:
            arrays = {k: np.ascontiguousarray(npz[k]) for k in npz.files}
    except (ValueError, KeyError, TypeError, struct.error, OSError, EOFError) as err:
        raise EstimatorError(f"expected a readable checkpoint, got {err}") from err
    return meta, arrays


def generator_state(rng: np.random.Generator) -> dict[str, Any]:
    """The Generator's bit-generator state and its SeedSequence (JSON-able).

    The SeedSequence matters too: scipy's QMC engines (the prior's Halton points) spawn
    their seed from it, so a restore that kept only the bit state would draw from fresh
    OS entropy after a restart, and the run would no longer equal an uninterrupted one.
    """
    state = dict(rng.bit_generator.state)
    seq = rng.bit_generator.seed_seq
    if isinstance(seq, np.random.SeedSequence):
        state["seed_seq"] = {"entropy": seq.entropy, "spawn_key": list(seq.spawn_key),
                             "pool_size": seq.pool_size,
                             "n_children_spawned": seq.n_children_spawned}
    return state


def generator_from_state(state: dict[str, Any]) -> np.random.Generator:
    """A Generator that continues exactly from ``state`` (a checkpoint without the
    SeedSequence, from before it was kept, restores the bit state alone)."""
    try:
        state = dict(state)
        seq = state.pop("seed_seq", None)
        kind = getattr(np.random, state["bit_generator"])
        bitgen = kind() if seq is None else kind(np.random.SeedSequence(
            seq["entropy"], spawn_key=tuple(seq["spawn_key"]), pool_size=seq["pool_size"],
            n_children_spawned=seq["n_children_spawned"]))
        bitgen.state = state
    except (AttributeError, KeyError, TypeError, ValueError) as err:
        raise EstimatorError(f"expected a numpy bit-generator state, got {err}") from err
    return np.random.Generator(bitgen)
