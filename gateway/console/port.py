"""The console's serial port: a pyserial thread that feeds the console and reopens forever.

The thread opens the device (default 115200 8N1), sends the banner, then reads what
arrives, hands it to :meth:`Console.feed` and writes the reply. If the port vanishes
(a read or write raises SerialException/OSError, the device reports EOF, or the device
node disappears or is replaced) it closes the port, ends the console session and
reopens it with exponential backoff between ``reopen_min_s`` and ``reopen_max_s``,
for as long as it runs. It touches nothing but the port and the console: a fitter
pulling the cable never disturbs the estimator. A reply the other side does not read
within ``write_timeout_s`` is dropped (counted), not retried.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import serial

from gateway.config import SerialConfig
from gateway.console.engine import Console
from gateway.console.session import ConsoleLimits
from gateway.console.view import ServiceView
from gateway.reconnect import Backoff
from gateway.records import Alert

log = logging.getLogger(__name__)

OpenSerial = Callable[[str, int], serial.Serial]
READ_CHUNK_BYTES = 4096
MAX_PENDING_ALERTS = 16
"""Alert notices waiting for the port thread; older ones are dropped beyond this."""
NODE_CHECK_S = 0.5
"""How often the device node is checked for having vanished or been replaced."""


class PortGone(serial.SerialException):
    """The device node vanished or now names another device."""


def open_serial(device: str, baudrate: int, *, read_timeout_s: float = 0.1,
                write_timeout_s: float = 2.0) -> serial.Serial:
    """Open ``device`` 8N1, no flow control, exclusive (so no getty can share it)."""
    return serial.Serial(port=device, baudrate=baudrate, bytesize=serial.EIGHTBITS,
                         parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                         timeout=read_timeout_s, write_timeout=write_timeout_s,
                         xonxoff=False, rtscts=False, dsrdtr=False, exclusive=True)


def _node_id(device: str) -> tuple[int, int] | None:
    try:
        st = os.stat(device)
    except OSError:
        return None
    return st.st_rdev, st.st_ino


@dataclass
class PortStats:
    """Counters of the port thread (read them from any thread)."""

    opens: int = 0
    open_failures: int = 0
    losses: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    writes_dropped: int = 0
    errors: int = 0
    is_open: bool = False
    last_error: str = ""


class ConsolePort:
    """The serial thread of one :class:`Console`; a context manager, ``close()`` idempotent.

    Usage from the service::

        console = Console(view, pin_hash=cfg.serial.pin_hash, port_name=device)
        port = ConsolePort(console, cfg.serial.device, baudrate=cfg.serial.baudrate)
        port.start()   # returns at once; the thread opens the port (and reopens it)
        port.notify_alert(alert)   # optional: alert events shown to a connected fitter
        port.close()   # stops the thread (within about read_timeout_s) and the port
    """

    def __init__(self, console: Console, device: str, *, baudrate: int = 115200,
                 reopen_min_s: float = 0.2, reopen_max_s: float = 5.0,
                 read_timeout_s: float = 0.1, write_timeout_s: float = 2.0,
                 opener: OpenSerial | None = None) -> None:
        if not device:
            raise ValueError("expected a serial device path, got ''")
        self.console = console
        self.device = device
        self.baudrate = baudrate
        self._opener: OpenSerial = opener or (
            lambda dev, baud: open_serial(dev, baud, read_timeout_s=read_timeout_s,
                                          write_timeout_s=write_timeout_s))
        self._stop = threading.Event()
        self._backoff = Backoff(reopen_min_s, reopen_max_s, wait=self._stop.wait)
        self._thread: threading.Thread | None = None
        self._changed = threading.Condition()
        self._alerts: deque[Alert] = deque(maxlen=MAX_PENDING_ALERTS)
        self.stats = PortStats()

    def __enter__(self) -> ConsolePort:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Start the thread (it opens the port); a second call does nothing."""
        if self._thread is None and not self._stop.is_set():
            self._thread = threading.Thread(target=self._run, name="console-port",
                                            daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop the thread and close the port; idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():
                log.warning("console port thread did not stop within 5 s")
            self._thread = None

    def notify_alert(self, alert: Alert) -> None:
        """Show an alert event on the terminal, if one is connected (text mode). Called
        from the service's thread; never blocks (at most 16 wait, older are dropped)."""
        if self.stats.is_open:
            self._alerts.append(alert)

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait_for(self, predicate: Callable[[PortStats], bool], timeout_s: float) -> bool:
        """Block until ``predicate(stats)`` holds (checked whenever the port opens, fails
        to open or is lost); False after ``timeout_s``.
        E.g. ``wait_for(lambda s: s.opens >= 2, 5.0)``."""
        with self._changed:
            return self._changed.wait_for(lambda: predicate(self.stats), timeout_s)

    def _notify(self) -> None:
        with self._changed:
            self._changed.notify_all()

    # -- the thread ------------------------------------------------------------------------
    def _run(self) -> None:
        backoff = self._backoff
        failing = 0  # consecutive open failures: log the first, not every retry
        while not self._stop.is_set():
            try:
                ser = self._opener(self.device, self.baudrate)
            except Exception as err:  # SerialException, OSError, ValueError, ...
                self.stats.open_failures += 1
                self.stats.last_error = f"open failed: {err}"
                self._notify()
                failing += 1
                (log.info if failing == 1 else log.debug)(
                    "console port %s not available (%s); retrying every <= %.1f s",
                    self.device, err, backoff.max_s)
                backoff.pause()
                continue
            if failing:
                log.info("console port %s available after %d failed opens", self.device,
                         failing)
            failing = 0
            if self._session(ser):   # it read data: the port worked
                backoff.reset()
            if not self._stop.is_set():
                backoff.pause()

    def _session(self, ser: serial.Serial) -> bool:
        """Serve one open port until it is lost or the thread stops; True if it read data."""
        node = _node_id(self.device)
        self.stats.opens += 1
        self.stats.is_open = True
        self._notify()
        log.info("console port %s open at %d baud", self.device, self.baudrate)
        got_input = False
        reason = "stopped"
        try:
            self._write(ser, self.console.connect())
            next_check = time.monotonic() + NODE_CHECK_S
            while not self._stop.is_set():
                data = ser.read(min(ser.in_waiting, READ_CHUNK_BYTES) or 1)
                if data:
                    got_input = True
                    self.stats.bytes_in += len(data)
                    out = self.console.feed(data)
                else:
                    out = self.console.poll()
                while self._alerts:
                    out += self.console.notify_alert(self._alerts.popleft())
                if out:
                    self._write(ser, out)
                if time.monotonic() >= next_check:
                    next_check = time.monotonic() + NODE_CHECK_S
                    if _node_id(self.device) != node:
                        raise PortGone(f"{self.device} vanished or was replaced")
        except (serial.SerialException, OSError) as err:
            reason = str(err) or type(err).__name__
            self.stats.losses += 1
            self.stats.last_error = reason
            log.warning("console port %s lost (%s); reopening", self.device, reason)
        except Exception as err:  # never let the thread die; reopen instead
            reason = f"internal error {type(err).__name__}"
            self.stats.errors += 1
            self.stats.last_error = reason
            log.exception("console port %s: internal error; reopening", self.device)
        finally:
            self.console.disconnect(reason)
            try:
                ser.close()
            except Exception as err:
                log.debug("console port close: %s", err)
            self.stats.is_open = False
            self._notify()
        return got_input

    def _write(self, ser: serial.Serial, data: bytes) -> None:
        try:
            n = ser.write(data)
            self.stats.bytes_out += n or 0
        except serial.SerialTimeoutException:
            self.stats.writes_dropped += 1
            log.debug("console port %s: reply of %d bytes not read in time; dropped",
                      self.device, len(data))


def console_port(view: ServiceView, serial_cfg: SerialConfig, *,
                 limits: ConsoleLimits | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time, reopen_min_s: float = 0.2,
                 reopen_max_s: float = 5.0) -> ConsolePort | None:
    """The service's one call: a (not yet started) port for ``[serial]``; None when the
    device is '' (console disabled)."""
    if not serial_cfg.device:
        return None
    console = Console(view, pin_hash=serial_cfg.pin_hash, limits=limits, clock=clock,
                      wall=wall, port_name=serial_cfg.device)
    return ConsolePort(console, serial_cfg.device, baudrate=serial_cfg.baudrate,
                       reopen_min_s=reopen_min_s, reopen_max_s=reopen_max_s)
