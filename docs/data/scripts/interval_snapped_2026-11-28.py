r"""Run a module with the likelihood interval's ends at the next grid value outside (the
rule before 2026-11-28's sixth session), for paired runs on the same code otherwise:

    python docs/data/scripts/interval_snapped_2026-11-28.py \
        firmware_sim.studies.detection faults ...

It replaces ``gateway.estimator.faultbank._likely_edge`` by the old rule; on seeds
4401-4403 (20 m/s, 3-sensor Csy x 0.5) its rows equal the old code's to the last digit,
``wall_s`` aside. A measuring tool.
"""

import runpy
import sys

import gateway.estimator.faultbank as fb

fb._likely_edge = lambda values, llr, level, i, out: float(values[i + out])
sys.argv = [sys.argv[1]] + sys.argv[2:]
runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
