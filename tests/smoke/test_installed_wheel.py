"""The installed wheel is the product: every user-facing path, run from a fresh venv.

The wheel is built and installed once per session (``conftest.installed``); each test
runs the venv's own ``railgw`` / ``railgw-sim`` / ``python`` from a directory outside
the source tree. Deselect with ``-m 'not smoke'``. The first test that reaches the
filter kernels compiles them in the fresh venv (1-2 min, once per session).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import select
import signal
import subprocess
import sys
import time
import tty
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from smokeenv import ROOT, Installed

pytestmark = [pytest.mark.smoke, pytest.mark.slow]

EDITABLE = ROOT / ".venv" / "bin" / "python"
PIN = "4711"
PROMPT_AT_END = re.compile(rb"(railgw[>#] |PIN: )$")
PROMPT = re.compile(rb"(railgw[>#] |PIN: )")
LABELS = {"csy_ns_per_m": "Csy lateral damper", "csay_ns_per_m": "Csay anti-yaw damper",
          "conicity": "lambda wheelset"}
COMPONENT = {"csy_ns_per_m": "lateral-damper", "csay_ns_per_m": "anti-yaw-damper",
             "conicity": "conicity"}


def _ok(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr}"
    return proc.stdout


def _wait_for(cond: Callable[[], Any], timeout_s: float, what: str,
              proc: subprocess.Popen[bytes] | None = None) -> Any:
    """Poll ``cond`` until true (returned) or the deadline; fails at once if ``proc`` ends."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the service exited ({proc.returncode}) while waiting for "
                                 f"{what}")
        got = cond()
        if got:
            return got
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def test_version_and_help_of_the_entry_points(installed: Installed):
    import importlib.metadata
    version = importlib.metadata.version("railgw")
    out = _ok(installed.run([installed.exe("railgw"), "--version"]))
    assert out.split()[-1] == version
    assert "run" in _ok(installed.run([installed.exe("railgw"), "--help"]))
    assert "simulate a scenario" in _ok(installed.run([installed.exe("railgw-sim"), "--help"]))


def test_python_m_gateway_run_help(installed: Installed):
    """The reported failure: ``ModuleNotFoundError: No module named 'gateway.commands'``."""
    out = _ok(installed.run([installed.python, "-m", "gateway", "run", "--help"]))
    assert "--config" in out and "--state-dir" in out


IMPORT_ALL = """
import importlib, importlib.metadata as md, json, pkgutil, re, gateway, firmware_sim, dbc
optional = set()        # import names of the optional extras (not 'dev'): may be absent
for req in md.requires("railgw") or []:
    if "extra ==" in req and "dev" not in req.split("extra ==")[1]:
        m = re.match(r"([A-Za-z0-9_.-]+)(?:\\[([^\\]]*)\\])?", req)
        optional.add(m.group(1).lower().replace("-", "_"))
        optional.update(x.strip().lower() for x in (m.group(2) or "").split(",") if x.strip())
names = [m.name for p in (gateway, firmware_sim, dbc)
         for m in pkgutil.walk_packages(p.__path__, p.__name__ + ".")
         if not m.name.endswith(".__main__")]
needs_extra = []
for n in names:
    try:
        importlib.import_module(n)
    except ModuleNotFoundError as err:
        if (err.name or "").split(".")[0] not in optional:
            raise
        needs_extra.append(n)
print(json.dumps({"file": gateway.__file__, "n": len(names), "needs_extra": needs_extra,
                  "optional": sorted(optional)}))
"""


def test_every_installed_module_imports(installed: Installed):
    """Every module of the wheel imports in the plain (vehicle) install; only modules that
    need an optional extra (``fleet``) may fail, and only on that extra's packages."""
    # importing compiles no kernel (the install fixture ran precompile already; a kernel
    # compiles on its first call), but a slow host may still take longer than the default
    got = json.loads(_ok(installed.run([installed.python, "-c", IMPORT_ALL],
                                       timeout_s=1200)))
    assert Path(got["file"]).is_relative_to(installed.venv), got
    assert got["n"] >= 80
    assert not [n for n in got["needs_extra"] if "fleet" not in n.split(".")], got
    from importlib.resources import files
    dbc = installed.run([installed.python, "-c", "from importlib.resources import files; "
                         "print(files('dbc').joinpath('railgw.dbc').read_text())"])
    assert _ok(dbc) == files("dbc").joinpath("railgw.dbc").read_text() + "\n"


