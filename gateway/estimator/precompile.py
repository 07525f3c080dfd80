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

from gateway.estimator.lanecode import KERNELS
from gateway.estimator.threads import available_cores

MODULES = ("gateway.estimator.steady", "gateway.estimator.kalman",
           "gateway.estimator.batch_expm")
"""The modules that define kernels (importing them compiles nothing)."""


def kernel_names() -> list[str]:
    """Every kernel, in the order the modules define them (costliest module first)."""
    for module in MODULES:
        importlib.import_module(module)
    return list(KERNELS)


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
    print(f"estimator kernels ready in numba's cache: {time.perf_counter() - t0:.1f} s "
          f"with {args.jobs} process(es)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
