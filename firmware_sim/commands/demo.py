"""``gateway demo``: the whole job on an embedded bus: simulator -> gateway -> frames back.

The simulated nodes play a scenario in real time on python-can's in-process
``virtual`` bus; the gateway service runs on the same bus exactly as under systemd
(worker process, alerts, state in a temporary directory); a monitor reads the
gateway's own estimate and alert frames back off the bus and prints them.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import threading
import time

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import open_bus, open_node_bus
from gateway.can.codec import default_codec
from gateway.cli import SEED, config_value, real
from gateway.config import Config, with_overrides
from gateway.errors import FrameError, InputError
from gateway.estimator.precompile import compile_parallel
from gateway.estimator.threads import available_cores
from gateway.model.vehicle import THETA_NOMINAL
from gateway.service.daemon import Service

NOMINAL = THETA_NOMINAL.as_array()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulator + gateway on an embedded bus (no hardware)")
    p.add_argument("--scenario", default="lateral-failing",
                   help="simulator scenario (default: the lateral damper fails at half-time)")
    p.add_argument("--duration", type=real(0.0, 86_400.0, lo_open=True), default=60.0,
                   help="seconds of simulation")
    p.add_argument("--particles", type=config_value("estimator", "particles"),
                   default=Config().estimator.particles,
                   help="RBPF particles (default: the service's, %(default)s; it keeps up "
                        "in fast mode beside the simulator on 2 cores)")
    p.add_argument("--sensors", type=int, choices=(3, 5), default=3)
    p.add_argument("--seed", type=SEED, default=1)
    p.add_argument("--state-dir", metavar="DIR", type=config_value("state", "directory"),
                   help="keep the gateway's state here (default: a temporary directory)")
    p.set_defaults(func=run)


class Monitor:
    """Reads the gateway's frames off the bus and prints a line a second."""

    def __init__(self, channel: str) -> None:
        self.bus = open_bus(f"virtual:{channel}")
        self.codec = default_codec()
        self.values: dict[str, float] = {}
        self.stop = threading.Event()
        self.alerts: list[str] = []
        self.estimate_frames = 0
        self.thread = threading.Thread(target=self._run, daemon=True, name="demo-monitor")

    def _run(self) -> None:
        while not self.stop.is_set():
            msg = self.bus.recv(timeout=0.1)
            if msg is None or msg.arbitration_id < 0x300:
                continue
            try:
                frame = self.codec.decode_message(msg)
            except FrameError:
                continue
            self.values.update(frame.values)
            if frame.message.startswith("GW_Est"):
                self.estimate_frames += 1
            if frame.message == "GW_Alert":
                v = frame.values
                sev = self.codec.choices("GW_Alert", "GW_Alert_Severity").get(
                    int(v["GW_Alert_Severity"]), "?")
                par = self.codec.choices("GW_Alert", "GW_Alert_Param").get(
                    int(v["GW_Alert_Param"]), "?")
                state = self.codec.choices("GW_Alert", "GW_Alert_State").get(
                    int(v["GW_Alert_State"]), "?")
                self.alerts.append(f"ALERT #{int(v['GW_Alert_Seq'])}: {sev.upper()} {par} "
                                   f"{state.lower()} ({100 * v['GW_Alert_ValueRel']:.0f} % "
                                   "of nominal)")

    def line(self, t_s: float, truth_csy: float) -> str:
        v = self.values

        def par(key: str, scale: float, nominal: float, fmt: str) -> str:
            m, s = v.get(f"GW_Est{key}_Mean", math.nan), v.get(f"GW_Est{key}_Std", math.nan)
            return (f"{m / scale:{fmt}} +- {s / scale:{fmt}} ({100 * m / nominal:3.0f} %)"
                    if math.isfinite(m) else "      --      ")

        return (f"{t_s:5.0f} s | Csy {par('Csy', 1e3, NOMINAL[0], '5.1f')} kNs/m "
                f"[truth {truth_csy / 1e3:4.1f}] | Csay {par('Csay', 1e3, NOMINAL[1], '5.0f')}"
                f" kNs/m | conicity {par('Conicity', 1, NOMINAL[2], '.3f')}")