def test_pip_install_dot_then_run_help(installed: Installed, tmp_path):
    """``pip install .`` (pip's own build of a clean copy of the tree) -> ``run --help``."""
    src = tmp_path / "src"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0") if (ROOT / ".git").exists() \
        else None
    if files is None:
        pytest.skip("not a git checkout: the wheel test above covers the install")
    for name in filter(None, files):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes((ROOT / name).read_bytes())
    target = tmp_path / "target"
    proc = subprocess.run([str(installed.python), "-m", "pip", "install", "-q", "--no-deps",
                           "--target", str(target), "."], cwd=src, env=installed.env(),
                          capture_output=True, text=True, timeout=600)
    _ok(proc)
    env = installed.env(PYTHONPATH=str(target))
    out = _ok(installed.run([installed.python, "-c", "import gateway; print(gateway.__file__)"],
                            env=env))
    assert Path(out.strip()).is_relative_to(target)
    assert "--config" in _ok(installed.run([installed.python, "-m", "gateway", "run", "--help"],
                                           env=env))


def test_replay_is_byte_identical_to_the_editable_install(installed: Installed):
    work = installed.work
    _ok(installed.run([installed.exe("railgw-sim"), "run", "--scenario", "paper",
                       "--duration", "6", "--seed", "3", "--out", "run.log"]))
    _ok(installed.run([EDITABLE, "-m", "firmware_sim", "run", "--scenario", "paper",
                       "--duration", "6", "--seed", "3", "--out", "run-editable.log"],
                      env=dict(os.environ)))
    assert (work / "run.log").read_bytes() == (work / "run-editable.log").read_bytes()
    args = ["replay", "run.log", "--particles", "200", "--no-progress"]
    t0 = time.monotonic()
    _ok(installed.run([installed.exe("railgw"), *args, "--report", "wheel.json",
                       "--jsonl", "wheel.jsonl"], timeout_s=600))
    wheel_s = time.monotonic() - t0
    _ok(installed.run([EDITABLE, "-m", "gateway", *args, "--report", "editable.json",
                       "--jsonl", "editable.jsonl"], timeout_s=600, env=dict(os.environ)))
    wheel, editable = (work / "wheel.jsonl").read_bytes(), (work / "editable.jsonl").read_bytes()
    assert wheel == editable
    rows = [json.loads(line) for line in wheel.splitlines()]
    assert sum(r["type"] == "estimate" for r in rows) >= 50
    print(f"installed replay (incl. first numba compile): {wheel_s:.1f} s")


# -- the live service and its console over a real pty ------------------------------------
class Terminal:
    """The master side of a pty whose slave the service opens as its console port."""

    def __init__(self, link: Path) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        os.symlink(os.ttyname(self.slave), link)
        self.prompt = ""

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)

    def read_until(self, done: Callable[[bytes], bool], timeout_s: float) -> bytes:
        got = bytearray()
        end = time.monotonic() + timeout_s
        while not done(bytes(got)):
            left = end - time.monotonic()
            assert left > 0, f"no complete reply within {timeout_s} s; got {bytes(got)!r}"
            if select.select([self.master], [], [], left)[0]:
                with contextlib.suppress(BlockingIOError, OSError):
                    got += os.read(self.master, 65536)
        return bytes(got)

    def command(self, line: str, timeout_s: float = 10.0) -> str:
        """A text-mode command -> its reply without echo and prompt (``\\n`` line ends).

        The reply is what lies between the echo of ``line`` and the next prompt; alert
        notices (``** alert: ...`` and a redrawn prompt, docs/console.md) that arrive
        before the echo or after the reply are not part of it."""
        os.write(self.master, line.encode() + b"\r")
        echo = (line.encode() if line != PIN else b"") + b"\r\n"

        def reply(b: bytes) -> re.Match[bytes] | None:
            at = b.find(echo)
            return None if at < 0 else PROMPT.search(b, at + len(echo))

        raw = self.read_until(lambda b: reply(b) is not None, timeout_s)
        m = reply(raw)
        assert m is not None
        self.prompt = m.group(1).decode()
        body = raw[raw.find(echo) + len(echo):m.start()].decode()
        lines = [t for t in body.split("\r\n") if not t.startswith("** alert: ")]
        return "\n".join(lines).rstrip("\n")

    def mode_json(self) -> None:
        """``mode json`` from text mode: the echoed line, then the reply object."""
        os.write(self.master, b"mode json\r")
        raw = self.read_until(lambda b: b.endswith(b"}\r\n"), 10.0)
        assert json.loads(raw.split(b"\r\n")[-2]) == {"ok": True, "cmd": "mode",
                                                        "data": {"mode": "json"}}

    def mode_text(self) -> None:
        os.write(self.master, b"mode text\r")
        self.read_until(lambda b: bool(PROMPT_AT_END.search(b)), 10.0)

    def json_command(self, line: str, timeout_s: float = 10.0) -> dict[str, Any]:
        os.write(self.master, line.encode() + b"\r")
        raw = self.read_until(lambda b: b.endswith(b"}\r\n"), timeout_s)
        obj = json.loads(raw.split(b"\r\n")[-2].decode())   # after any text-mode leftovers
        assert isinstance(obj, dict), raw
        return obj


