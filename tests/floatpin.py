"""The environment that gives the test suite the same floats on every x86-64 host with AVX2.

Three libraries pick their code by CPU, and their rounding moves a particle filter's
Monte Carlo path (the golden files, single-record tests):

- OpenBLAS (in numpy and scipy) picks its kernels at load time: pinned to Haswell's;
- numba compiles for the host CPU: pinned to ``haswell`` with that CPU's own features
  (``NUMBA_CPU_FEATURES`` empty), so an AVX-512 host compiles what an AVX2 host does;
- numpy dispatches its loops by CPU: its AVX-512 loops off.

``tests/run.sh`` exports these before the kernel pre-compile, so the pre-compiled
kernels and every test share one numba cache key; ``tests/test_golden.py`` sets them
for its runs whatever the caller's environment. Measured on 2026-12-01: fixtures
recorded on AVX-512 hosts under the OpenBLAS pin alone differed by about 1e-10
(relative) in every float on an AMD EPYC host without AVX-512.

``python tests/floatpin.py`` prints the ``export`` lines for a shell (variables already
set are left as they are).
"""

from __future__ import annotations

import os
import shlex


def reproducible_floats() -> dict[str, str]:
    """Variable -> value: the pins above for this numpy's names of its CPU features."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:                                   # numpy < 2
        from numpy.core._multiarray_umath import __cpu_dispatch__
    avx512 = [f for f in __cpu_dispatch__ if f.startswith("AVX512") or f == "X86_V4"]
    return {"OPENBLAS_CORETYPE": "Haswell", "NUMBA_CPU_NAME": "haswell",
            "NUMBA_CPU_FEATURES": "", "NPY_DISABLE_CPU_FEATURES": " ".join(avx512)}


if __name__ == "__main__":
    for name, value in reproducible_floats().items():
        if name not in os.environ:
            print(f"export {name}={shlex.quote(value)}")