def run(args: argparse.Namespace) -> int:
    if args.duration <= 0:
        raise InputError(f"expected a positive --duration, got {args.duration}")
    scenario = get_scenario(args.scenario)
    channel = f"railgw-demo-{time.monotonic_ns()}"
    # The estimator's kernels into numba's cache over every core before the service
    # starts: on a cold cache (the first run) its worker and warm spare would compile
    # them at once, one process each, which took over 5 minutes on a 2-core host
    # without AVX-512 (2026-12-01), and the demo then ran with no estimator. Warm, this
    # loads them in seconds.
    cores = available_cores()
    print(f"(the estimator's kernels into numba's cache, {cores} process(es): minutes on "
          "the first run, seconds later)", flush=True)
    t0 = time.monotonic()
    compile_parallel(cores)
    print(f"(kernels ready in {time.monotonic() - t0:.0f} s)", flush=True)
    with tempfile.TemporaryDirectory(prefix="railgw-demo-") as tmp_dir:
        state_dir = args.state_dir or tmp_dir
        cfg = with_overrides(Config(), {
            "bus.interface": "virtual", "bus.channel": channel, "state.directory": state_dir,
            "estimator.particles": args.particles, "estimator.sensors": args.sensors,
            "estimator.seed": args.seed})
        service = Service(cfg)
        sim = Simulation(scenario, SimConfig(duration_s=args.duration, seed=args.seed))
        monitor = Monitor(channel)
        monitor.thread.start()
        done = threading.Event()
        started = threading.Event()

        def simulate() -> None:
            service.source.opened.wait(10)
            end = time.monotonic() + 300      # the kernels are compiled: loads in seconds
            while time.monotonic() < end and not (
                    service.pipeline is not None and service.pipeline.worker.stats.ready):
                time.sleep(0.1)
            started.set()
            with open_node_bus(f"virtual:{channel}") as tx:
                send_live(sim.messages(), tx, stop=lambda: service.flags.stop)
            time.sleep(2.0)
            done.set()
            service.flags.stop = True

        print(f"demo: scenario '{scenario.name}' ({scenario.description}), "
              f"{args.duration:g} s in real time, {args.particles} particles, "
              f"{args.sensors} sensors; gateway frames read back off the bus:")
        threading.Thread(target=simulate, daemon=True, name="demo-sim").start()
        printer = threading.Thread(target=_print_loop, args=(monitor, scenario, args.duration,
                                                             started, done), daemon=True)
        printer.start()
        service.install_signal_handlers()
        code = service.run()
        done.set()
        printer.join(timeout=2)
        monitor.stop.set()
        monitor.thread.join(timeout=1)
        monitor.bus.shutdown()
    print(f"demo finished: {monitor.estimate_frames} estimate frame(s) and "
          f"{len(monitor.alerts)} alert event(s) on the bus")
    if code == 0 and monitor.estimate_frames == 0:
        print(f"demo failed: expected estimate frames back off the bus within "
              f"{args.duration:g} s, got none (the estimator worker never caught up: "
              "a loaded machine or a first run's kernel compile)", file=sys.stderr)
        return 1
    return code


def _print_loop(monitor: Monitor, scenario: object, duration_s: float,
                started: threading.Event, done: threading.Event) -> None:
    if not started.wait(1.0):
        print("(waiting for the estimator worker to load its kernels)", flush=True)
        while not started.wait(1.0):
            if done.is_set():
                return
    start = time.monotonic()
    shown = 0
    while not done.wait(2.0):
        t = time.monotonic() - start
        truth = scenario.theta([min(t, duration_s)], duration_s)[0]  # type: ignore[attr-defined]
        print(monitor.line(t, float(truth[0])), flush=True)
        while shown < len(monitor.alerts):
            print("      " + monitor.alerts[shown], flush=True)
            shown += 1
