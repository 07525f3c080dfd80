"""Shared fixtures: paths, the project's python, and small helpers."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

import pytest

from gateway.estimator.threads import configure, max_threads

configure(max_threads())   # numba's globals, once per process, as a worker process does

ROOT = Path(__file__).resolve().parent.parent


def run_cli(*args: str, timeout: float = 300.0,
            env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ...`` with this interpreter; returns the completed process.

    ``env``: variables set on top of this process's environment.
    """
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env={**os.environ, **(env or {})})


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--serial-only", action="store_true",
                     help="run only the tests marked serial (tests/run.sh's second pass)")


HEAVY_FIRST = ("test_alert_replay.py", "smoke/test_installed_wheel.py", "test_rbpf_drift.py",
               "test_node_timing_estimate.py", "test_fault_injection.py", "test_service.py",
               "test_faultbank.py", "test_fleet_loop.py", "test_fuzz_inputs.py",
               "test_dead_sensor.py", "test_identify_canlog.py", "test_calibration.py")
"""Test files of minutes each (docs/ci.md, measured 2026-12-01), longest first: pytest-xdist
workers get them before the rest (``tests/run.sh`` passes ``--no-loadscope-reorder``,
which keeps this order instead of xdist's most-tests-first), so the short files fill the
end of the run instead of one long file running alone. Order only, never selection."""


def _heavy_first(items: list[pytest.Item]) -> None:
    """Reorder ``items`` in place: the files of :data:`HEAVY_FIRST` in its order, then the
    rest as collected; each file's own tests keep their order."""
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(
        item.nodeid.split("::", 1)[0].removeprefix("tests/"), len(rank)))   # stable


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests marked ``serial`` assert a wall-clock bound: under pytest-xdist's workers they
    are left to the serial pass (``--serial-only``), which runs nothing else. A worker's
    collection puts the long files first (:data:`HEAVY_FIRST`)."""
    serial_only = config.getoption("--serial-only")
    in_worker = hasattr(config, "workerinput")
    if in_worker:
        _heavy_first(items)
    if not serial_only and not in_worker:
        return
    keep: list[pytest.Item] = []
    dropped: list[pytest.Item] = []
    for item in items:
        is_serial = item.get_closest_marker("serial") is not None
        (keep if is_serial == serial_only else dropped).append(item)
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = keep


@pytest.fixture()
def cli():
    return run_cli
