"""numba's process-wide settings, made once where a process that runs the estimator starts.

Called by the worker process at its start (:mod:`gateway.runtime.worker`) and by the
offline commands (``estimate``, ``bench``) before their first filter step; nothing
changes numba's globals at import or per sample.

Threading layer: the kernels run ``prange`` over chunks. :func:`configure` selects
numba's OpenMP layer (``omp``, falling back to ``workqueue`` where numba has no OpenMP)
with ``OMP_WAIT_POLICY=PASSIVE``: threads sleep at the barrier instead of spinning.
Neither is changed where ``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY``
chose the layer, and a set ``OMP_WAIT_POLICY`` is kept. Measured (2026-11-26, m = 1000,
3 sensors, 20 s, one process per row, 2 cores):

==========================  =============  =============  =============
layer                       exact (idle)   fast (idle)    fast, CPU hog on one core
==========================  =============  =============  =============
OpenMP, spinning (default)  2.8-3.8        9.5-15.7       5.3 (exact 1.65)
OpenMP, passive (chosen)    2.6-3.5        8.6-13.4       9.1 (exact 1.9-2.0)
workqueue (until then)      1.9-3.2        6.4-10.2       8.5 (exact 1.93)
one thread                  2.0            8.8            8.3 (exact 1.86)
==========================  =============  =============  =============

(whole-run RTF from a bare script, the spread over 1-9 processes per cell; the
``gateway bench`` figures are in docs/estimator.md, "Speed"). workqueue's
parallel speed-up was erratic on this machine: from none (exact 1.9-2.1 with two
threads, 2.0 with one) to about 1.6 x between identical processes.
Spinning OpenMP threads hold their core while they wait, so when another process takes
one core each launch waits for the thread that shares it (a per-sample step took
12-14 ms instead of 1-3 ms, measured 2026-11-23); a passive thread sleeps, its core
goes idle, and the scheduler runs the other thread's work there. Both settings only
take effect before the first parallel kernel runs in the process (they are read when
numba loads the layer, which :func:`configure` does). OpenMP is not fork-safe: a
process that has run a parallel kernel must not fork a child that runs one (the worker
is spawned, :mod:`gateway.runtime.worker`).
"""

from __future__ import annotations

import os
from typing import Any

import numba

from gateway.estimator.lanecode import LANES

LAYER_PRIORITY = ("omp", "workqueue", "tbb")
"""numba's threading layers in the order :func:`configure` tries them."""
MIN_PARALLEL_CHUNKS = 16
"""Below this many lane chunks (``LANES`` particles each) one thread is faster."""


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:       # not on Linux
        return os.cpu_count() or 1


def max_threads() -> int:
    """The number of threads numba may use in this process (all cores by default)."""
    return int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]


def threading_layer() -> str:
    """The active numba threading layer, or "unset" before the first parallel launch."""
    try:
        return str(numba.threading_layer())
    except ValueError:
        return "unset"


def kernel_threads(n_particles: int, wanted: int | None = None) -> int:
    """Threads for a filter of ``n_particles``: 1 below :data:`MIN_PARALLEL_CHUNKS`
    chunks, else ``wanted`` (None: all) capped at :func:`max_threads`."""
    if -(-n_particles // LANES) < MIN_PARALLEL_CHUNKS:
        return 1
    return max(1, min(wanted or max_threads(), max_threads()))


def configure(threads: int) -> None:
    """Select the OpenMP layer with passive waiting (each unless chosen explicitly, see the
    module's docstring) and ``threads`` threads."""
    cfg: Any = numba.config
    if cfg.THREADING_LAYER == "default" and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
        cfg.THREADING_LAYER_PRIORITY = list(LAYER_PRIORITY)
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    numba.set_num_threads(max(1, min(threads, max_threads())))
