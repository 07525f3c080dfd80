"""``gateway bench``: the estimator bench's fast-mode keys (the bare filter's and the
service's), the threads in effect, and the cost-curve sweep (``--what sweep``: JSON
records and the PNG). Tiny settings; no timing assertions (speed is measured by the
benchmark itself, on an idle machine)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pytest

from firmware_sim.studies.sweep import FS_HZ, bench_data, filter_config, service_filter_config
from gateway.cli import main
from gateway.config import EstimatorConfig
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.estimator.threads import kernel_threads, max_threads, threading_layer
from gateway.model.vehicle import AR_PAPER_DEFAULT
from gateway.runtime.pipeline import estimator_config

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SEED = 0
"""At this seed, m = 32 and a 10 ms warm-up, fast mode resamples 3 times in the 50 ms and
exact mode twice: the counts in the JSON tell which mode ran."""
TINY = ["--seconds", "0.05", "--naive-steps", "2", "--seed", str(SEED)]
OLD_KEYS = ("exact_rtf_whole_run", "exact_rtf_steady", "naive_rtf", "ratio_whole_run",
            "ratio_steady", "steady_gflops", "ceiling_rtf", "numba_threads",
            "available_cores")
NEW_KEYS = ("fast_rtf_whole_run", "fast_rtf_steady", "ratio_fast_naive_whole_run",
            "ratio_fast_naive_steady", "threads", "fast_rtf_whole_run_lossy",
            "fast_rtf_steady_lossy", "frame_loss")
RECORD_RTFS = ("fast_rtf_whole_run", "fast_rtf_steady", "exact_rtf_whole_run",
               "exact_rtf_steady", "naive_rtf")


@pytest.fixture(autouse=True)
def _keep_numba_threads() -> Iterator[None]:
    """The bench sets numba's thread count for the process; give it back afterwards."""
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def bench_json(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    assert main(["bench", "--json", *argv]) == 0
    out: dict[str, Any] = json.loads(capsys.readouterr().out)
    return out


def positive(value: Any) -> bool:
    return isinstance(value, float) and math.isfinite(value) and value > 0


def resamples(mode: str, particles: int, fast_warmup_s: float) -> int:
    """Resample-moves of a reference run of the bench's filter over the bench's data."""
    return _resamples(filter_config(mode, particles, SEED, AR_PAPER_DEFAULT, fast_warmup_s))


def _resamples(config: RBPFConfig) -> int:
    data = bench_data(0.05, SEED)
    filt = RBPF(config)
    filt.run(data.samples)
    return filt.n_resamples


def test_estimator_keeps_its_keys_and_adds_fast_mode(capsys):
    r = bench_json(["--what", "estimator", "--particles", "32", "--fast-warmup-s", "0.01",
                    *TINY], capsys)
    assert list(r) == ["estimator"]
    est = r["estimator"]
    for key in OLD_KEYS + NEW_KEYS:
        assert key in est, key
    for key in ("exact_rtf_whole_run", "exact_rtf_steady", "fast_rtf_whole_run",
                "fast_rtf_steady", "naive_rtf", "ratio_fast_naive_whole_run"):
        assert positive(est[key]), (key, est[key])
    assert est["ratio_fast_naive_whole_run"] == pytest.approx(
        est["fast_rtf_whole_run"] / est["naive_rtf"])
    assert est["fast_warmup_s"] == 0.01
    assert est["frame_loss"] == 1e-3 and positive(est["fast_rtf_steady_lossy"])
    assert est["threading_layer"] == threading_layer() != "unset"   # what the kernels ran on
    # the counts come from a filter in each mode over the same data with the same seed
    assert resamples("fast", 32, 0.01) != resamples("exact", 32, 0.01), "pick another SEED"
    assert (est["fast_resamples_convergence"] + est["fast_resamples_steady"]
            == resamples("fast", 32, 0.01))
    assert (est["resamples_convergence"] + est["resamples_steady"]
            == resamples("exact", 32, 0.01))


def test_estimator_times_the_services_filter_beside_the_bare_one(capsys):
    m = 32
    est = bench_json(["--what", "estimator", "--particles", str(m), "--fast-warmup-s", "0.01",
                      *TINY], capsys)["estimator"]
    for key in ("service_fast_rtf_whole_run", "service_fast_rtf_steady",
                "ratio_service_fast_naive_whole_run"):
        assert positive(est[key]), (key, est[key])
    assert est["ratio_service_fast_naive_whole_run"] == pytest.approx(
        est["service_fast_rtf_whole_run"] / est["naive_rtf"])
    service = service_filter_config(m, SEED, AR_PAPER_DEFAULT, 0.01)
    want = estimator_config(EstimatorConfig(particles=m), FS_HZ)
    assert (service.mode, service.delta, service.floor_rel, service.start_ramp_s,
            service.start_ramp_m, service.prior_lo, service.walk_rel_per_sqrt_s) == (
        want.mode, want.delta, want.floor_rel, want.start_ramp_s, want.start_ramp_m,
        want.prior_lo, want.walk_rel_per_sqrt_s)
    assert est["service_filter"] == {"kernel_delta": want.delta,
                                     "start_ramp_s": want.start_ramp_s,
                                     "start_ramp_m": want.start_ramp_m,
                                     "prior_lo": list(want.prior_lo)}
    # the counts say which filter ran: the service's, which differs from the bare one
    bare = resamples("fast", m, 0.01)
    assert _resamples(service) != bare, "pick another SEED"
    assert (est["service_fast_resamples_convergence"] + est["service_fast_resamples_steady"]
            == _resamples(service))


def test_threads_option_is_the_threads_measured_with(capsys):
    m = 128                                    # 16 chunks: the smallest parallel filter
    one = bench_json(["--what", "estimator", "--what", "sweep", "--particles", str(m),
                      "--threads", "1", "--sweep-particles", f"16,{m}", *TINY], capsys)
    assert one["estimator"]["threads"] == 1 and one["estimator"]["numba_threads"] == 1
    assert [rec["threads"] for rec in one["sweep"]] == [1, 1]
    assert positive(one["estimator"]["fast_rtf_whole_run"])
    every = bench_json(["--what", "estimator", "--what", "sweep", "--particles", str(m),
                        "--sweep-particles", f"16,{m}", *TINY], capsys)
    assert every["estimator"]["threads"] == kernel_threads(m) == max_threads()
    assert [rec["threads"] for rec in every["sweep"]] == [1, max_threads()]


def test_sweep_json_and_plot(tmp_path: Path, capsys):
    png = tmp_path / "cost.png"
    r = bench_json(["--what", "sweep", "--sweep-particles", "32,16,32", "--plot", str(png),
                    "--fast-warmup-s", "0.01", *TINY], capsys)
    assert list(r) == ["sweep"]
    assert [rec["particles"] for rec in r["sweep"]] == [16, 32]
    for rec in r["sweep"]:
        for key in RECORD_RTFS:
            assert positive(rec[key]), (rec["particles"], key, rec[key])
    assert r["sweep"][1]["fast_resamples"] == resamples("fast", 32, 0.01)
    assert r["sweep"][1]["exact_resamples"] == resamples("exact", 32, 0.01)
    data = png.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 10_000


def test_sweep_exact_max_skips_exact_mode_above_it(tmp_path: Path, capsys):
    png = tmp_path / "cost.png"
    r = bench_json(["--what", "sweep", "--sweep-particles", "16,32", "--sweep-exact-max", "16",
                    "--plot", str(png), *TINY], capsys)
    small, large = r["sweep"]
    assert positive(small["exact_rtf_whole_run"]) and positive(small["exact_rtf_steady"])
    assert large["exact_rtf_whole_run"] is None and large["exact_rtf_steady"] is None
    assert large["exact_resamples"] is None
    assert positive(large["fast_rtf_whole_run"]) and positive(large["naive_rtf"])
    assert png.read_bytes().startswith(PNG_MAGIC)


def test_sweep_text_table(capsys):
    assert main(["bench", "--what", "sweep", "--sweep-particles", "16",
                 "--sweep-exact-max", "0", *TINY]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "[sweep]"
    header, row = lines[1].split(), lines[2].split()
    assert header[:3] == ["particles", "threads", "fast_rtf_whole_run"]
    assert row[0] == "16" and row[header.index("exact_rtf_steady")] == "-"


def one_line_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as stop:
        code = int(stop.code or 0)
    captured = capsys.readouterr()
    assert captured.out == "" and "Traceback" not in captured.err
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    return code, lines[0]


@pytest.mark.parametrize("value, words", [
    ("16,x", "expected int for [estimator] particles, got 'x'"),
    ("", "expected comma-separated particle counts such as 250,500,1000, got ''"),
    ("16,,32", "expected comma-separated particle counts"),
    ("250,1", "[estimator] particles: expected a value in [2, 20000], got 1"),
    ("1e9", "expected int for [estimator] particles, got '1e9'"),
])
def test_bad_sweep_particles_is_a_one_line_usage_error(value, words, capsys):
    code, line = one_line_error(["bench", "--what", "sweep", "--sweep-particles", value],
                                capsys)
    assert code == 2
    assert line.startswith("python -m gateway bench: error: argument --sweep-particles: ")
    assert words in line, line


def test_plot_without_the_sweep_is_refused(tmp_path: Path, capsys):
    png = tmp_path / "cost.png"
    code, line = one_line_error(["bench", "--what", "estimator", "--plot", str(png)], capsys)
    assert code == 2
    assert line == "error: expected --what sweep with --plot, got --what estimator"
    assert not png.exists()


def test_lost_frames_are_the_share_asked_for_and_nothing_else_changes():
    """The lossy bench run's data: each sensor value lost (NaN) with the given
    probability, independently, the rest untouched."""
    from firmware_sim.studies.sweep import bench_data, lose_sensor_values

    data = bench_data(2.0, SEED)
    lossy = lose_sensor_values(data, 0.05, SEED)
    lost = np.isnan(lossy.y)
    assert not np.isnan(data.y).any()
    assert 0.04 < lost.mean() < 0.06                        # 6000 values: +-0.008 is 3 sd
    assert lost.all(axis=1).sum() < 5 and 220 < lost.any(axis=1).sum() < 350   # 0.25, 285
    assert np.array_equal(lossy.y[~lost], data.y[~lost])
    assert all(np.array_equal(s.values, y, equal_nan=True)
               for s, y in zip(lossy.samples, lossy.y, strict=True))


def test_pipeline_bench_runs_every_frame_through_the_front_end(capsys):
    """The front end's throughput is the bench's to measure (the serial tests that timed
    the resampler and the decoder failed on a slow host): here only that it decodes every
    simulator frame and puts 10 s of them on the 1 kHz grid."""
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation
    from firmware_sim.studies.bench_pipeline import FULL_BUS_FRAMES_PER_S

    r = bench_json(["--what", "pipeline", "--seed", "3"], capsys)["pipeline"]
    sent = sum(1 for _ in Simulation(get_scenario("nominal"),
                                     SimConfig(duration_s=10.0, seed=3)).messages())
    assert r["frames"] == sent > 0
    assert 9_900 <= r["grid_points"] <= 10_001
    for key in ("frames_per_cpu_s", "decode_frames_per_cpu_s", "cpu_s"):
        assert positive(r[key]), (key, r[key])
    assert r["cpu_share_at_full_bus_pct"] == pytest.approx(
        100.0 * FULL_BUS_FRAMES_PER_S / r["frames_per_cpu_s"])
    assert r["sustains_full_bus_on_one_core"] == (r["frames_per_cpu_s"] >= FULL_BUS_FRAMES_PER_S)
