"""Console replies and their wire form: text for a fitter or one JSON object, both bounded.

A :class:`Reply` carries the command name, the machine-readable ``data`` and the
human ``text``. :func:`encode_text` and :func:`encode_json` turn it into bytes with
CRLF line ends and never more than ``max_bytes``: text is cut at a line with a
marker; JSON is shrunk (oldest list items and long strings first) until it fits, so
that it still parses, with ``"truncated": true``.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from dataclasses import dataclass, field
from typing import Any

TRUNCATED_MARKER = "... [reply truncated: {n} bytes over the {cap}-byte limit]"
_MAX_SHRINK_STEPS = 200


@dataclass(frozen=True)
class Reply:
    """One reply: ``ok``, the command, its data (JSON mode), its text (text mode)."""

    ok: bool
    cmd: str
    text: str = ""
    data: Any = None
    error: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def fail(cls, cmd: str, error: str, **extra: Any) -> Reply:
        return cls(False, cmd, text=f"error: {error}", error=error, extra=extra)


def jsonable(x: Any, depth: int = 0) -> Any:
    """``x`` with only JSON types: enums by name, dataclasses as dicts, non-finite -> None."""
    if depth > 20:
        return str(x)
    if x is None or isinstance(x, bool | str):
        return x
    if isinstance(x, enum.Enum):
        return x.name
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        x = {f.name: getattr(x, f.name) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k): jsonable(v, depth + 1) for k, v in x.items()}
    if isinstance(x, list | tuple | set | frozenset):
        return [jsonable(v, depth + 1) for v in x]
    item = getattr(x, "item", None)  # numpy scalars
    if callable(item):
        try:
            return jsonable(item(), depth + 1)
        except (TypeError, ValueError):
            pass
    return str(x)


def to_wire(text: str) -> bytes:
    """Text with any line ends as ASCII bytes with CRLF (non-ASCII becomes '?')."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    return "\r\n".join(lines).encode("ascii", errors="replace")


def encode_text(reply: Reply, max_bytes: int) -> bytes:
    """The text reply, CRLF-terminated, at most ``max_bytes`` (cut with a marker)."""
    body = reply.text if reply.ok or reply.text else f"error: {reply.error}"
    wire = to_wire(body.rstrip("\n")) + b"\r\n" if body else b""
    if len(wire) <= max_bytes:
        return wire
    marker = to_wire(TRUNCATED_MARKER.format(n=len(wire) - max_bytes, cap=max_bytes)) + b"\r\n"
    head = wire[:max(0, max_bytes - len(marker))]
    cut = head.rfind(b"\r\n")
    head = head[:cut + 2] if cut >= 0 else head
    return head + marker


def reply_object(reply: Reply) -> dict[str, Any]:
    """The JSON object of a reply: ``{"ok", "cmd", "data"}`` or ``{"ok", "cmd", "error"}``."""
    obj: dict[str, Any] = {"ok": reply.ok, "cmd": reply.cmd}
    if reply.ok:
        obj["data"] = reply.data
    else:
        obj["error"] = reply.error
    obj.update(reply.extra)
    return jsonable(obj)


def _dump(obj: Any) -> bytes:
    return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode("ascii") + b"\r\n"


def _shrink(x: Any) -> tuple[Any, bool]:
    """A smaller version of ``x`` (drop the oldest half of the biggest list, halve the
    longest string); False when nothing is left to shrink."""
    if isinstance(x, list):
        if len(x) > 1:
            return x[len(x) // 2:], True
        if x:
            inner, ok = _shrink(x[0])
            return ([inner], True) if ok else ([], True)
        return x, False
    if isinstance(x, str):
        return (x[:len(x) // 2] + "...", True) if len(x) > 16 else (x, False)
    if isinstance(x, dict):
        for key in sorted(x, key=lambda k: len(json.dumps(x[k])), reverse=True):
            inner, ok = _shrink(x[key])
            if ok:
                return {**x, key: inner}, True
        return x, False
    return x, False


def encode_json(reply: Reply, max_bytes: int) -> bytes:
    """One JSON object and CRLF, at most ``max_bytes``; shrunk (``"truncated": true``)."""
    obj = reply_object(reply)
    wire = _dump(obj)
    if len(wire) <= max_bytes:
        return wire
    payload_key = "data" if reply.ok else "error"
    payload = obj.get(payload_key)
    for _ in range(_MAX_SHRINK_STEPS):
        payload, shrunk = _shrink(payload)
        wire = _dump({**obj, payload_key: payload, "truncated": True})
        if len(wire) <= max_bytes or not shrunk:
            break
    if len(wire) <= max_bytes:
        return wire
    return _dump({"ok": False, "cmd": str(reply.cmd)[:32],
                  "error": f"reply over the {max_bytes}-byte limit", "truncated": True})
