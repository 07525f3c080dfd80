"""Fuzzing the edges (issue 12, "Validation at the edge"): generated TOML configs,
interchange CSVs, candump logs and console lines. Each input gets one line of error or a
success, never a traceback; sizes are bounded so memory is too (peak RSS checked).

Derandomized hypothesis (the same inputs in every CI run), no deadline. At the end the
count is printed in the terminal summary: ``fuzz: N inputs, 0 tracebacks``.
"""

from __future__ import annotations

import io
import math
import resource
import string
import tempfile
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout, suppress
from pathlib import Path

import pytest
from fakes.example_view import ExampleView
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.cli import main
from gateway.config import DOMAINS, load_config
from gateway.console.engine import Console
from gateway.console.session import ConsoleLimits
from gateway.errors import GatewayError
from gateway.offline.grid import to_grid
from gateway.offline.interchange import OPTIONAL, REQUIRED, read_csv

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

COUNTS: dict[str, int] = {"toml": 0, "csv": 0, "candump": 0, "console": 0}
TRACEBACKS: list[str] = []
TARGET_INPUTS = 10_000
FUZZ = settings(derandomize=True, deadline=None, database=None, print_blob=False,
                suppress_health_check=list(HealthCheck))


def fuzz(examples: int) -> settings:
    return settings(FUZZ, max_examples=examples)


TMP = Path(tempfile.mkdtemp(prefix="railgw-fuzz-"))


@pytest.fixture(scope="module", autouse=True)
def fuzz_summary(request: pytest.FixtureRequest) -> Iterator[None]:
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    yield
    total = sum(COUNTS.values())
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
    line = (f"fuzz: {total} inputs, {len(TRACEBACKS)} tracebacks "
            f"({', '.join(f'{k} {v}' for k, v in COUNTS.items())}; peak RSS +{grown_mb:.0f} MB)")
    reporter = request.config.pluginmanager.get_plugin("terminalreporter")
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    if reporter is not None and capture is not None:
        with capture.global_and_fixture_disabled():
            reporter.write_line(line)
    else:
        print(line)


def one_line(text: str) -> bool:
    return len(text.strip().splitlines()) <= 1


def cli(argv: list[str]) -> tuple[int, str]:
    """In-process ``python -m gateway ...``: (exit status, stderr)."""
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as stop:
            code = int(stop.code or 0) if not isinstance(stop.code, str) else 2
        except Exception as exc:  # noqa: BLE001 - what the fuzzer is looking for
            TRACEBACKS.append(f"{argv}: {type(exc).__name__}: {exc}")
            raise
    return code, err.getvalue()


# ----------------------------------------------------------------------- TOML
NUMBERS = st.one_of(
    st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["inf", "-inf", "nan", "1e308", "-0.0", "0", "1", "500", "1e-320"]))
SECTION_KEYS = sorted(DOMAINS)


def _toml_value(draw: st.DrawFn) -> str:
    kind = draw(st.integers(0, 5))
    if kind == 0:
        n = draw(NUMBERS)
        return n if isinstance(n, str) else repr(n).replace("inf", "inf").replace("nan", "nan")
    if kind == 1:
        return '"' + draw(st.text(string.printable, max_size=20)).replace("\\", "\\\\") \
            .replace('"', '\\"').replace("\n", "\\n").replace("\r", "\\r") \
            .replace("\x0b", "\\u000b").replace("\x0c", "\\f") + '"'
    if kind == 2:
        return draw(st.sampled_from(["true", "false", "[]", "[1, 2]", "{}", "{ a = 1 }",
                                     "1979-05-27", '""', "'lit'"]))
    if kind == 3:
        return draw(st.sampled_from(["socketcan", "virtual", "can0", "/var/lib/railgw"])) \
            .join('""')
    return draw(st.text(string.printable, max_size=12))


@st.composite
def toml_documents(draw: st.DrawFn) -> bytes:
    lines: list[str] = []
    for _ in range(draw(st.integers(0, 8))):
        section, key = draw(st.sampled_from(SECTION_KEYS))
        style = draw(st.integers(0, 5))
        value = _toml_value(draw)
        if style == 0:
            lines += [f"[{section}]", f"{key} = {value}"]
        elif style == 1:
            lines += [f'["{section}"]', f'"{key}" = {value}']
        elif style == 2:
            lines.append(f"{section}.{key} = {value}")
        elif style == 3:
            lines.append(f"{section} = {{ {key} = {value} }}")
        elif style == 4:
            lines += [f"[{section}.{key}]", f"x = {value}"]
        else:
            lines.append(draw(st.text(max_size=30)))
    text = "\n".join(lines) + "\n"
    raw = text.encode("utf-8", "surrogatepass")
    if draw(st.booleans()) and raw:
        at = draw(st.integers(0, len(raw) - 1))
        raw = raw[:at] + draw(st.binary(min_size=1, max_size=4)) + raw[at:]
    return raw


