"""Console security, fail closed: salted PIN, persisted lockout, no PIN echo, escapes, audit.

Each test failed before its fix (issue 11 item 5, issue 12 finding 5). The lockout and
audit tests use a real :class:`gateway.service.daemon.Service` (its StateStore and view) on a
state directory; the audit failure is a full disk at ``os.fsync`` (ENOSPC), so the
store's own failure path runs.
"""

from __future__ import annotations

import errno
import hashlib
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fakes.example_view import ExampleView

from gateway.config import Config, load_config, with_overrides
from gateway.console.engine import Console
from gateway.console.lines import Line, LineDiscipline
from gateway.console.session import ConsoleLimits
from gateway.errors import ConfigError
from gateway.pin import hash_pin, parse_pin_hash, verify_pin
from gateway.service.daemon import Service

PIN = "482913"
PIN_HASH = hash_pin(PIN, n=2 ** 10)
ROOT = Path(__file__).resolve().parent.parent


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def say(console: Console, line: str) -> str:
    return console.feed(line.encode() + b"\r").decode()


def service_on(state: Path) -> Service:
    cfg = with_overrides(Config(), {"bus.interface": "virtual",
                                    "bus.channel": f"sec-{time.monotonic_ns()}",
                                    "state.directory": str(state),
                                    "serial.pin_hash": PIN_HASH})
    return Service(cfg)


@pytest.fixture()
def service(tmp_path: Path) -> Iterator[Service]:
    svc = service_on(tmp_path / "state")
    try:
        yield svc
    finally:
        svc.close()


# -- the PIN hash --------------------------------------------------------------------------
def test_pin_hash_is_salted_scrypt_and_verifies():
    a, b = hash_pin(PIN, n=2 ** 10), hash_pin(PIN, n=2 ** 10)
    assert a.startswith("scrypt$1024$8$1$") and a != b          # salted: never the same
    assert verify_pin(PIN, parse_pin_hash(a)) and not verify_pin("482914", parse_pin_hash(a))


