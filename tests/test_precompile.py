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
    assert {ln.split(":")[0] for ln in lines[:-1]} == {*kernel_names(), "plain numba functions"}
    assert "kernels ready in numba's cache" in lines[-1] and "2 process(es)" in lines[-1]


def test_jobs_below_one_is_a_one_line_error():
    proc = subprocess.run([sys.executable, "-m", "gateway.estimator.precompile", "--jobs", "0"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "expected --jobs >= 1, got 0" in proc.stderr


_NOTHING_COMPILES_AFTER_WARMUP = """
import sys
from numba.core.registry import CPUDispatcher
from gateway.runtime.pipeline import warm_estimator

warm_estimator(1)


def signatures():
    return {f"{v.py_func.__module__}.{v.py_func.__qualname__}": len(v.signatures)
            for name, mod in list(sys.modules.items()) if name.startswith("gateway")
            for v in list(vars(mod).values()) if isinstance(v, CPUDispatcher)}


before = signatures()
from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.filtering import run, service_filter

th, Y = fault_data(0, 0.25, 3, 4902, 18.0, 8.0)
est, found, filt = run(Y, service_filter(3, 4902))
after = signatures()
print(len(before), len(found))
print(sorted(k for k in after if after[k] > before.get(k, 0)))
"""


def test_a_warmed_worker_compiles_nothing_on_its_first_samples():
    """The worker's warm-up (what runs before it says it is ready) leaves no numba function
    of the gateway to compile on the data path: in a fresh process, a record with a
    failed damper (the fault bank confirms and locates it) through the service's filter
    after the warm-up compiles nothing more. Before 2026-11-29 four plain functions
    compiled on the first samples, and the demo's first start dropped 460 samples."""
    proc = subprocess.run([sys.executable, "-c", _NOTHING_COMPILES_AFTER_WARMUP],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    counts, compiled = proc.stdout.splitlines()[-2:]
    n_dispatchers, n_found = map(int, counts.split())
    assert n_dispatchers >= 4 and n_found >= 1        # the functions exist; the bank located
    assert compiled == "[]"
