"""Helpers of the vcan tests: where vcan is, raw AF_CAN sockets, ip link, the gateway process.

The tests use real SocketCAN: ``vcan0`` (set ``RAILGW_VCAN_CHANNEL`` for another) for
what does not change the link, and a scratch interface they create themselves
(``rgw-vcan0``, needs root) for taking links down, deleting and re-creating them.
"""

from __future__ import annotations

import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CHANNEL = os.environ.get("RAILGW_VCAN_CHANNEL", "vcan0")
SCRATCH = "rgw-vcan0"
"""The interface the link tests create, break and delete (never the developer's vcan0)."""
WAIT_S = 60.0
"""Upper bound of every wait for a condition (qemu TCG is 20-50x slower than the host)."""

# linux/can.h, linux/can/raw.h, asm-generic/socket.h, linux/sock_diag.h
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_SFF_MASK = 0x7FF
CAN_RAW_FILTER = 1
CAN_RAW_ERR_FILTER = 2
CAN_ERR_MASK = 0x1FFFFFFF
CAN_FRAME = struct.Struct("=IB3x8s")
"""struct can_frame: can_id (with the EFF/RTR/ERR flags), len, 3 pad bytes, data[8]."""
SO_RXQ_OVFL = 40
SO_MEMINFO = 55
SK_MEMINFO_DROPS = 8
SK_MEMINFO_FIELDS = 9


def wait_for(cond: Callable[[], object], timeout_s: float = WAIT_S) -> bool:
    """Poll ``cond`` every 10 ms until it is true (True) or ``timeout_s`` passes (False)."""
    end = time.monotonic() + timeout_s
    while True:
        if cond():
            return True
        if time.monotonic() > end:
            return False
        time.sleep(0.01)


# ---------------------------------------------------------------- where vcan is
@cache
def vcan_unavailable(channel: str = CHANNEL) -> str | None:
    """None if ``channel`` exists and a raw CAN socket binds to it, else why not (one line)."""
    if not hasattr(socket, "AF_CAN"):
        return "this Python has no AF_CAN"
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as err:
        return f"this kernel has no SocketCAN (AF_CAN: errno {err.errno})"
    with sock:
        try:
            sock.bind((channel,))
        except OSError as err:
            return f"no {channel} here ({err.strerror})"
    return None


def vm_cache() -> Path:
    """tests/vm/setup.sh's cache (the same rule as there and in run_vcan_suite.py)."""
    env = os.environ.get("RAILGW_VM_CACHE")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "railgw-vm"


def vm_ready() -> bool:
    """Whether tests/vm/run-vcan-suite.sh can boot its VM here."""
    cache = vm_cache()
    current = cache / "kernel/current"
    return (shutil.which("qemu-system-x86_64") is not None and (cache / "venv/bin/vng").exists()
            and current.exists() and bool(current.read_text().strip()))


# ---------------------------------------------------------------- ip link
def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    """Run ``ip ARGS`` (iproute2); raises with its stderr when ``check`` and it fails."""
    exe = shutil.which("ip") or next((p for p in ("/usr/sbin/ip", "/sbin/ip", "/bin/ip")
                                      if Path(p).exists()), "ip")
    proc = subprocess.run([exe, *args], capture_output=True, text=True, timeout=30)
    if check and proc.returncode != 0:
        raise RuntimeError(f"expected 'ip {' '.join(args)}' to succeed, got exit "
                           f"{proc.returncode}: {proc.stderr.strip()}")
    return proc


def link_exists(name: str) -> bool:
    return Path("/sys/class/net", name).exists()


def add_vcan(name: str) -> None:
    """Create vcan interface ``name`` and bring it up."""
    ip("link", "add", "dev", name, "type", "vcan")
    ip("link", "set", "up", name)