@fuzz(3000)
@given(toml_documents())
def test_fuzz_toml_config(doc: bytes) -> None:
    COUNTS["toml"] += 1
    path = TMP / "fuzz.toml"
    path.write_bytes(doc)
    try:
        load_config(path)
    except GatewayError as err:
        assert err.exit_code == 78 and one_line(str(err)) and str(err).startswith(str(path))
    except Exception as exc:
        TRACEBACKS.append(f"toml {doc!r}: {type(exc).__name__}: {exc}")
        raise


@fuzz(150)
@given(toml_documents())
def test_fuzz_toml_config_through_the_command_line(doc: bytes) -> None:
    COUNTS["toml"] += 1
    path = TMP / "cli.toml"
    path.write_bytes(doc)
    code, err = cli(["replay", str(TMP / "missing.log"), "--config", str(path), "--report",
                     str(TMP / "r.json"), "--no-progress"])
    assert code in (2, 78) and one_line(err) and err.startswith("error: "), err


# ------------------------------------------------------------------------ CSV
CELLS = st.one_of(
    st.floats(-2e3, 2e3, allow_nan=False), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["", "nan", "inf", "1e300", "-1e300", "x", " 1 ", "1e-320", "0x10"]),
    st.text(string.printable.replace("\n", "").replace("\r", ""), max_size=6))


@st.composite
def csv_documents(draw: st.DrawFn) -> bytes:
    columns = list(REQUIRED) + [c for c in OPTIONAL if draw(st.booleans())]
    if draw(st.integers(0, 9)) == 0:
        columns = draw(st.permutations(columns))[: draw(st.integers(1, len(columns)))]
    n = draw(st.integers(0, 40))
    step = draw(st.sampled_from([1e-3, 1e-3, 5e-3, 1e-6, 10.0, 1e8]))
    t = draw(st.floats(-1e3, 1e3, allow_nan=False))
    rows = [",".join(columns)]
    for _ in range(n):
        jump = draw(st.sampled_from([1.0, 1.0, 1.0, 1.0, 0.0, -1.0, 1e4, 1e9]))
        t += step * jump
        cells = []
        for c in columns:
            if c == "time_s":
                cells.append(repr(t) if draw(st.integers(0, 19)) else str(draw(CELLS)))
            elif c == "speed_mps":
                cells.append(str(draw(st.one_of(st.floats(0, 80), CELLS))))
            else:
                cells.append(str(draw(CELLS)))
        if draw(st.integers(0, 29)) == 0:
            cells = cells[: draw(st.integers(0, len(cells)))]
        rows.append(",".join(cells))
    raw = ("\n".join(rows) + "\n").encode()
    if draw(st.integers(0, 19)) == 0:
        raw += draw(st.binary(max_size=8))
    return raw


@fuzz(2500)
@given(csv_documents(), st.sampled_from([("acc_b", "gyro_b", "acc_bd"),
                                         ("acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd")]))
def test_fuzz_interchange_csv(doc: bytes, sensors: tuple[str, ...]) -> None:
    COUNTS["csv"] += 1
    path = TMP / "fuzz.csv"
    path.write_bytes(doc)
    try:
        grid = to_grid(read_csv(path), sensors, 42.5)
        assert math.isfinite(grid.fs_hz) and len(grid.t_s) <= 10_000_000
    except GatewayError as err:
        assert err.exit_code == 2 and one_line(str(err)), err
    except Exception as exc:
        TRACEBACKS.append(f"csv {doc!r}: {type(exc).__name__}: {exc}")
        raise


@fuzz(120)
@given(csv_documents())
def test_fuzz_interchange_csv_through_estimate(doc: bytes) -> None:
    COUNTS["csv"] += 1
    path = TMP / "est.csv"
    path.write_bytes(doc)
    code, err = cli(["estimate", str(path), "--report", str(TMP / "est.json"),
                     "--particles", "2", "--history-every-s", "1"])
    assert (code == 0 and err == "") or (code == 2 and one_line(err)
                                         and err.startswith("error: ")), err


# -------------------------------------------------------------------- candump
@pytest.fixture(scope="module")
def nominal_log() -> list[str]:
    from firmware_sim.cli import main as sim_main

    path = TMP / "nominal.log"
    with redirect_stdout(io.StringIO()):
        assert sim_main(["run", "--duration", "0.15", "--out", str(path)]) == 0
    BASE_LOG[:] = path.read_text().splitlines()
    return BASE_LOG


BASE_LOG: list[str] = []
"""The nominal simulator log every candump input starts from (set by the fixture)."""
FRAME_IDS = ["101", "102", "103", "104", "105", "110", "7FF", "1FFFFFFF", "0", "ZZ"]


