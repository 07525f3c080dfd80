"""Console line discipline and parser fuzzing: no exception escapes, every reply is bounded."""

from __future__ import annotations

import json

from fakes.example_view import ExampleView
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from gateway.console.engine import Console
from gateway.console.lines import Cancelled, Event, Line, LineDiscipline, TooLong
from gateway.console.session import ConsoleLimits
from gateway.pin import hash_pin


class Clock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def run(data: bytes | list[bytes], *, cap: int = 256, echo: bool = True
        ) -> tuple[list[Event], bytes]:
    ld = LineDiscipline(cap, echo=echo)
    events: list[Event] = []

    def handle(e: Event) -> bytes:
        events.append(e)
        return b""

    chunks = [data] if isinstance(data, bytes) else data
    out = b"".join(ld.feed(c, handle) for c in chunks)
    return events, out


def test_cr_lf_and_crlf_each_end_one_line():
    events, _ = run(b"status\rbus\nversion\r\nlog\n\rhelp\r")
    assert events == [Line("status"), Line("bus"), Line("version"), Line("log"), Line(""),
                      Line("help")]


def test_crlf_split_across_reads_is_one_line_end():
    events, _ = run([b"status\r", b"\nbus\r", b"\n"])
    assert events == [Line("status"), Line("bus")]


def test_backspace_and_del_edit_and_echo_erases():
    events, echo = run(b"statx\x08us\x7f\x7fus\r")
    assert events == [Line("status")]
    assert echo == b"statx\b \bus\b \b\b \bus\r\n"


def test_backspace_on_empty_line_does_nothing():
    events, echo = run(b"\x08\x7f\x08ok\r")
    assert events == [Line("ok")] and echo == b"ok\r\n"


def test_escape_sequences_and_stray_bytes_are_dropped():
    arrows = b"\x1b[A\x1b[B\x1b[1;5C\x1bOP\x1b[15~\x1bx"
    events, echo = run(b"\x00st" + arrows + b"a\xff\xc3\xa9tus\x07\x1b\r")
    assert events == [Line("status")]
    assert echo == b"status\r\n"


def test_unterminated_escape_does_not_swallow_the_line_end():
    events, _ = run(b"help\x1b[12;\rbus\r")
    assert events == [Line("help"), Line("bus")]


def test_a_long_csi_is_dropped_whole_up_to_its_final_byte():
    # ECMA-48: parameters 0x30..0x3F run until a final byte 0x40..0x7E ("b" here); no
    # parameter digit may leak into the command, however long the sequence
    events, _ = run(b"\x1b[" + b"1;" * 40 + b"bus\r")
    assert events == [Line("us")]


def test_tab_is_a_space_and_ctrl_u_erases_the_line():
    events, _ = run(b"junk\x15help\tlog\r")
    assert events == [Line("help log")]


def test_ctrl_c_cancels_the_partial_line():
    events, echo = run(b"baseline res\x03bus\r")
    assert events == [Cancelled(), Line("bus")]
    assert b"^C\r\n" in echo


def test_overlong_line_is_discarded_whole_and_reported():
    events, echo = run(b"x" * 300 + b"\rbus\r", cap=256)
    assert events == [TooLong(300), Line("bus")]
    assert echo.count(b"x") == 256


def test_no_echo_when_off_and_no_characters_while_secret():
    _, echo = run(b"status\r", echo=False)
    assert echo == b""
    ld = LineDiscipline(64)
    ld.secret = True
    got: list[Event] = []
    echo = ld.feed(b"1234\r", lambda e: got.append(e) or b"")
    assert got == [Line("1234")] and echo == b"\r\n"


def test_the_handler_can_switch_to_secret_between_lines_of_one_read():
    ld = LineDiscipline(64)

    def handle(e: Event) -> bytes:
        ld.secret = isinstance(e, Line) and e.text == "login"
        return b"|"

    echo = ld.feed(b"login\r2468\rbus\r", handle)
    assert echo == b"login\r\n|\r\n|bus\r\n|"


