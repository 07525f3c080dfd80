"""The systemd units: `systemd-analyze verify` says nothing, security exposure <= 2.5."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

UNITS = Path(__file__).resolve().parent.parent / "systemd"
ANALYZE = shutil.which("systemd-analyze")
pytestmark = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed "
                                "(tests/run.sh installs Debian's systemd package)")


def _installed_copy(tmp_path: Path) -> Path:
    """The unit as installed here: ExecStart points at this project's interpreter."""
    text = (UNITS / "railgw.service").read_text()
    assert "ExecStart=/opt/railgw/venv/bin/python " in text
    unit = tmp_path / "railgw.service"
    unit.write_text(text.replace("/opt/railgw/venv/bin/python", sys.executable))
    return unit


def test_unit_verifies_without_any_output(tmp_path):
    unit = _installed_copy(tmp_path)
    proc = subprocess.run([ANALYZE, "verify", "--man=no", str(unit)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout == "" and proc.stderr == "", proc.stderr


def test_security_exposure_at_most_2_5(tmp_path):
    unit = _installed_copy(tmp_path)
    proc = subprocess.run([ANALYZE, "security", "--offline=yes", "--threshold=25",
                           "--no-pager", str(unit)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr
    level = float(proc.stdout.split("Overall exposure level for railgw.service:")[1].split()[0])
    assert level <= 2.5


def test_unit_promises():
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read_string((UNITS / "railgw.service").read_text())
    svc = unit["Service"]
    assert svc["Type"] == "notify" and svc["Restart"] == "on-failure"
    assert svc["DynamicUser"] == "yes" and svc["StateDirectory"] == "railgw"
    assert svc["ProtectSystem"] == "strict"
    assert svc["RestrictAddressFamilies"] == "AF_UNIX AF_CAN"
    assert "WatchdogSec" in svc and "DeviceAllow" in svc


def test_network_files_parse():
    for name, section, key in [("80-can0.network", "CAN", "BitRate"),
                               ("80-vcan0.netdev", "NetDev", "Kind"),
                               ("80-vcan0.network", "Match", "Name")]:
        cp = configparser.ConfigParser()
        cp.optionxform = str  # type: ignore[assignment,method-assign]
        cp.read_string((UNITS / name).read_text())
        assert key in cp[section], name
    can0 = configparser.ConfigParser()
    can0.optionxform = str  # type: ignore[assignment,method-assign]
    can0.read_string((UNITS / "80-can0.network").read_text())
    assert can0["CAN"]["BitRate"] == "1M" and "RestartSec" in can0["CAN"]


def _syscalls(group: str) -> set[str]:
    """The syscalls of one SystemCallFilter item (a @group, expanded by systemd, or a name)."""
    if not group.startswith("@"):
        return {group}
    out = subprocess.run([ANALYZE, "syscall-filter", "--no-pager", group], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    names: set[str] = set()
    for line in out.splitlines()[1:]:
        word = line.strip()
        if word and not word.startswith("#"):
            names |= _syscalls(word)
    return names


def test_the_seccomp_filter_lets_the_worker_lower_its_priority_and_nothing_more():
    """systemd's rule: the first SystemCallFilter= line is an allow list; later ``~`` lines
    remove from it and plain lines add back, in order. os.nice is getpriority +
    setpriority on x86-64 (nice(2) elsewhere); no other @resources call is allowed."""
    lines = [line.split("=", 1)[1].split() for line in
             (UNITS / "railgw.service").read_text().splitlines()
             if line.startswith("SystemCallFilter=")]
    assert lines[0][0] != "~", "expected an allow list first"
    allowed: set[str] = set()
    for k, items in enumerate(lines):
        deny = items[0].startswith("~")
        names = set().union(*(_syscalls(i.lstrip("~")) for i in items))
        allowed = allowed - names if deny and k else allowed | names
    assert {"setpriority", "getpriority", "nice"} <= allowed
    assert not (_syscalls("@resources") - {"setpriority", "nice"}) & allowed
    assert not {"sched_setscheduler", "sched_setattr", "setrlimit"} & allowed
