"""Console PIN hashes: salted scrypt in a self-describing string, checked in constant time.

The stored form is ``scrypt$N$r$p$SALT$HASH`` (SALT and HASH in unpadded base64url,
16 and 32 bytes), e.g. ``scrypt$16384$8$1$...$...``, as ``railgw console hash-pin``
prints it for ``[serial] pin_hash``. scrypt at N = 2**14, r = 8 costs 16 MiB and about
50 ms per guess, so a leaked config no longer gives a short PIN away in a blink, and
the salt makes each gateway's hash its own. Standard library only (``hashlib.scrypt``).

The old unsalted form (64 hex digits of SHA-256) is refused with a message that names
the fix. Pure functions; no I/O.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import os
import re
from dataclasses import dataclass

from gateway.errors import InputError

SCHEME = "scrypt"
N_DEFAULT, R_DEFAULT, P_DEFAULT = 2 ** 14, 8, 1
SALT_BYTES = 16
HASH_BYTES = 32
MAXMEM_BYTES = 64 << 20
"""The largest scrypt memory (128 N r bytes) a stored hash may ask for."""
PIN_MIN_CHARS, PIN_MAX_CHARS = 4, 64
FIX = "make one with 'railgw console hash-pin' and set it as [serial] pin_hash"
_HEX64 = re.compile(r"^[0-9a-fA-F]{64}$")


@dataclass(frozen=True)
class PinHash:
    """A parsed stored PIN hash: scrypt cost (n, r, p), salt and derived key (bytes)."""

    n: int
    r: int
    p: int
    salt: bytes
    digest: bytes

    def text(self) -> str:
        """The self-describing string form."""
        return "$".join((SCHEME, str(self.n), str(self.r), str(self.p), _b64(self.salt),
                         _b64(self.digest)))


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).decode("ascii").rstrip("=")


def _unb64(text: str) -> bytes:
    if not re.fullmatch(r"[A-Za-z0-9_-]+", text):
        raise ValueError("not base64url")
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def _derive(pin: str, salt: bytes, n: int, r: int, p: int) -> bytes:
    return hashlib.scrypt(pin.encode("utf-8"), salt=salt, n=n, r=r, p=p,
                          maxmem=MAXMEM_BYTES + (1 << 20), dklen=HASH_BYTES)


def pin_problem(pin: str) -> str | None:
    """Why ``pin`` cannot be a console PIN ("expected ..., got ..."), or None."""
    if not PIN_MIN_CHARS <= len(pin) <= PIN_MAX_CHARS:
        return (f"expected a PIN of {PIN_MIN_CHARS} to {PIN_MAX_CHARS} characters, "
                f"got {len(pin)}")
    if not all(0x21 <= ord(c) <= 0x7E for c in pin):
        return "expected a PIN of printable ASCII without spaces, got other characters"
    return None


def hash_pin(pin: str, *, salt: bytes | None = None, n: int = N_DEFAULT, r: int = R_DEFAULT,
             p: int = P_DEFAULT) -> str:
    """The stored form of ``pin`` with a fresh random salt (or ``salt``); InputError for a
    PIN the console could not take (see :func:`pin_problem`)."""
    problem = pin_problem(pin)
    if problem:
        raise InputError(problem)
    salt = os.urandom(SALT_BYTES) if salt is None else salt
    parsed = PinHash(n, r, p, salt, b"\0" * HASH_BYTES)
    _check_cost(parsed)
    return PinHash(n, r, p, salt, _derive(pin, salt, n, r, p)).text()


def _check_cost(h: PinHash) -> None:
    if not (h.n >= 2 and h.n & (h.n - 1) == 0 and 1 <= h.r <= 64 and 1 <= h.p <= 16
            and 128 * h.n * h.r <= MAXMEM_BYTES):
        raise ValueError(f"scrypt cost N={h.n} (a power of 2), r={h.r}, p={h.p} out of range")


def parse_pin_hash(text: str) -> PinHash:
    """The :class:`PinHash` of a stored string; InputError ("expected ..., got ...")
    naming the fix for anything else, the old unsalted SHA-256 digest included."""
    t = text.strip()
    if _HEX64.match(t):
        raise InputError(f"expected a salted scrypt PIN hash ({SCHEME}$N$r$p$salt$hash), "
                         f"got an unsalted SHA-256 digest, which is no longer accepted: {FIX}")
    parts = t.split("$")
    try:
        if len(parts) != 6 or parts[0] != SCHEME:
            raise ValueError(f"{len(parts)} '$'-separated fields")
        h = PinHash(int(parts[1]), int(parts[2]), int(parts[3]), _unb64(parts[4]),
                    _unb64(parts[5]))
        _check_cost(h)
        if len(h.salt) < 8 or len(h.digest) != HASH_BYTES:
            raise ValueError(f"a {len(h.salt)}-byte salt and a {len(h.digest)}-byte hash")
    except (ValueError, binascii.Error) as err:
        raise InputError(f"expected a PIN hash '{SCHEME}$N$r$p$salt$hash', got "
                         f"{t[:12]!r}... ({err}): {FIX}") from err
    return h


def pin_hash_problem(text: str) -> str | None:
    """Why ``text`` is not a usable ``[serial] pin_hash`` ('' is: no PIN, writes off)."""
    if not text.strip():
        return None
    try:
        parse_pin_hash(text)
    except InputError as err:
        return str(err)
    return None


def verify_pin(pin: str, stored: PinHash) -> bool:
    """True when ``pin`` matches ``stored`` (constant-time comparison of the keys)."""
    try:
        given = _derive(pin, stored.salt, stored.n, stored.r, stored.p)
    except (ValueError, MemoryError):
        return False
    return hmac.compare_digest(given, stored.digest)