# -- fuzzing the whole parser (line discipline + session + commands) ----------------------
TOKENS = [b"\r", b"\n", b"\r\n", b"\x08", b"\x7f", b"\x03", b"\x15", b"\x1b[A", b"\x1b",
          b"\x00", b"\xff", b"help\r", b"help ack\r", b"estimates\r", b"alerts\r",
          b"history 9999d\r", b"history 2\r", b"log 200\r", b"config\r", b"sensors\r",
          b"login\r", b"login a\r1234\r", b"login\r2468\r", b"ack 3\r", b"ack wheels\r",
          b"baseline reset csy\r", b"threshold set csy warning 40%\r", b"mode json\r",
          b"echo off\r", b"?\r", b"x" * 300]
chunk = st.one_of(st.binary(max_size=300), st.sampled_from(TOKENS))
MAX_PROMPT_AND_NOTICE = 120


def fuzz_console(clock: Clock) -> tuple[Console, list[int]]:
    limits = ConsoleLimits(reply_max_bytes=600, max_line_bytes=128, rate_per_s=50, burst=50)
    console = Console(ExampleView.example(), pin_hash=hash_pin("2468"), limits=limits,
                      clock=clock, wall=lambda: 1.7e9, port_name="fuzz")
    sizes: list[int] = []
    inner = console._on_event

    def spy(event: Event) -> bytes:
        out = inner(event)
        sizes.append(len(out))
        return out

    console._on_event = spy  # type: ignore[method-assign]
    console.connect()
    return console, sizes


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(chunk, max_size=12), st.lists(st.floats(0, 700), max_size=12))
@example(chunks=[b" " * 42, b"\x15"], steps=[])      # Ctrl-U erases a line typed earlier
def test_arbitrary_bytes_never_raise_and_every_reply_is_bounded(chunks, steps):
    """Echo is at most 3 bytes per byte read, plus one erase of the line pending from
    earlier reads (Ctrl-U: at most ``max_line_bytes`` characters, 3 bytes each); replies
    are the commands' own, each capped."""
    clock = Clock()
    console, sizes = fuzz_console(clock)
    for i, data in enumerate(chunks):
        if i < len(steps):
            clock.t += steps[i]
        out = console.feed(data) + console.poll()
        pending = 3 * console.limits.max_line_bytes
        assert len(out) <= 3 * len(data) + pending + sum(sizes) + MAX_PROMPT_AND_NOTICE
    assert console.internal_errors == 0
    assert all(n <= console.limits.reply_max_bytes + MAX_PROMPT_AND_NOTICE for n in sizes)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(chunk, max_size=12))
def test_in_json_mode_every_reply_line_parses(chunks):
    clock = Clock()
    console, _ = fuzz_console(clock)
    assert console.feed(b"mode json\r").endswith(b"}\r\n")
    out = b"".join(console.feed(c) for c in [*chunks, b"\r"])
    for raw in out.split(b"\r\n"):
        if raw == b"text mode":  # 'mode text' (unlikely from noise) replies in text mode
            break
        if not raw:
            continue
        obj = json.loads(raw)
        assert isinstance(obj, dict) and isinstance(obj["ok"], bool)
        assert len(raw) + 2 <= console.limits.reply_max_bytes
    assert console.internal_errors == 0


def test_ctrl_u_erases_the_line_typed_in_earlier_reads() -> None:
    """Ctrl-U alone erases every character typed before it, one BS-space-BS each."""
    got: list[Event] = []

    def handle(event: Event) -> bytes:
        got.append(event)
        return b""

    lines = LineDiscipline(128)
    assert lines.feed(b"ack 3", handle) == b"ack 3"
    assert lines.feed(b"\x15", handle) == b"\b \b" * 5
    lines.feed(b"help\r", handle)
    assert got == [Line("help")]
