"""A receive thread behind the kernel: service deadlines follow what it has read, not wall time.

Found under qemu (tests/vcan/test_vcan_gateway.py): a receive thread slower than the
bus leaves frames waiting in the kernel while the pipeline's queue runs empty. The
service then advanced the resampler's receive clock to wall time, so every grid point
older than 0.2 s was final with its data missing, and the frames still waiting were
dropped as late when they came: the estimator saw nothing but gaps.
"""

from __future__ import annotations

import threading
import time

import can

import gateway.service.daemon
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.source import BusSource
from gateway.config import Config, with_overrides
from gateway.service.daemon import Service

LAG_S = 2.0


class LaggingBus:
    """A bus whose reader is ``LAG_S`` behind: each frame carries the (kernel) timestamp it
    got ``LAG_S`` before it is read, and reading one takes ``per_frame_s``."""

    channel_info = "lagging test bus"

    def __init__(self, frames: list[can.Message], per_frame_s: float) -> None:
        t0 = frames[0].timestamp
        self._base = time.time() - LAG_S - t0
        self._frames = iter(frames)
        self._per_frame_s = per_frame_s
        self.done = False

    def recv(self, timeout: float | None = None) -> can.Message | None:
        msg = next(self._frames, None)
        if msg is None:
            self.done = True
            time.sleep(timeout or 0.0)
            return None
        time.sleep(self._per_frame_s)
        return can.Message(timestamp=msg.timestamp + self._base,
                           arbitration_id=msg.arbitration_id, data=msg.data,
                           is_extended_id=False)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass

    def shutdown(self) -> None:
        pass


def _frames(duration_s: float) -> list[can.Message]:
    return list(Simulation(get_scenario("nominal"), SimConfig(duration_s=duration_s,
                                                              seed=1)).messages())


def test_rx_horizon_is_the_newest_frame_read_then_wall_time_after_silence():
    frames = _frames(0.05)
    bus = LaggingBus(frames, 0.0)
    with BusSource(lambda: bus) as src:           # type: ignore[arg-type, return-value]
        deadline = time.monotonic() + 10
        while not bus.done and time.monotonic() < deadline:
            time.sleep(0.01)
        newest = frames[-1].timestamp + bus._base
        assert abs(src.stats.rx_horizon_s - newest) < 1e-6 or src.stats.rx_horizon_s > newest
        t_silent = time.time()
        deadline = time.monotonic() + 5
        while src.stats.rx_horizon_s < t_silent and time.monotonic() < deadline:
            time.sleep(0.01)
        assert src.stats.rx_horizon_s >= t_silent      # a receive found nothing: caught up


def test_a_receive_thread_behind_the_kernel_loses_no_data(tmp_path, monkeypatch):
    frames = _frames(2.0)
    bus = LaggingBus(frames, 0.0002)
    monkeypatch.setattr(gateway.service.daemon, "open_bus", lambda spec, **kwargs: bus)
    cfg = with_overrides(Config(), {"bus.interface": "virtual", "bus.channel": "unused",
                                    "state.directory": str(tmp_path / "state"),
                                    "estimator.particles": 16})
    svc = Service(cfg)
    runner = threading.Thread(target=svc.run, daemon=True)
    runner.start()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (
                bus.done and svc.pipeline is not None
                and svc.pipeline.validator.stats.frames == len(frames)):
            time.sleep(0.05)
        assert svc.pipeline is not None and svc.pipeline.validator.stats.frames == len(frames)
        stats = svc.pipeline.resampler.stats()
    finally:
        svc.flags.stop = True
        runner.join(timeout=10)
    assert stats.late_frames == 0, stats
    assert stats.grid_points >= 1900, stats                   # 2 s at 1 kHz, all read
    assert max(stats.missing.values()) <= 5, stats
