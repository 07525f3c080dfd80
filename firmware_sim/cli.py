"""The ``python -m firmware_sim`` command line: run scenarios, play CSVs, stream to a bus.

Deliberate failures (GatewayError) print one line and exit non-zero; never a traceback.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Sequence

from firmware_sim.output import send_live, write_log
from firmware_sim.playback import playback_frames
from firmware_sim.scenarios import SCENARIOS, get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import DEFAULT_DEMO_BUS, open_bus, open_node_bus, parse_bus_spec
from gateway.cli import (
    SEED,
    OneLineParser,
    config_value,
    dispatch,
    integer,
    output_dir,
    output_path,
    real,
    writing,
)
from gateway.errors import FrameError, InputError
from gateway.offline.interchange import read_csv


def _add_target(p: argparse.ArgumentParser) -> None:
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--out", metavar="RUN.log", type=output_path,
                        help="write a CAN log, format by suffix (.log candump, .asc, .blf)")
    target.add_argument("--bus", metavar="IFACE:CHANNEL",
                        help="send live, e.g. virtual:railgw or socketcan:vcan0")
    p.add_argument("--speed", type=real(0.01, 1000.0), default=1.0,
                   help="live playback speed, x real time (default 1)")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="python -m firmware_sim",
                                     description="Simulated bogie/body/wheelset/vehicle nodes.")
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser("list", help="list the scenarios")
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("run", help="simulate a scenario to a log or a bus")
    p.add_argument("--scenario", default="nominal", help="scenario name (see 'list')")
    p.add_argument("--duration", type=real(0.0, 86_400.0, lo_open=True),
                   help="seconds (default: the scenario's)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--nonlinear-dampers", action="store_true",
                   help="saturating damper curves in the truth (paper Figs. 6-7)")
    p.add_argument("--track-roughness", type=config_value("estimator", "track_roughness"),
                   default=None,
                   help="Ar as printed in the paper (default 2 x 0.33e-3)")
    p.add_argument("--noise-scale", type=real(0.0, 100.0, lo_open=True), default=1.0,
                   help="sensor noise std relative to the paper's Qv (1; e.g. 1.4 for "
                        "noisier sensors or another simulator's convention)")
    _add_target(p)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("play-csv", help="turn an interchange CSV into node frames")
    p.add_argument("csv", help="interchange CSV (time_s, bogie_lat_acc_mps2, ...)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the bus latency jitter")
    _add_target(p)
    p.set_defaults(func=cmd_play_csv)
    p = sub.add_parser("stream", help="simulate on an embedded bus and print decoded values")
    p.add_argument("--scenario", default="nominal")
    p.add_argument("--duration", type=real(0.0, 86_400.0, lo_open=True), default=10.0,
                   help="seconds (default 10)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--bus", default=DEFAULT_DEMO_BUS, help=f"default {DEFAULT_DEMO_BUS}")
    p.set_defaults(func=cmd_stream)
    p = sub.add_parser("fleet", help="simulate a fleet: vehicles x days x runs, logs + truth")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir,
                   help="directory for logs/<vehicle>/<bogie>/*.log, truth.csv, truth.json")
    p.add_argument("--vehicles", type=integer(1, 1000), default=12)
    p.add_argument("--days", type=integer(1, 3650), default=30)
    p.add_argument("--runs-per-day", type=integer(1, 24), default=2)
    p.add_argument("--run-seconds", type=real(2.0, 3600.0), default=8.0,
                   help="length of each run, s (default 8)")
    p.add_argument("--bogies", type=integer(1, 4), default=1)
    p.add_argument("--degrade-days", type=real(1.0, 3650.0), default=60.0,
                   help="days over which a degrading damper loses 30 %% (default 60)")
    p.add_argument("--fail-frac", type=real(0.0, 1.0, lo_open=True), default=0.5,
                   help="the failing damper fails at this fraction of the days (default 0.5)")
    p.add_argument("--start", default="2026-01-05", help="first day, YYYY-MM-DD (UTC)")
    p.add_argument("--seed", type=SEED, default=0)
    p.set_defaults(func=cmd_fleet)
    return parser


def cmd_fleet(args: argparse.Namespace) -> int:
    from firmware_sim.fleet import FleetSpec, simulate_fleet

    spec = FleetSpec(vehicles=args.vehicles, days=args.days, runs_per_day=args.runs_per_day,
                     run_s=args.run_seconds, bogies=args.bogies, degrade_days=args.degrade_days,
                     fail_frac=args.fail_frac, seed=args.seed, start=args.start)

    def progress(k: int, n: int) -> None:
        if k == n or k % 10 == 0:
            print(f"simulated {k}/{n} runs", flush=True)

    with writing(args.out):
        n = simulate_fleet(spec, args.out, progress=progress)
    print(f"wrote {n} runs, truth.csv and truth.json to {args.out}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    for s in SCENARIOS.values():
        print(f"{s.name:18} {s.default_duration_s:6.0f} s  {s.description}")
    return 0


def _simulation(args: argparse.Namespace) -> Simulation:
    scenario = get_scenario(args.scenario)
    duration = args.duration if args.duration is not None else scenario.default_duration_s
    if not duration > 0:
        raise InputError(f"expected a positive --duration in seconds, got {duration}")
    kwargs = {}
    if getattr(args, "track_roughness", None) is not None:
        kwargs["ar_paper"] = args.track_roughness
    cfg = SimConfig(duration_s=duration, seed=args.seed,
                    nonlinear_dampers=getattr(args, "nonlinear_dampers", False),
                    noise_scale=getattr(args, "noise_scale", 1.0), **kwargs)
    return Simulation(scenario, cfg)


def _emit(messages: object, args: argparse.Namespace) -> int:
    if args.out:
        with writing(args.out):
            n = write_log(messages, args.out)  # type: ignore[arg-type]
        print(f"wrote {n} frames to {args.out}")
        return 0
    spec = parse_bus_spec(args.bus)
    with open_node_bus(spec) as bus:
        n = send_live(messages, bus, speed=args.speed)  # type: ignore[arg-type]
    print(f"sent {n} frames on {spec}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    return _emit(_simulation(args).messages(), args)


def cmd_play_csv(args: argparse.Namespace) -> int:
    return _emit(playback_frames(read_csv(args.csv), seed=args.seed), args)


def cmd_stream(args: argparse.Namespace) -> int:
    """Sender thread on the bus; this thread receives, decodes and prints twice a second."""
    from gateway.can.codec import default_codec

    codec = default_codec()
    sim = _simulation(args)
    spec = parse_bus_spec(args.bus)
    done = threading.Event()
    with open_bus(spec) as rx, open_node_bus(spec) as tx:
        def send() -> None:
            send_live(sim.messages(), tx)
            done.set()

        sender = threading.Thread(target=send, daemon=True, name="sim-sender")
        sender.start()
        print(f"simulating '{sim.scenario.name}' for {sim.config.duration_s:g} s on {spec}; "
              "decoded sensor values:")
        print(f"{'t [s]':>6} {'bogie acc':>10} {'yaw rate':>10} {'body acc':>10} "
              f"{'speed':>7} {'frames':>7} {'rejected':>8}")
        last: dict[str, float] = {}
        n_ok = n_bad = 0
        t_start = time.monotonic()
        next_print = t_start + 0.5
        while True:
            msg = rx.recv(timeout=0.1)
            if msg is None and done.is_set():
                break
            if msg is not None:
                try:
                    last.update(codec.decode_message(msg).values)
                    n_ok += 1
                except FrameError:
                    n_bad += 1
            now = time.monotonic()
            if now >= next_print:
                next_print += 0.5
                print(f"{now - t_start:6.1f} {last.get('BGN_Acc', float('nan')):10.4f} "
                      f"{last.get('BGN_YawRate', float('nan')):10.5f} "
                      f"{last.get('BDN_Acc', float('nan')):10.4f} "
                      f"{last.get('VEH_Speed', float('nan')):7.2f} {n_ok:7d} {n_bad:8d}",
                      flush=True)
        sender.join(timeout=1.0)
    print(f"done: {n_ok} frames decoded, {n_bad} rejected")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    return dispatch(args)
