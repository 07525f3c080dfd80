"""Where simulated frames go: a CAN log file (faster than real time) or a live bus.

Log formats are python-can's, chosen by the file suffix (candump ``.log``, ``.asc``,
``.blf``, ...). Live sending paces frames by their timestamps on a monotonic clock.
:func:`drop_frames` makes the way there lossy.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import can
import numpy as np

from gateway.errors import InputError

LOG_SUFFIXES = (".log", ".asc", ".blf", ".csv", ".trc", ".mf4")


def drop_frames(messages: Iterable[can.Message], loss: float, rng: np.random.Generator,
                dropped: list[can.Message] | None = None) -> Iterator[can.Message]:
    """``messages`` as a lossy bus delivers them: each lost independently with probability
    ``loss`` (drawn from ``rng``, one draw per frame), appended to ``dropped`` if given."""
    for msg in messages:
        if loss > 0 and rng.random() < loss:
            if dropped is not None:
                dropped.append(msg)
            continue
        yield msg


def write_log(messages: Iterable[can.Message], path: str | Path) -> int:
    """Write all messages to a log chosen by suffix; returns the frame count."""
    p = Path(path)
    if p.suffix.lower() not in LOG_SUFFIXES:
        raise InputError(f"expected a log file ending in one of {list(LOG_SUFFIXES)}, "
                         f"got {str(p)!r}")
    try:
        writer = can.Logger(str(p))
    except (ValueError, ImportError, OSError) as err:
        raise InputError(f"expected a writable CAN log {str(p)!r}, got {err}") from err
    n = 0
    try:
        for msg in messages:
            writer.on_message_received(msg)
            n += 1
    finally:
        writer.stop()
    return n


def send_live(messages: Iterable[can.Message], bus: can.BusABC, *, speed: float = 1.0,
              clock: Callable[[], float] = time.monotonic,
              wall: Callable[[], float] = time.time,
              sleep: Callable[[float], None] = time.sleep,
              stop: Callable[[], bool] = lambda: False) -> int:
    """Send messages paced by their timestamps (``speed`` x real time); returns count.

    Frames are sent when their time comes; a late sender catches up without sleeping.
    Each frame carries the wall time at which it is due (``time.time()`` base), which a
    virtual bus opened with ``preserve_timestamps=True`` hands to receivers like a
    kernel receive timestamp, so Python scheduling jitter of the sender does not leak
    into the receiver's timing; SocketCAN stamps frames itself.
    """
    if speed <= 0:
        raise InputError(f"expected a positive playback speed, got {speed}")
    n = 0
    start_wall = clock()
    start_epoch = wall()
    start_data: float | None = None
    for msg in messages:
        if stop():
            break
        if start_data is None:
            start_data = msg.timestamp
        offset = (msg.timestamp - start_data) / speed
        wait = start_wall + offset - clock()
        if wait > 0.002:
            sleep(wait)
        bus.send(can.Message(timestamp=start_epoch + offset, arbitration_id=msg.arbitration_id,
                             data=msg.data, is_extended_id=msg.is_extended_id, dlc=msg.dlc))
        n += 1
    return n
