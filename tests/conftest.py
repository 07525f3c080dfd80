"""Shared fixtures: paths, the project's python, and small helpers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gateway.estimator.threads import configure, max_threads

configure(max_threads())   # numba's globals, once per process, as a worker process does

ROOT = Path(__file__).resolve().parent.parent


def run_cli(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ...`` with this interpreter; returns the completed process."""
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


@pytest.fixture()
def cli():
    return run_cli
