"""The CAN source: a receive thread over a python-can bus that reopens it with backoff.

Frames go into a bounded queue; a full queue drops the frame and counts it. Error
frames update the bus state (error-active, error-passive, bus-off) and never enter
the queue. If the bus fails, or its interface goes down or disappears, the thread
closes it, waits (exponential backoff between ``reopen_min_s`` and ``reopen_max_s``)
and reopens it, for as long as the source runs. Sending shares the open bus.
"""

from __future__ import annotations

import enum
import logging
import math
import queue
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can

from gateway.reconnect import Backoff

log = logging.getLogger(__name__)

# SocketCAN error-frame classes (linux/can/error.h), as python-can reports them in
# arbitration_id, and the controller-status bits of data[1] for CAN_ERR_CRTL.
CAN_ERR_CRTL = 0x004
CAN_ERR_BUSOFF = 0x040
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
# Frames the kernel dropped because the socket's receive buffer was full: sk_drops, the
# counter SO_RXQ_OVFL attaches to each frame, read on demand with SO_MEMINFO.
SO_MEMINFO = 55  # asm-generic/socket.h
SK_MEMINFO_DROPS = 8  # linux/sock_diag.h
_MEMINFO = struct.Struct("=9I")
KERNEL_DROPS_EVERY_FRAMES = 256


class BusState(enum.IntEnum):
    """CAN controller state as reported in health (values as on the bus)."""

    ERROR_ACTIVE = 0
    ERROR_PASSIVE = 1
    BUS_OFF = 2


def next_bus_state(state: BusState, error_frame: can.Message) -> BusState:
    """The bus state after one error frame (pure function)."""
    cls = error_frame.arbitration_id
    data = bytes(error_frame.data)
    if cls & CAN_ERR_BUSOFF:
        return BusState.BUS_OFF
    if cls & CAN_ERR_RESTARTED:
        return BusState.ERROR_ACTIVE
    if cls & CAN_ERR_CRTL and len(data) > 1:
        if data[1] & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            return BusState.ERROR_PASSIVE
        if data[1] & CAN_ERR_CRTL_ACTIVE:
            return BusState.ERROR_ACTIVE
    return state


