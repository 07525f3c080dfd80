"""Compile, on the host, the numba kernels the vcan tests use, into the cache the VM shares.

Under qemu's TCG a numba compilation takes minutes; on the host seconds. The runner
(``run_vcan_suite.py``) calls this with ``NUMBA_CACHE_DIR=<cache>/numba`` and
``NUMBA_CPU_NAME=generic``, and the guest runs with the same two variables, so the
guest finds the compiled kernels (numba keys its cache on the CPU name and features;
``generic`` makes them equal on host and guest).

A vcan test that needs another jitted path adds a warm-up function to ``WARMUPS``:
something short that runs that path once. ``gateway_service`` also writes the gateway
test's recorded traffic, which a Python simulator under TCG could not produce in time.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

VCAN_TESTS = Path(__file__).resolve().parents[1] / "vcan"


def simulator() -> None:
    """firmware_sim's truth recursion (firmware_sim.truth._propagate)."""
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation

    for _ in Simulation(get_scenario("nominal"), SimConfig(duration_s=0.2, seed=0)).messages():
        pass


def gateway_service() -> None:
    """The gateway test's traffic log (into ``RAILGW_VCAN_DATA``, which the guest reads)
    and the estimator kernels its 64-particle worker runs (a replay of that log)."""
    sys.path.insert(0, str(VCAN_TESTS))
    import e2e_traffic

    data = os.environ.get("RAILGW_VCAN_DATA")
    e2e_traffic.warm(Path(data) if data else None)


def estimator_kernels() -> None:
    """Every estimator kernel, one per core (gateway.estimator.precompile), before the
    paths below load them."""
    from gateway.estimator.precompile import compile_parallel
    from gateway.estimator.threads import available_cores

    compile_parallel(available_cores())


WARMUPS: tuple[Callable[[], None], ...] = (estimator_kernels, simulator, gateway_service)


def main() -> int:
    for warm in WARMUPS:
        t0 = time.monotonic()
        warm()
        print(f"warmed {warm.__name__} in {time.monotonic() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
