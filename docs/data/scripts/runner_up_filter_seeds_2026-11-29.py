"""One faulted record through the service's filter with several filter seeds, runner-up on and off.

The detection study ties the filter seed to the data seed; this keeps the data and
varies the filter's seed, which decides whether the watch's first confirmation names
the right parameter. One JSON line per (filter seed, runner_up): the bank's detections
(data time, parameter, value relative to nominal, confirmation time). Rows in
docs/data/runner_up_filter_seeds_2026-11-29_eighth.jsonl (S = this script)::

    python S 0 0.25 3 4902 18 8.0 4902 0 1 2 3
    python S 0 0.25 3 4902 18 8.025 4902 0 1 2 3

Arguments: parameter index, factor, sensors, data seed, seconds, step time (s), then
the filter seeds.
"""

import json
import sys

from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.filtering import FilterOptions, run, service_filter


def main(argv: list[str]) -> None:
    param, factor, sensors, data_seed = int(argv[0]), float(argv[1]), int(argv[2]), int(argv[3])
    seconds, at = float(argv[4]), float(argv[5])
    th, Y = fault_data(param, factor, sensors, data_seed, seconds, at)
    for seed in map(int, argv[6:]):
        for runner_up in (False, True):
            _, found, _ = run(Y, service_filter(sensors, seed, FilterOptions(runner_up=runner_up)))
            print(json.dumps({"parameter": param, "factor": factor, "sensors": sensors,
                              "data_seed": data_seed, "fault_at_s": at, "filter_seed": seed,
                              "runner_up": runner_up,
                              "detections": [[round(f[0] - at, 3), f[1], round(f[2], 3),
                                              round(f[3] - at, 3)] for f in found]}),
                  flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
