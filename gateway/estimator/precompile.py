"""Compile the estimator's kernels into numba's on-disk cache, in parallel processes.

A fresh install, or a changed kernel, compiles every generated kernel
(:mod:`gateway.estimator.lanecode`) on its first use: about 2 minutes on one core, the
largest share in the steady-state DARE kernel. ``python -m gateway.estimator.precompile`` compiles
them once, one kernel per process, over the available cores; afterwards every
process (the worker, replay, the tests) loads them from the cache in about a second.
The kernels and their results are the same either way: this only fills the cache
sooner. CI runs it before the tests, the installed-wheel tests run it in their fresh
venv, and the vcan VM's host warm-up runs it too.
"""

from __future__ import annotations

import argparse
import importlib
import multiprocessing
import sys
import time

import numpy as np

from gateway.estimator.lanecode import KERNELS, compile_all
from gateway.estimator.threads import available_cores

MODULES = ("gateway.estimator.steady", "gateway.estimator.kalman",
           "gateway.estimator.batch_expm")
"""The modules that define kernels (importing them compiles nothing)."""


def kernel_names() -> list[str]:
    """Every kernel, in the order the modules define them (costliest module first)."""
    for module in MODULES:
        importlib.import_module(module)
    return list(KERNELS)


def load_functions() -> None:
    """Compile (or load) the estimator's plain numba functions, which compile lazily on
    their first call, by calling each once on small arrays of the types the filter
    passes (a numba function compiles once per argument types, not per size).

    Without this, a worker whose kernels were loaded said it was ready, and its first
    samples then waited for these functions: on a cold cache seconds, and 460 grid
    samples dropped at the demo's first start (2026-11-29). The test
    ``tests/test_precompile.py`` runs a faulted record after :func:`load_all` in a fresh
    process and fails if any numba function of the gateway compiles during it.
    """
    from gateway.estimator import monitor, particles, rbpf
    from gateway.estimator.lanecode import LANES
    from gateway.model.coordinates import NZ

    m, k = 4, 2
    logw, w = np.zeros(m), np.full(m, 1.0 / m)
    LL, NIS = np.zeros((k, LANES)), np.zeros((k, LANES))
    particles.absorb(logw, LL[0], NIS[0], w)
    particles.absorb_block(logw, LL, NIS, w, -1.0, False, np.zeros(k, dtype=np.int64),
                           1, 0.0, 0.0, 0, 0, monitor.initial_state())
    monitor.update_nb(1, 0.0, 0.0, 0, 0, monitor.initial_state(), 0.0, 0)
    for order in ("C", "F"):                 # a prior draw is column-major, a move's not
        rbpf._posterior(w, np.zeros((m, 3), order=order), np.zeros((1, NZ * LANES)))


def load_all() -> None:
    """Every kernel and every plain numba function of the estimator compiled or loaded
    in this process: what a worker does before it says it is ready."""
    compile_all()
    load_functions()


def compile_one(name: str) -> tuple[str, float]:
    """Compile (or load) kernel ``name`` in this process: (name, wall seconds)."""
    kernel_names()
    t0 = time.perf_counter()
    KERNELS[name].compile()
    return name, time.perf_counter() - t0


def compile_parallel(jobs: int) -> list[tuple[str, float]]:
    """Every kernel compiled into the cache by ``jobs`` fresh processes (1: here, in
    turn); (name, wall seconds) per kernel, in the order they finished."""
    names = kernel_names()
    if jobs <= 1:
        return [compile_one(n) for n in names]
    with multiprocessing.get_context("spawn").Pool(min(jobs, len(names))) as pool:
        return list(pool.imap_unordered(compile_one, names))


def main(argv: list[str] | None = None) -> int:
    cores = available_cores()
    p = argparse.ArgumentParser(prog="python -m gateway.estimator.precompile",
                                description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=cores,
                   help=f"processes compiling at once (default: the usable cores, {cores})")
    args = p.parse_args(argv)
    if args.jobs < 1:
        p.error(f"expected --jobs >= 1, got {args.jobs}")
    t0 = time.perf_counter()
    for name, dt in compile_parallel(args.jobs):
        print(f"{name}: {dt:.1f} s", flush=True)
    t1 = time.perf_counter()
    load_functions()
    print(f"plain numba functions: {time.perf_counter() - t1:.1f} s", flush=True)
    print(f"estimator kernels ready in numba's cache: {time.perf_counter() - t0:.1f} s "
          f"with {args.jobs} process(es)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
