"""The gateway end-to-end test's bus traffic: a recorded simulator run, played into vcan.

Why recorded, and why canplayer: the simulated nodes send 3 100 frames/s (three 1 kHz
sensor messages and the 100 Hz speed). Under qemu's TCG a Python sender manages a
small fraction of that, and the traffic cannot be slowed down instead: the gateway
fits each node's clock to the kernel receive timestamps (drift clamped to 500 ppm,
frames more than 0.1 s off the fit are outliers), so frames delivered at a fraction of
their rate look like a broken node clock, not like slow data. So the run is written
to a candump log beforehand (on the host: ``tests/vm/prewarm.py``; anywhere else by
the test itself, which takes a second) and played at its recorded rate by can-utils'
``canplayer``, a small C program that keeps up even under TCG. Without canplayer (a
laptop without can-utils) python-can's player is used; the VM requires canplayer.

The run: the paper's vehicle at 42.5 m/s with the lateral damper worn to 40 % of
nominal (Csy 16 kNs/m) from the start, 8 s. Why not ``lateral-failing`` (nominal, then
a step to 25 %): with the 64 particles used here the RBPF follows a step only slowly
(40 -> 10 kNs/m: still ~30 kNs/m 10 s after it, measured), and the 40-60 s of data it
would need take many minutes under TCG.

The service's settings that differ from the defaults (``OVERRIDES``), and why: under
TCG one RBPF step at 64 particles takes about 25 ms (RTF 0.04 at 1 kHz, measured in
the VM), so the estimator runs on a 250 Hz grid (``[resampler] fs_hz``) with 64
particles: 2 000 steps for the run. The sensor frames still come at 1 kHz; the
resampler interpolates them onto the grid as on any other rate. With these settings
the replay of this log (simulator seeds 0-4) raises a Csy alert at 2.5-5.6 s of data
(estimates before the estimator's first look at its sensor noise, 2 s after the first
data, are provisional and not judged; where that look is not sure, until its test at
5 s) and ends at Csy 15.6-18.6 kNs/m, Csay 1.28-1.51 x and conicity within 12 % of
nominal (host replay, measured 2026-11-25; the test's live run in the VM bounds Csay
within 25 %).

How close Csy ends (``CSY_END_REL``): with 64 particles the cloud is still coming down
from the prior after 8 s, and where it ends varies with the filter's seed and with the
receive times (the grid's phase). The same log replayed on the host (2026-11-25, after
a live VM run ended 31 % high against the former 30 % bound): 30 filter seeds, Csy
−6 % to +43 % off (median +4 %, 3 of 30 beyond 25 %, 1 beyond 30 %); 30 replays with
the receive times shifted by 0-4 ms and jittered by 0-2 ms per frame, +0 % to +24 %
(median +8 %). Two live VM runs that day: +31 % and +24 %, both in the top tenth of
that spread: the VM's receive times may be worse than the jitter tried here (canplayer
under emulation; not measured). The bound is 50 %: beyond that spread, and far from a
filter that stayed at nominal (+150 %).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

DURATION_S = 8.0
SEED = 3
CSY_FACTOR = 0.4
"""Truth Csy relative to nominal, the whole run (inside the RBPF's 0.3-2.5 x prior)."""
CSY_END_REL = 0.5
"""How far from the truth the last Csy estimate may be (relative): the module docstring
says how the 64-particle filter's end point spreads."""
OVERRIDES: dict[str, float | int] = {"resampler.fs_hz": 250.0, "estimator.particles": 64,
                                     "bus.rcvbuf_bytes": 64 << 20}
"""The service's settings for the test (``section.key``); every other key is the default.
The worker's queue (5 000 samples, 20 s at 250 Hz) holds the whole run, so a worker
far behind real time drops nothing. The CAN socket's receive buffer holds the whole run
too (64 MiB; the VM runs as root, so the kernel grants it past net.core.rmem_max): the
service's receive thread, 30x slower under TCG, cannot take 3 100 frames/s off the
socket as they come, and the default 4 MiB (about 3 s) lost 2,422 frames in a VM
run on 2026-11-26. On a real machine the default applies."""
LOG_CHANNEL = "vcan0"
"""The interface name written into the candump log (python-can's default)."""


def data_dir() -> Path | None:
    """Where the VM runner's host warm-up leaves the log (``RAILGW_VCAN_DATA``), if set."""
    env = os.environ.get("RAILGW_VCAN_DATA")
    return Path(env) if env else None


def log_name() -> str:
    return f"worn-lateral-{CSY_FACTOR:g}x-{DURATION_S:g}s-seed{SEED}.log"


def scenario():  # -> firmware_sim.scenarios.Scenario (imported lazily: numba)
    from firmware_sim.scenarios import V_PAPER, Scenario
    from gateway.model.vehicle import THETA_NOMINAL

    theta = THETA_NOMINAL.as_array() * np.array([CSY_FACTOR, 1.0, 1.0])
    return Scenario("worn-lateral", f"lateral damper at {CSY_FACTOR:g} x nominal from the "
                    "start", DURATION_S, lambda f: np.tile(theta, (len(f), 1)),
                    lambda f: np.full(len(f), V_PAPER))


def traffic_log(directory: Path) -> Path:
    """The candump log of the run in ``directory``, written if it is not there yet."""
    path = directory / log_name()
    if not path.exists():
        from firmware_sim.output import write_log
        from firmware_sim.simulation import SimConfig, Simulation

        directory.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".part.log")
        write_log(Simulation(scenario(), SimConfig(duration_s=DURATION_S, seed=SEED))
                  .messages(), tmp)
        tmp.rename(path)
    return path


def config_toml(channel: str, state_dir: Path) -> str:
    """The service's configuration file for the test: ``OVERRIDES`` on SocketCAN."""
    sections: dict[str, list[str]] = {"bus": ['interface = "socketcan"', f'channel = "{channel}"'],
                                      "state": [f'directory = "{state_dir}"']}
    for dotted, value in OVERRIDES.items():
        section, _, key = dotted.partition(".")
        sections.setdefault(section, []).append(f"{key} = {value!r}")
    return "".join(f"[{name}]\n" + "\n".join(lines) + "\n\n" for name, lines in sections.items())


def play(log: Path, channel: str, *, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """Play ``log`` into ``channel`` at its recorded rate; returns when it is sent."""
    exe = shutil.which("canplayer")
    if exe is not None:
        cmd = [exe, "-I", str(log), f"{channel}={LOG_CHANNEL}"]
    else:
        if os.environ.get("RAILGW_IN_VM") == "1":
            raise RuntimeError("expected can-utils' canplayer in the VM, got none on PATH "
                               "(tests/vm/setup.sh installs it)")
        cmd = [sys.executable, "-m", "can.player", "-i", "socketcan", "-c", channel, str(log)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)


def warm(directory: Path | None) -> None:
    """Host warm-up for the VM: write the log, and replay it through the service's
    pipeline with the test's estimator settings, so that every numba kernel the
    guest's worker runs is compiled into the shared cache."""
    import tempfile

    from gateway.config import Config, with_overrides
    from gateway.offline.replay import replay

    with tempfile.TemporaryDirectory(prefix="rgw-e2e-warm-") as tmp:
        log = traffic_log(directory or Path(tmp))
        cfg = with_overrides(Config(), {**OVERRIDES, "state.directory": str(Path(tmp) / "state")})
        result = replay(log, cfg)
    if not any(a.parameter == "csy_ns_per_m" for a in result.alerts):
        raise RuntimeError(f"expected the replay of {log.name} to raise a Csy alert, got "
                           f"{result.alerts}")