@st.composite
def candump_documents(draw: st.DrawFn) -> str:
    lines = list(BASE_LOG)
    for _ in range(draw(st.integers(0, 12))):
        at = draw(st.integers(0, len(lines)))
        kind = draw(st.integers(0, 5))
        if kind == 0:                                  # a random frame on a known id
            data = draw(st.binary(max_size=9)).hex().upper()
            t = draw(st.one_of(st.floats(-1.0, 1000.0),
                               st.sampled_from([math.nan, math.inf, -math.inf])))
            lines.insert(at, f"({t:f}) vcan0 {draw(st.sampled_from(FRAME_IDS))}#{data}")
        elif kind == 1 and lines:                      # timestamp step / glitch
            shift = draw(st.sampled_from([-0.5, -100.0, 0.5, 10.0, 100.0, 500.0, -5e3,
                                          1e9, -1e9, 1e300, -1e300]))
            for k in range(at, min(len(lines), at + draw(st.integers(1, 50)))):
                head, _, tail = lines[k].partition(")")
                with suppress(ValueError):
                    lines[k] = f"({float(head[1:]) + shift:f}){tail}"
        elif kind == 2 and lines:                      # bytes flipped in a line
            line = lines[at % len(lines)]
            pos = draw(st.integers(0, max(0, len(line) - 1)))
            lines[at % len(lines)] = line[:pos] + draw(st.sampled_from("0F#()x. ")) \
                + line[pos + 1:]
        elif kind == 3 and lines:                      # dropped run of frames
            del lines[at:at + draw(st.integers(1, 100))]
        elif kind == 4 and lines:                      # duplicated run (replay attack)
            lines[at:at] = lines[at:at + draw(st.integers(1, 30))]
        else:
            lines.insert(at, draw(st.text(max_size=40)).replace("\n", " "))
    return "\n".join(lines) + "\n"


def test_fuzz_candump_logs(nominal_log: list[str]) -> None:
    from gateway.identify.canlog import read_can_log

    @fuzz(400)
    @given(candump_documents())
    def one(doc: str) -> None:
        COUNTS["candump"] += 1
        path = TMP / "fuzz.log"
        path.write_text(doc, encoding="utf-8", errors="surrogateescape")
        try:
            rec = read_can_log(path)
            assert len(rec.t_s) < 10_000_000
        except GatewayError as err:
            assert err.exit_code == 2 and one_line(str(err)), err
        except Exception as exc:
            TRACEBACKS.append(f"candump: {type(exc).__name__}: {exc}")
            raise

    one()


# -------------------------------------------------------------------- console
PIN = "2468"


@pytest.fixture(scope="module")
def console() -> Console:
    from gateway.pin import hash_pin

    clock = iter(range(10**9))
    c = Console(ExampleView.example(), pin_hash=hash_pin(PIN),
                limits=ConsoleLimits(), clock=lambda: float(next(clock)), wall=lambda: 1.7e9)
    c.connect()
    return c


WORDS = ["help", "status", "estimates", "alerts", "history", "sensors", "bus", "config",
         "version", "log", "login", "logout", "mode", "echo", "ack", "baseline", "threshold",
         "json", "text", "on", "off", "reset", "set", "csy", "csay", "lambda", "alarm",
         "warning", "1", "-1", "1e-320", "100", "nan", "inf", "24h", "1e308h", PIN, "9999"]
CONTROL = ["\x1b[31m", "\x1b]0;title\x07", "\x1bP+q\x1b\\", "\x03", "\x04", "\x7f", "\x08",
           "\x00", "\t", "\x1b", "\r", "\n", "\x15", "\x17"]


@st.composite
def console_lines(draw: st.DrawFn) -> bytes:
    parts = draw(st.lists(st.one_of(st.sampled_from(WORDS), st.sampled_from(CONTROL),
                                    st.text(max_size=10)), max_size=8))
    raw = " ".join(parts).encode("utf-8", "surrogatepass")
    if draw(st.integers(0, 9)) == 0:
        raw += draw(st.binary(max_size=16))
    if draw(st.integers(0, 49)) == 0:
        raw *= 300                                      # an over-long line
    return raw + b"\r"


@fuzz(4000)
@given(console_lines())
def test_fuzz_console_lines(console: Console, line: bytes) -> None:
    COUNTS["console"] += 1
    before = console.internal_errors
    try:
        out = console.feed(line)
    except Exception as exc:
        TRACEBACKS.append(f"console {line!r}: {type(exc).__name__}: {exc}")
        raise
    assert isinstance(out, bytes) and len(out) < 1 << 20
    assert console.internal_errors == before, line


def test_fuzz_total_and_no_tracebacks() -> None:
    """Runs last in this module: the CI tier's count and its zero."""
    assert TRACEBACKS == []
    if all(COUNTS.values()):                    # the whole module ran (not a -k subset)
        assert sum(COUNTS.values()) >= TARGET_INPUTS, COUNTS
