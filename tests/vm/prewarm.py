"""Compile, on the host, the numba kernels the vcan tests use, into the cache the VM shares.

Under qemu's TCG a numba compilation takes minutes; on the host seconds. The runner
(``run_vcan_suite.py``) calls this with ``NUMBA_CACHE_DIR=<cache>/numba`` and
``NUMBA_CPU_NAME=generic``, and the guest runs with the same two variables, so the
guest finds the compiled kernels (numba keys its cache on the CPU name and features;
``generic`` makes them equal on host and guest).

A vcan test that needs another jitted path (the gateway service's estimator, say)
adds a warm-up function to ``WARMUPS``: something short that runs that path once.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable


def simulator() -> None:
    """firmware_sim's truth recursion (firmware_sim.truth._propagate)."""
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation

    for _ in Simulation(get_scenario("nominal"), SimConfig(duration_s=0.2, seed=0)).messages():
        pass


WARMUPS: tuple[Callable[[], None], ...] = (simulator,)


def main() -> int:
    for warm in WARMUPS:
        t0 = time.monotonic()
        warm()
        print(f"warmed {warm.__name__} in {time.monotonic() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