# ---------------------------------------------------------------- raw AF_CAN
class RawCan:
    """A raw CAN socket bound to one interface; a context manager.

    Frames are ``(can_id, data)`` with ``can_id`` carrying the kernel's flag bits
    (CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG). With ``rxq_ovfl`` every received
    frame also brings the socket's drop count (SO_RXQ_OVFL) as ancillary data.
    """

    def __init__(self, channel: str = CHANNEL, *, rxq_ovfl: bool = False,
                 rcvbuf_bytes: int | None = None, error_frames: bool = False) -> None:
        self.channel = channel
        self.sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        if rcvbuf_bytes is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
        if rxq_ovfl:
            self.sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        if error_frames:
            self.sock.setsockopt(socket.SOL_CAN_RAW, CAN_RAW_ERR_FILTER, CAN_ERR_MASK)
        self.sock.bind((channel,))
        self.last_dropcount = 0

    def __enter__(self) -> RawCan:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.sock.close()

    def send(self, can_id: int, data: bytes = bytes(8)) -> None:
        self.sock.send(CAN_FRAME.pack(can_id, len(data), data.ljust(8, b"\0")))

    def send_error(self, error_class: int, data: bytes = bytes(8)) -> None:
        """Inject an error frame: class bits (linux/can/error.h) | CAN_ERR_FLAG, DLC 8."""
        self.send(CAN_ERR_FLAG | error_class, data)

    def recv(self, timeout_s: float | None = WAIT_S) -> tuple[int, bytes] | None:
        """The next frame, or None after ``timeout_s`` (0: don't wait)."""
        self.sock.settimeout(timeout_s)
        try:
            raw, anc, _flags, _addr = self.sock.recvmsg(CAN_FRAME.size,
                                                        socket.CMSG_SPACE(4))
        except (TimeoutError, BlockingIOError):
            return None
        for level, kind, value in anc:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL:
                self.last_dropcount = struct.unpack("=I", value[:4])[0]
        can_id, length, data = CAN_FRAME.unpack(raw)
        return can_id, data[:length]

    def drain(self) -> list[tuple[int, bytes]]:
        """Every frame already queued on the socket (does not wait)."""
        out = []
        while (frame := self.recv(0)) is not None:
            out.append(frame)
        return out

    def kernel_drops(self) -> int:
        """Frames the kernel dropped for this socket (SO_MEMINFO's SK_MEMINFO_DROPS)."""
        return socket_drops(self.sock)


def socket_drops(sock: socket.socket) -> int:
    """sk_drops of any socket: the counter SO_RXQ_OVFL reports, read with SO_MEMINFO."""
    raw = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * SK_MEMINFO_FIELDS)
    return struct.unpack(f"={SK_MEMINFO_FIELDS}I", raw)[SK_MEMINFO_DROPS]


def kernel_filters(sock: socket.socket, max_filters: int = 64) -> list[tuple[int, int]]:
    """The (can_id, can_mask) receive filters installed on a raw CAN socket."""
    raw = sock.getsockopt(socket.SOL_CAN_RAW, CAN_RAW_FILTER, 8 * max_filters)
    return [struct.unpack_from("=II", raw, i) for i in range(0, len(raw), 8)]


# ---------------------------------------------------------------- processes
def python_module(*args: str, timeout_s: float = 600.0) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ARGS`` with this interpreter in the project root."""
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=timeout_s, cwd=ROOT)


class GatewayProcess:
    """``python -m gateway run`` as systemd would start it, with our own NOTIFY_SOCKET.

    For the end-to-end test (tests/vcan/test_vcan_gateway.py): ``wait_ready()`` returns
    once the service sent READY=1 (no sleeps), ``status`` is its last STATUS=, and
    ``stop()`` sends SIGTERM and returns the exit status. A context manager.
    """

    def __init__(self, args: Sequence[str], *, env: dict[str, str] | None = None,
                 log_path: Path | None = None) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="rgw-notify-")
        path = os.path.join(self._dir.name, "notify")
        self._notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._notify.bind(path)
        self.status = ""
        self.ready = False
        self.notifications: list[dict[str, str]] = []
        self.log_path = log_path or Path(self._dir.name) / "gateway.log"
        self._log = self.log_path.open("w")
        full_env = dict(os.environ, NOTIFY_SOCKET=path, **(env or {}))
        self.proc = subprocess.Popen([sys.executable, "-m", "gateway", *args], cwd=ROOT,
                                     env=full_env, stdout=self._log, stderr=subprocess.STDOUT)

    def __enter__(self) -> GatewayProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def poll_notifications(self, timeout_s: float) -> bool:
        """Read one datagram (True) or time out (False); updates ready and status."""
        self._notify.settimeout(timeout_s)
        try:
            data = self._notify.recv(4096)
        except TimeoutError:
            return False
        fields = dict(line.partition("=")[::2] for line in data.decode().splitlines())
        self.notifications.append(fields)
        self.ready = self.ready or fields.get("READY") == "1"
        self.status = fields.get("STATUS", self.status)
        return True

    def wait_for_notification(self, cond: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
        """Read notifications until ``cond()`` or the process exits or ``timeout_s`` passes."""
        end = time.monotonic() + timeout_s
        while not cond():
            if self.proc.poll() is not None or time.monotonic() > end:
                return False
            self.poll_notifications(min(1.0, max(0.01, end - time.monotonic())))
        return True

    def wait_ready(self, timeout_s: float = WAIT_S) -> bool:
        return self.wait_for_notification(lambda: self.ready, timeout_s)

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self, timeout_s: float = WAIT_S) -> int | None:
        """SIGTERM, wait, then SIGKILL; the exit status (idempotent)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        with suppress(OSError):
            self._notify.close()
        self._log.close()
        return self.proc.returncode


@contextmanager
def scratch_link(name: str = SCRATCH) -> Iterator[str]:
    """A fresh vcan interface ``name`` (up) for the duration; deleted afterwards."""
    if link_exists(name):
        ip("link", "del", "dev", name)
    add_vcan(name)
    try:
        yield name
    finally:
        if link_exists(name):
            ip("link", "del", "dev", name, check=False)
