"""python -m gateway.estimator.precompile: every kernel, in worker processes, into the cache."""

from __future__ import annotations

import subprocess
import sys

from gateway.estimator import lanecode
from gateway.estimator.precompile import kernel_names


def test_every_generated_kernel_is_listed():
    names = kernel_names()
    assert set(names) == {"gateway.estimator.kalman.kf_step", "gateway.estimator.kalman.kf_block",
                          "gateway.estimator.batch_expm.phi_qd", "gateway.estimator.steady.sda",
                          "gateway.estimator.steady.kf_steady_block"}
    assert set(names) == set(lanecode.KERNELS)


def test_two_processes_fill_the_cache_and_report_each_kernel():
    """Here the cache is warm (the suite's kernels ran): each process loads its kernels."""
    proc = subprocess.run([sys.executable, "-m", "gateway.estimator.precompile", "--jobs", "2"],
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert {ln.split(":")[0] for ln in lines[:-1]} == set(kernel_names())
    assert "kernels ready in numba's cache" in lines[-1] and "2 process(es)" in lines[-1]


def test_jobs_below_one_is_a_one_line_error():
    proc = subprocess.run([sys.executable, "-m", "gateway.estimator.precompile", "--jobs", "0"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "expected --jobs >= 1, got 0" in proc.stderr
