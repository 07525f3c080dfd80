"""The console's line discipline: raw serial bytes in, complete command lines (and echo) out.

Only printable ASCII (0x20..0x7E) enters a line; TAB becomes a space. CR, LF or CRLF
end a line (an LF right after a CR is swallowed, even across reads). BS (0x08) and
DEL (0x7F) erase one character; Ctrl-U erases the line; Ctrl-C cancels it. Escape
sequences are dropped whole, payload included (ECMA-48): ``ESC x``, ``ESC`` with
intermediates (``ESC ( B``), CSI ``ESC [ ... final`` and SS3 ``ESC O x`` (arrow and
function keys), and the string sequences OSC ``ESC ]``, DCS ``ESC P``, SOS ``ESC X``,
PM ``ESC ^`` and APC ``ESC _``, which run to BEL or ST (``ESC`` + backslash); their 8-bit forms
(0x9B CSI, 0x9D OSC, 0x90 DCS, 0x98, 0x9E, 0x9F) too. CAN/SUB (0x18, 0x1A) or a line
end abandons an unfinished sequence. Every other control or high byte (0x80..0xFF,
NUL) is dropped. A line longer than ``max_line_bytes`` is discarded up to its end and
reported as :class:`TooLong`.

Pure state machine: no I/O, no clock. The state is the partial line and a few flags.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

CR, LF, BS, DEL, TAB, ESC = 0x0D, 0x0A, 0x08, 0x7F, 0x09, 0x1B
CTRL_C, CTRL_U, BEL, CAN, SUB = 0x03, 0x15, 0x07, 0x18, 0x1A
STRING_INTRODUCERS = frozenset(b"]PX^_")
"""After ESC: OSC, DCS, SOS, PM, APC, whose payload runs to BEL or ST."""
C1_STRING = frozenset((0x90, 0x98, 0x9D, 0x9E, 0x9F))
C1_CSI, C1_ST = 0x9B, 0x9C
ERASE = b"\b \b"


@dataclass(frozen=True)
class Line:
    """A complete line, printable ASCII only, without its terminator."""

    text: str


@dataclass(frozen=True)
class TooLong:
    """A line over the cap was discarded; ``length`` bytes (at least) were received."""

    length: int


@dataclass(frozen=True)
class Cancelled:
    """Ctrl-C discarded the partial line."""


Event = Line | TooLong | Cancelled


class LineDiscipline:
    """Bytes in, events out: ``output = ld.feed(data, handle)``.

    ``handle(event)`` is called for each event as it completes and returns the bytes to
    send in reply; it may change :attr:`secret` or :attr:`echo` for the following
    bytes. ``output`` is the echo and the replies in order. The echo is what an
    interactive terminal should see: the accepted characters, ``b"\\b \\b"`` per
    erased character and CRLF per line end; nothing when ``echo`` is False, and never
    the characters of a line while ``secret`` is True (PIN entry).
    """

    def __init__(self, max_line_bytes: int, *, echo: bool = True) -> None:
        if max_line_bytes < 1:
            raise ValueError(f"expected max_line_bytes >= 1, got {max_line_bytes}")
        self.max_line_bytes = max_line_bytes
        self.echo = echo
        self.secret = False
        self._buf = bytearray()
        self._overflow = 0
        self._after_cr = False
        self._esc = ""  # "", "esc", "nf" (intermediates), "csi", "ss3", "str", "str-esc"

    def reset(self) -> None:
        """Forget the partial line and any escape sequence (a new connection)."""
        self._buf.clear()
        self._overflow = 0
        self._after_cr = False
        self._end_escape()
        self.secret = False

    @property
    def partial(self) -> bytes:
        """The partial line as the terminal shows it (b"" while ``secret`` or echo is off),
        to redraw it after an unsolicited notice."""
        return bytes(self._buf) if self.echo and not self.secret else b""

    @property
    def pending(self) -> int:
        """Bytes of the partial line received so far."""
        return len(self._buf) + self._overflow

    def _end_escape(self) -> None:
        self._esc = ""

    def _in_escape(self, b: int) -> bool:
        """Consume ``b`` as part of an escape sequence; False when it is not one (then
        ``b`` is handled as an ordinary byte)."""
        state = self._esc
        if b in (CAN, SUB) and state:
            self._esc = ""
            return True
        if not state:
            if b == ESC:
                self._esc = "esc"
            elif b == C1_CSI:
                self._esc = "csi"
            elif b in C1_STRING:
                self._esc = "str"
            else:
                return False
            return True
        if state == "esc":
            if b in STRING_INTRODUCERS:
                self._esc = "str"
            elif b == ord("["):
                self._esc = "csi"
            elif b == ord("O"):
                self._esc = "ss3"
            elif 0x20 <= b <= 0x2F:
                self._esc = "nf"
            elif b == ESC:
                self._esc = "esc"
            elif b < 0x20:
                self._esc = ""
                return False  # a control byte aborts the sequence and acts as itself
            else:
                self._esc = ""  # ESC x: two bytes
            return True
        if state in ("csi", "nf"):
            params = range(0x20, 0x40) if state == "csi" else range(0x20, 0x30)
            if b in params:
                return True
            self._esc = ""
            return 0x40 <= b <= 0x7E if state == "csi" else 0x30 <= b <= 0x7E
        if state == "ss3":
            self._esc = ""
            return 0x20 <= b <= 0x7E
        # string sequences: everything up to BEL or ST (ESC \ or 0x9C) is payload
        if b in (BEL, C1_ST):
            self._esc = ""
        elif state == "str-esc":
            self._esc = "" if b == ord("\\") else "str"
        elif b == ESC:
            self._esc = "str-esc"
        return True

    def feed(self, data: bytes, handle: Callable[[Event], bytes]) -> bytes:
        """Process ``data``, calling ``handle`` per event; returns echo and replies."""
        echo = bytearray()
        show = self.echo and not self.secret
        for b in data:
            if b in (CR, LF):
                self._end_escape()
                if b == LF and self._after_cr:
                    self._after_cr = False
                    continue
                self._after_cr = b == CR
                if self.echo:
                    echo += b"\r\n"
                event: Event = (TooLong(len(self._buf) + self._overflow) if self._overflow
                                else Line(self._buf.decode("ascii")))
                self._buf.clear()
                self._overflow = 0
                echo += handle(event)
                show = self.echo and not self.secret
                continue
            self._after_cr = False
            if self._in_escape(b):
                continue
            if b == TAB:
                b = 0x20
            if 0x20 <= b <= 0x7E:
                if self._overflow or len(self._buf) >= self.max_line_bytes:
                    self._overflow += 1
                    continue
                self._buf.append(b)
                if show:
                    echo.append(b)
            elif b in (BS, DEL):
                if self._buf and not self._overflow:
                    self._buf.pop()
                    if show:
                        echo += ERASE
            elif b == CTRL_U:
                if show:
                    echo += ERASE * len(self._buf)
                self._buf.clear()
            elif b == CTRL_C:
                if self.echo:
                    echo += b"^C\r\n"
                self._buf.clear()
                self._overflow = 0
                echo += handle(Cancelled())
                show = self.echo and not self.secret
            # every other byte (NUL, other C0 controls, 0x80..0xFF) is dropped
        return bytes(echo)
