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


@pytest.fixture()
def cli():
    return run_cli