def _events(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def _raised(term: Terminal, after_seq: int = 0) -> dict[str, Any] | None:
    """An active alert not yet acknowledged and newer than ``after_seq``, from the JSON
    ``alerts`` reply (the console's read side is a snapshot the service refreshes twice a
    second, so an alert just cleared may still be listed for a moment: hence ``after_seq``)."""
    reply = term.json_command("alerts")
    assert reply["ok"], reply
    active = [a for a in reply["data"]["active"] if a["state"] == "RAISED"
              and a["seq"] > after_seq and a["parameter"] in COMPONENT]
    return active[0] if active else None


def test_live_service_frames_console_and_sigterm(installed: Installed):
    work = installed.work / "live"
    work.mkdir()
    term = Terminal(work / "ttyRAILGW0")
    hashed = subprocess.run([installed.exe("railgw"), "console", "hash-pin"], input=PIN + "\n",
                            cwd=work, env=installed.env(), capture_output=True, text=True,
                            timeout=60)
    pin_hash = _ok(hashed).strip()
    assert pin_hash.startswith("scrypt$") and PIN not in pin_hash
    (work / "railgw.toml").write_text(
        f'[serial]\ndevice = "{work / "ttyRAILGW0"}"\npin_hash = "{pin_hash}"\n')
    events = work / "events.jsonl"
    helper = work / "live_helper.py"
    helper.write_bytes((Path(__file__).parent / "live_helper.py").read_bytes())
    channel = f"smoke-{os.getpid()}"
    log = open(work / "service.log", "w")  # noqa: SIM115
    proc = subprocess.Popen(
        [str(installed.python), str(helper), str(events), channel, "paper", "120", "--",
         "run", "--config", str(work / "railgw.toml"), "--bus", f"virtual:{channel}",
         "--state-dir", str(work / "state"), "--particles", "200", "--sensors", "3"],
        cwd=work, env=installed.env(), stdout=log, stderr=subprocess.STDOUT)
    try:
        start = _wait_for(lambda: [e for e in _events(events) if e["event"] == "start"], 60,
                          "the helper to start", proc)[0]
        assert Path(start["gateway_file"]).is_relative_to(installed.venv)
        _wait_for(lambda: any(e["event"] == "notify" and "READY=1" in e["text"]
                              for e in _events(events)), 300, "READY=1 from the service", proc)

        def frames(name: str) -> list[dict[str, float]]:
            return [e["values"] for e in _events(events)
                    if e["event"] == "frame" and e["message"] == name]

        for name in ("GW_EstCsy", "GW_EstCsay", "GW_EstConicity", "GW_Health"):
            _wait_for(functools.partial(frames, name), 60, f"a {name} frame off the bus", proc)
        _wait_for(lambda: any(v["GW_Health_FramesRx"] > 0 for v in frames("GW_Health")), 30,
                  "a health frame counting received sensor frames", proc)
        assert not [e for e in _events(events) if e["event"] == "bad_frame"]

        # the console: text mode banner, then JSON mode
        term.read_until(lambda b: b.endswith(b"railgw> "), 30)
        term.mode_json()
        assert term.json_command("login smoke") == {"ok": True, "cmd": "login",
                                                    "data": {"pin_required": True}}
        assert term.json_command(PIN) == {"ok": True, "cmd": "login", "data": {"user": "smoke"}}
        alert = _wait_for(lambda: _raised(term), 90, "a raised alert (paper scenario)", proc)
        # by component: the alert may escalate (new seq) between the poll and the ack
        reply = term.json_command(f"ack {COMPONENT[alert['parameter']]}")
        assert reply["ok"] and reply["cmd"] == "ack", reply
        acked = reply["data"]["alert"]
        assert acked["parameter"] == alert["parameter"] and acked["state"] == "ACKNOWLEDGED"
        assert acked["seq"] > alert["seq"]
        reply = term.json_command(f"baseline reset {COMPONENT[alert['parameter']]}")
        assert reply["ok"] and reply["cmd"] == "baseline", reply
        cleared = reply["data"]["events"]
        assert cleared and {e["parameter"] for e in cleared} == {alert["parameter"]}
        last_seq = max(e["seq"] for e in cleared)
        reply = term.json_command("history 1")
        assert reply["ok"] and reply["data"]["hours"] == 1.0
        assert f"baseline reset {alert['parameter']}" in [r["event"] for r in
                                                          reply["data"]["rows"]]
        assert term.json_command("logout")["ok"]

        # text mode: the same write commands, with the replies docs/console.md shows
        term.mode_text()
        assert term.command("ack 1") == "error: refused: write commands need 'login' first"
        assert term.command("login smoke") == "" and term.prompt == "PIN: "
        assert "logged in as smoke" in term.command(PIN) and term.prompt == "railgw# "
        term.mode_json()
        alert = _wait_for(lambda: _raised(term, last_seq), 90, "a new alert after the reset",
                          proc)
        term.mode_text()
        assert "logged in as smoke" in term.command("status")
        label = LABELS[alert["parameter"]]
        text = term.command(f"ack {COMPONENT[alert['parameter']]}")
        assert re.fullmatch(rf"acknowledged: #\d+ {label} (ADVISORY|WARNING|ALARM)", text), text
        text = term.command(f"baseline reset {COMPONENT[alert['parameter']]}")
        assert re.fullmatch(rf"baseline reset: {label} re-learns from its prior; "
                            r"cleared alert #\d+", text), text
        text = term.command("history 1")
        assert text.startswith("history, last 1 h (")
        assert f"** baseline reset {alert['parameter']}" in text
        assert term.command("logout") == "logged out"

        # SIGTERM: a clean stop with status 0
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=15) == 0
        assert _events(events)[-1] == {"event": "exit", "code": 0}
        assert (work / "state" / "checkpoint.bin").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        log.close()
        term.close()
        if sys.exc_info()[0] is not None:
            print((work / "service.log").read_text()[-4000:])


def test_identify_on_a_small_synthetic_run(installed: Installed):
    work = installed.work / "identify"
    railgw = installed.exe("railgw")
    work.mkdir()
    _ok(installed.run([railgw, "identify", "synth", "--out", work / "syn", "--duration-s", "14",
                       "--perturb", "Kx=+20,Csay=-20", "--seed", "2"]))
    _ok(installed.run([railgw, "identify", "run", work / "syn" / "data.csv", "--track",
                       work / "syn" / "track.csv", "--track-offset-m", "500", "--section",
                       "2:12", "--params", "Kx,Csay", "--methods", "nm,ps", "--local-maxfev",
                       "120", "--workers", "1", "--truth", work / "syn" / "truth.json",
                       "--out", work / "rep"], timeout_s=600))
    doc = json.loads((work / "rep" / "report.json").read_text())
    errs = [abs(v["error_vs_truth"]) for v in doc["parameters"]["ps"].values()]
    assert max(errs) < 0.05, doc["parameters"]["ps"]
    assert (work / "rep" / "parameters.png").stat().st_size > 1000
