"""A study's measurement row names the BLAS kernels that computed it
(:mod:`firmware_sim.studies.rows`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.studies.rows import blas_kernels, emit

HAS_AVX2 = Path("/proc/cpuinfo").exists() and " avx2" in Path("/proc/cpuinfo").read_text()


def test_a_row_is_one_json_line_with_the_kernels_this_process_loaded(
        capsys: pytest.CaptureFixture[str]) -> None:
    emit({"seed": 6040, "z": [0.5, -1.0, 2.0]})
    (line,) = capsys.readouterr().out.splitlines()
    assert json.loads(line) == {"seed": 6040, "z": [0.5, -1.0, 2.0], "blas": blas_kernels()}


@pytest.mark.skipif(not HAS_AVX2, reason="OPENBLAS_CORETYPE=Haswell needs an x86-64 CPU "
                                         "with AVX2")
def test_the_row_tells_pinned_kernels_from_the_cpus_own_choice() -> None:
    """The same code in two processes, one with ``OPENBLAS_CORETYPE=Haswell``: the first
    names Haswell, the second whatever OpenBLAS chose for this CPU (docs/estimator.md,
    "Two runs of one study that did not agree")."""
    code = "from firmware_sim.studies.rows import blas_kernels; print(blas_kernels())"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    pinned = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True, env={**env, "OPENBLAS_CORETYPE": "Haswell"})
    own = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env=env)
    for lib in pinned.stdout.strip().split("; "):
        assert lib.startswith("openblas ") and lib.split()[-1] == "Haswell", pinned.stdout
    for lib in own.stdout.strip().split("; "):
        assert lib.startswith("openblas ") and lib.split()[-1] != "?", own.stdout
