"""The node-timing study with the resampler's fractional delay as before 2026-11-27.

With NOFILL=1 a hole anywhere in the 32-tap window makes the grid point fall back to
linear interpolation (the code before the bridge); otherwise today's code. Arguments as
``python -m firmware_sim.studies.timing``; rows in
docs/data/timing_lossy_bus_2026-11-27_seeds201-230.jsonl::

    NOFILL=1 python docs/data/scripts/timing_nofill_2026-11-27.py --seeds 201-230 \\
        --cases drift --sensors 5 --mode exact --bus-loss 0.01
"""

import os

import numpy as np

import gateway.frontend.resample as resample
from firmware_sim.studies.timing import main
from gateway.frontend import fracdelay


def _linear_fallback(self: resample.Resampler, message: str, k0: int, f: float
                     ) -> np.ndarray | None:
    tk = self._taps_k[message]
    ks = fracdelay.OFFSETS + k0
    slots = ks & (len(tk) - 1)
    if not (tk[slots] == ks).all():
        return None
    return fracdelay.taps(f) @ self._taps_v[message][slots]


if __name__ == "__main__":
    if os.environ.get("NOFILL") == "1":
        resample.Resampler._band_limited = _linear_fallback  # type: ignore[method-assign]
    raise SystemExit(main())
