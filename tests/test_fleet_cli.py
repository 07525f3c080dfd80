"""railgw fleet's seams: dask/pyarrow stay out of the vehicle's imports, the product never
imports the simulator, and bad input is a one-line error."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_run_and_fleet_parsers_import_no_dask_or_pyarrow() -> None:
    # the vehicle's command and the fleet command's parser (the full parser is not
    # checked: identify's SALib imports pandas, which imports pyarrow when installed)
    code = ("import sys, gateway.cli as c; c.build_parser(['run']); c.build_parser(['fleet']); "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('dask', 'distributed', 'pyarrow', 'duckdb')); print(bad); sys.exit(bool(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


def test_fleet_package_never_imports_the_simulator() -> None:
    files = [*sorted((ROOT / "gateway" / "fleet").glob("*.py")),
             ROOT / "gateway" / "commands" / "fleet.py"]
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n.split(".")[0] == "firmware_sim" for n in names), (f, names)


def test_ingest_of_a_missing_path_is_one_line(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "gateway", "fleet", "ingest",
                          str(tmp_path / "store"), str(tmp_path / "nope")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert out.stderr.strip().splitlines() == [
        f"error: expected a CAN log, a directory of logs or a gateway state directory, got "
        f"{str(tmp_path / 'nope')!r} (not found)"]


def test_ingest_needs_vehicle_and_bogie_for_a_loose_log(tmp_path: Path) -> None:
    log = tmp_path / "run.log"
    log.write_text("")
    out = subprocess.run([sys.executable, "-m", "gateway", "fleet", "ingest",
                          str(tmp_path / "store"), str(log)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert "expected" in out.stderr and "--vehicle and --bogie" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_fleet_demo_command_runs_the_whole_loop(tmp_path: Path) -> None:
    # the README's command, small: simulate (a subprocess) -> ingest -> replay on the
    # embedded LocalCluster -> report; the failed damper comes out on top
    pytest.importorskip("distributed")
    out = subprocess.run([sys.executable, "-m", "gateway", "fleet", "demo", "--out",
                          str(tmp_path / "demo"), "--vehicles", "2", "--days", "4",
                          "--run-seconds", "6", "--particles", "200", "--no-progress"],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    table = lines[next(i for i, s in enumerate(lines) if s.lstrip().startswith("# unit")) + 1:]
    assert [r.split()[1] for r in table] == ["V02/B1", "V01/B1"], out.stdout
    assert table[0].split()[2:4] == ["Csy", "crossed"] and table[0].endswith("csy-failing")
    assert "replayed 8 runs on 2 Dask workers" in out.stdout
    page = (tmp_path / "demo" / "report" / "report.html").read_text(encoding="utf-8")
    assert page.count("data:image/png;base64,") == 3
