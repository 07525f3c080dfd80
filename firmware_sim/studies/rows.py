"""One measurement row out: a study's JSON line, with the BLAS kernels that computed it.

A particle filter's Monte Carlo path moves with floating-point rounding, and OpenBLAS
(inside numpy and scipy) picks its kernels by CPU when it loads, unless
``OPENBLAS_CORETYPE`` names them. So the same study command on the same machine gives
other rows with and without ``OPENBLAS_CORETYPE=Haswell`` (measured 2026-11-29: seed
6040, 5 sensors, Csay x 0.1 from the start, Csy located at 4.392 s with the Haswell
kernels and at 4.433 s with this AMD host's own choice, SkylakeX; docs/estimator.md, "Two
runs of one study that did not agree"). Every row says which kernels computed it
(``blas``), so two rows that differ can be told apart from a defect.
"""

from __future__ import annotations

import functools
import json
from typing import Any

import numpy  # noqa: F401  (loads the BLAS whose kernels blas_kernels names)
from threadpoolctl import threadpool_info


@functools.cache
def blas_kernels() -> str:
    """Each BLAS library loaded (numpy's, and scipy's once a study has imported it) and
    the CPU kernels it chose, e.g. "openblas 0.3.31.188.0 Haswell; openblas 0.3.30
    Haswell"; "unknown" where threadpoolctl finds none. Cached at the first row: a
    study imports what it needs before it computes one."""
    libs = [" ".join(str(lib.get(k) or "?") for k in ("internal_api", "version",
                                                       "architecture"))
            for lib in threadpool_info() if lib.get("user_api") == "blas"]
    return "; ".join(libs) or "unknown"


def emit(row: dict[str, Any]) -> None:
    """Print ``row`` as one JSON line on stdout, flushed, with ``blas``
    (:func:`blas_kernels`) added."""
    print(json.dumps({**row, "blas": blas_kernels()}), flush=True)