@pytest.mark.parametrize("line", [
    f'pin_sha256 = "{hashlib.sha256(PIN.encode()).hexdigest()}"',
    f'pin_hash = "{hashlib.sha256(PIN.encode()).hexdigest()}"',
])
def test_an_old_unsalted_hash_is_a_config_error_naming_the_fix(tmp_path: Path, line: str):
    path = tmp_path / "railgw.toml"
    path.write_text(f'[serial]\ndevice = "/dev/ttyS1"\n{line}\n')
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert err.value.exit_code == 78
    message = str(err.value)
    assert message.startswith(f"{path}:3: [serial] pin_") and "railgw console hash-pin" in message
    assert "\n" not in message
    run = subprocess.run([sys.executable, "-m", "gateway", "run", "--config", str(path)],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.returncode == 78 and "hash-pin" in run.stderr and "Traceback" not in run.stderr


def test_hash_pin_command_reads_stdin_and_prints_a_usable_hash():
    run = subprocess.run([sys.executable, "-m", "gateway", "console", "hash-pin"],
                         input=f"{PIN}\n", capture_output=True, text=True, timeout=120,
                         cwd=ROOT)
    assert run.returncode == 0, run.stderr
    stored = run.stdout.strip()
    assert PIN not in run.stdout and verify_pin(PIN, parse_pin_hash(stored))
    cfg = with_overrides(Config(), {"serial.pin_hash": stored})
    assert cfg.serial.pin_hash == stored
    short = subprocess.run([sys.executable, "-m", "gateway", "console", "hash-pin"],
                           input="12\n", capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert short.returncode == 2 and "expected a PIN of 4 to 64 characters" in short.stderr


# -- lockout -------------------------------------------------------------------------------
def test_the_lockout_survives_a_service_restart(tmp_path: Path):
    state = tmp_path / "state"
    svc = service_on(state)
    console = Console(svc.view, pin_hash=PIN_HASH, clock=Clock())
    console.connect()
    for _ in range(5):
        say(console, "login")
        say(console, "000000")
    assert console.guard.locked_for_s() == pytest.approx(300.0)
    svc.close()
    assert (state / "console_lockout.json").is_file()
    again = service_on(state)                          # a restart: new process state
    try:
        console = Console(again.view, pin_hash=PIN_HASH, clock=Clock())
        console.connect()
        assert 290.0 < console.guard.locked_for_s() <= 300.0
        out = say(console, "login")
        assert "console locked after failed PINs" in out and "PIN: " not in out
    finally:
        again.close()


def test_failed_pins_before_a_restart_still_count(tmp_path: Path):
    state = tmp_path / "state"
    svc = service_on(state)
    console = Console(svc.view, pin_hash=PIN_HASH, clock=Clock())
    console.connect()
    for _ in range(4):
        say(console, "login")
        say(console, "000000")
    svc.close()
    again = service_on(state)
    try:
        console = Console(again.view, pin_hash=PIN_HASH, clock=Clock())
        console.connect()
        say(console, "login")
        assert "locked for 300 s" in say(console, "000000")    # the fifth, not the first
    finally:
        again.close()


# -- no PIN echo ---------------------------------------------------------------------------
@pytest.mark.parametrize("why", ["locked", "wrong PIN", "timed out"])
def test_a_pin_typed_after_a_refused_login_is_never_echoed_or_repeated(why: str):
    clock = Clock()
    view = ExampleView.example()
    console = Console(view, pin_hash=PIN_HASH, clock=clock,
                      limits=ConsoleLimits(pin_entry_timeout_s=60))
    console.connect()
    if why == "locked":
        for _ in range(5):
            say(console, "login")
            say(console, "000000")
        assert "locked" in say(console, "login")
    elif why == "wrong PIN":
        say(console, "login")
        assert "wrong PIN" in say(console, "111111")
    else:
        say(console, "login")
        clock.t += 61
        assert "PIN entry timed out" in console.poll().decode()
    out = say(console, PIN)                              # typed as if the prompt were there
    assert PIN not in out and "line discarded" in out
    assert "Running" in say(console, "status") or "Degraded" in say(console, "status")
    console.session.json = True
    console._sync()
    for _ in range(5):
        say(console, "login")
        say(console, "000000")
    say(console, "login")
    assert PIN not in say(console, PIN)


# -- escape sequences ----------------------------------------------------------------------
@pytest.mark.parametrize("data", [
    b"\x1b]0;status\x07help\r",                     # OSC, BEL-terminated (window title)
    b"\x1b]8;;http://x/y\x1b\\help\x1b]8;;\x1b\\\r",   # OSC 8 hyperlink, ST-terminated
    b"\x1bPq#0;2;0;0;0status\x1b\\help\r",          # DCS (sixel) with a payload
    b"\x9d0;status\x07help\r",                      # 8-bit OSC
    b"\x1b_Gstatus\x1b\\help\r",                    # APC
    b"\x1b(Bhelp\r",                                # designate G0: ESC ( B
    b"\x1b[38;5;196mhelp\x1b[0m\r",                 # SGR colours
])
def test_escape_sequences_are_stripped_with_their_payload(data: bytes):
    got: list[Any] = []
    LineDiscipline(256).feed(data, lambda e: got.append(e) or b"")
    assert got == [Line("help")]


def test_an_unterminated_string_sequence_ends_at_the_line_end():
    got: list[Any] = []
    LineDiscipline(256).feed(b"\x1b]2;status status\rhelp\r", lambda e: got.append(e) or b"")
    assert got == [Line(""), Line("help")]


# -- audit fails closed --------------------------------------------------------------------
def _full_disk(monkeypatch: pytest.MonkeyPatch) -> None:
    def fsync(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "fsync", fsync)


def test_an_unwritable_audit_log_refuses_login_and_every_write(service: Service,
                                                                monkeypatch: pytest.MonkeyPatch):
    console = Console(service.view, pin_hash=PIN_HASH, clock=Clock())
    console.connect()
    with monkeypatch.context() as m:
        _full_disk(m)
        say(console, "login fitter")
        out = say(console, PIN)
        assert "audit log cannot be written" in out and not console.session.logged_in
    say(console, "login fitter")
    assert "logged in as fitter" in say(console, PIN)
    before = service.policy.snapshot()
    failures = service.store.write_failures
    with monkeypatch.context() as m:
        _full_disk(m)
        for line in ("ack csy", "threshold set csy warning 50%", "baseline reset csy"):
            out = say(console, line)
            assert "refused: the audit log cannot be written" in out, (line, out)
    assert service.policy.snapshot() == before          # nothing was carried out
    assert service.store.write_failures >= failures + 3
    stop = threading.Event()

    def main_loop() -> None:                             # the service's write executor
        while not stop.wait(0.01):
            service.view.run_pending()
    loop = threading.Thread(target=main_loop, daemon=True)
    loop.start()
    try:                                                 # the disk is back: writes work
        out = say(console, "threshold set csy warning 50%")
        assert "threshold set: Csy lateral damper low-side WARNING at 50 % of nominal" in out
        assert service.policy.config.params["csy_ns_per_m"].low_rel[1] == 0.5
        # The console's reads come from a snapshot the main loop takes twice a second
        # (not running here); a write refreshes it at once, so the very next read is
        # current: the failed writes reach the fitter's status.
        out = say(console, "status")
        assert f"state dir  {service.store.write_failures} WRITE FAILURES since start" \
            in out, out
    finally:
        stop.set()
        loop.join(timeout=5)