def kernel_drops(bus: can.BusABC) -> int | None:
    """Frames the kernel dropped for ``bus``'s socket so far; None without a kernel socket."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return None
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, _MEMINFO.size)
    except OSError:
        return None
    return _MEMINFO.unpack(raw)[SK_MEMINFO_DROPS]


@dataclass
class SourceStats:
    """Counters of the source (monotonic; read them from any thread)."""

    frames_rx: int = 0
    dropped_queue_full: int = 0
    dropped_kernel: int = 0
    error_frames: int = 0
    send_failures: int = 0
    frames_tx: int = 0
    reopens: int = 0
    bus_open: bool = False
    bus_state: BusState = BusState.ERROR_ACTIVE
    last_error: str = ""
    rx_horizon_s: float = -math.inf
    """Receive-clock time (s, ``time.time()`` base) up to which every frame has been taken
    off the bus: the newest frame's timestamp while frames flow (it follows a step of the
    receive clock, back or forward), that plus the wall time since after a receive that
    waited and found none. Behind wall time when this thread lags the kernel; a consumer
    must not declare data missing past it."""


class BusSource:
    """Receive thread + bounded queue over a bus made by ``open_bus()``; a context manager."""

    def __init__(self, open_bus: Callable[[], can.BusABC], *, queue_frames: int = 100_000,
                 reopen_min_s: float = 0.2, reopen_max_s: float = 10.0) -> None:
        self._open_bus = open_bus
        self._queue: queue.Queue[can.Message] = queue.Queue(maxsize=queue_frames)
        self._stop = threading.Event()
        self._backoff = Backoff(reopen_min_s, reopen_max_s, wait=self._stop.wait)
        self._bus: can.BusABC | None = None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.stats = SourceStats()
        self.opened = threading.Event()

    def __enter__(self) -> BusSource:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Start the receive thread (it opens the bus)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="can-rx", daemon=True)
            self._thread.start()

    def get(self, timeout_s: float | None = None) -> can.Message | None:
        """The next received frame, or None after ``timeout_s``."""
        try:
            return self._queue.get(timeout=timeout_s) if timeout_s else self._queue.get_nowait()
        except queue.Empty:
            return None

    def send(self, msg: can.Message) -> bool:
        """Send on the open bus; False (and counted) if it is closed or the send fails."""
        with self._lock:
            bus = self._bus
        if bus is None:
            self.stats.send_failures += 1
            return False
        try:
            bus.send(msg, timeout=0.01)
            self.stats.frames_tx += 1
            return True
        except (can.CanError, OSError) as err:
            self.stats.send_failures += 1
            log.debug("send of 0x%X failed: %s", msg.arbitration_id, err)
            return False

    def close(self) -> None:
        """Stop the thread and close the bus; idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._close_bus()

    def _close_bus(self) -> None:
        with self._lock:
            bus, self._bus = self._bus, None
        self.stats.bus_open = False
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as err:
                log.debug("bus shutdown: %s", err)

    def _run(self) -> None:
        backoff = self._backoff
        while not self._stop.is_set():
            try:
                bus = self._open_bus()
            except (can.CanError, OSError, ValueError) as err:
                self.stats.last_error = f"open failed: {err}"
                log.warning("CAN bus open failed (%s); retrying in %.1f s", err,
                            backoff.delay_s)
                backoff.pause()
                continue
            with self._lock:
                self._bus = bus
            self.stats.bus_open = True
            self.opened.set()
            log.info("CAN bus open: %s", bus.channel_info)
            try:
                self._receive(bus)
                backoff.reset()
            except (can.CanError, OSError) as err:
                self.stats.last_error = str(err)
                log.warning("CAN bus failed (%s); reopening in %.1f s", err, backoff.delay_s)
                self._close_bus()
                self.stats.reopens += 1
                backoff.pause()
        self._close_bus()

    def _receive(self, bus: can.BusABC) -> None:
        stats = self.stats
        put = self._queue.put_nowait
        drops_before = stats.dropped_kernel  # a reopened socket counts from 0 again
        n = 0
        last_stamp_s = -math.inf
        last_wall_s: float | None = None     # wall time when the newest frame was taken
        try:
            while not self._stop.is_set():
                msg = bus.recv(timeout=0.1)
                n += 1
                if msg is None or n % KERNEL_DROPS_EVERY_FRAMES == 0:
                    self._count_kernel_drops(bus, drops_before)
                if msg is None:
                    # Nothing waits: the horizon is "now" on the frames' own clock (the
                    # newest stamp plus the wall time since), not wall time, so a receive
                    # clock that stepped away from wall time keeps one time base.
                    stats.rx_horizon_s = time.time() if last_wall_s is None else \
                        last_stamp_s + (time.time() - last_wall_s)
                    continue
                # The newest frame's stamp, not the largest seen: after a step back of
                # the receive clock the horizon follows it (a kept maximum would run ahead
                # of the re-based frames and turn them into late drops).
                stats.rx_horizon_s = last_stamp_s = msg.timestamp
                last_wall_s = time.time()
                if msg.is_error_frame:
                    stats.error_frames += 1
                    stats.bus_state = next_bus_state(stats.bus_state, msg)
                    continue
                stats.frames_rx += 1
                try:
                    put(msg)
                except queue.Full:
                    stats.dropped_queue_full += 1
        finally:
            self._count_kernel_drops(bus, drops_before)

    def _count_kernel_drops(self, bus: can.BusABC, before: int) -> None:
        drops = kernel_drops(bus)
        if drops is not None:
            self.stats.dropped_kernel = before + drops
