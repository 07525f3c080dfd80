"""numba's process-wide settings, made once where a process that runs the estimator starts.

Called by the worker process at its start (:mod:`gateway.runtime.worker`) and by the
offline commands (``estimate``, ``bench``) before their first filter step; nothing
changes numba's globals at import or per sample.

Threading layer: the kernels run ``prange`` over chunks. Numba's default layer here is
OpenMP, whose threads spin at the barrier; when another process competes for the two
cores, a 1000-particle step was measured at 12-14 ms with OpenMP against 1-2.7 ms with
numba's own ``workqueue`` layer, so :func:`configure` selects ``workqueue`` (unless the
layer was chosen explicitly). It only takes effect before the first parallel kernel
runs in the process. The workqueue layer must not be entered from two Python threads
at once: the estimator runs in one worker (process) at a time.
"""

from __future__ import annotations

import os
from typing import Any

import numba

from gateway.estimator.lanecode import LANES

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
    """Select the ``workqueue`` layer (if not chosen explicitly) and ``threads`` threads."""
    cfg: Any = numba.config
    if cfg.THREADING_LAYER == "default":
        cfg.THREADING_LAYER = "workqueue"
    numba.set_num_threads(max(1, min(threads, max_threads())))
