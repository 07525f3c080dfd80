"""Node phase rows: the clock cases against aligned, and two filter seeds against each
other, |difference| of the estimate in %, median / largest per parameter, per sensor set
(argv: JSONL files of `python -m firmware_sim.studies.timing ... --filter-seeds 2`)."""
import json
import statistics as st
import sys

for f in sys.argv[1:]:
    with open(f) as fh:
        rows = [r for r in (json.loads(line) for line in fh if line.strip()) if "case" in r]
    for n in sorted({r["sensors"] for r in rows}):
        rs = [r for r in rows if r["sensors"] == n]
        d = {(r["seed"], r["filter_seed"], r["case"]): r for r in rs}
        clock, seeds2 = [[], [], []], [[], [], []]
        for s in sorted({r["seed"] for r in rs}):
            fss = sorted({r["filter_seed"] for r in rs if r["seed"] == s})
            for fs in fss:
                a = d[(s, fs, "aligned")]
                for c in ("phase", "drift"):
                    b = d[(s, fs, c)]
                    for k in range(3):
                        clock[k].append(abs(100 * ((1 + b["rel"][k]) / (1 + a["rel"][k]) - 1)))
            for c in ("aligned", "phase", "drift"):
                a, b = d[(s, fss[0], c)], d[(s, fss[1], c)]
                for k in range(3):
                    seeds2[k].append(abs(100 * ((1 + b["rel"][k]) / (1 + a["rel"][k]) - 1)))
        sig = [st.median(r["sigma_rel"][k] * 100 for r in rs) for k in range(3)]
        print(f, f"{n} sensors, m = {rs[0]['particles']}:",
              "clock |diff| % median/max (Csy, Csay, lambda)",
              [f"{st.median(x):.2f}/{max(x):.2f}" for x in clock],
              "two filter seeds", [f"{st.median(x):.2f}/{max(x):.2f}" for x in seeds2],
              "median sigma %", [round(x, 2) for x in sig])
