"""Runs the installed ``railgw`` console script in this process, beside simulated nodes and
a frame monitor on the same python-can ``virtual`` bus, and logs what it sees.

python-can's virtual bus is in-process only and this machine's kernel has no CAN, so
the simulator and the monitor share the service's process: the service itself is the
venv's ``bin/railgw`` script, run as ``__main__`` in the main thread (its SIGTERM
handler, its spawned worker), exactly as systemd's ExecStart would run it. The
simulator starts when the service sends READY=1 to the NOTIFY_SOCKET set up here.
Events go to a JSON Lines file, one object a line:
``{"event": "notify", "text": ...}``, ``{"event": "frame", "message": ..., "values": ...}``,
``{"event": "sim_done", "frames": n}``, ``{"event": "exit", "code": n}``.

usage: python live_helper.py EVENTS.jsonl CHANNEL SCENARIO DURATION_S -- RAILGW_ARGS...
The exit status is the service's.
"""

from __future__ import annotations

import json
import os
import runpy
import socket
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any


def main(argv: list[str]) -> int:
    split = argv.index("--")
    events_path, channel, scenario_name, duration = argv[:split]
    railgw_args = argv[split + 1:]
    sock_dir = tempfile.mkdtemp(prefix="railgw-notify-")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(os.path.join(sock_dir, "notify"))
    notify.settimeout(0.2)
    os.environ["NOTIFY_SOCKET"] = os.path.join(sock_dir, "notify")
    # only the installed package: nothing of the source tree may be importable here
    from firmware_sim.output import send_live
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation
    from gateway.can.bus import open_bus, open_node_bus
    from gateway.can.codec import default_codec
    from gateway.errors import FrameError

    lock = threading.Lock()
    out = open(events_path, "a", buffering=1, encoding="utf-8")  # noqa: SIM115

    def emit(obj: dict[str, Any]) -> None:
        with lock:
            out.write(json.dumps(obj) + "\n")

    import gateway
    emit({"event": "start", "gateway_file": gateway.__file__, "pid": os.getpid()})
    stop = threading.Event()
    ready = threading.Event()

    def read_notify() -> None:
        while not stop.is_set():
            try:
                text = notify.recv(4096).decode("utf-8", "replace")
            except TimeoutError:
                continue
            except OSError:
                return
            emit({"event": "notify", "text": text})
            if "READY=1" in text.split("\n"):
                ready.set()

    def monitor() -> None:
        codec = default_codec()
        with open_bus(f"virtual:{channel}") as bus:
            while not stop.is_set():
                msg = bus.recv(timeout=0.1)
                if msg is None or msg.arbitration_id < 0x300:
                    continue
                try:
                    frame = codec.decode_message(msg)
                except FrameError as err:
                    emit({"event": "bad_frame", "id": msg.arbitration_id, "error": str(err)})
                    continue
                emit({"event": "frame", "message": frame.message,
                      "values": {k: float(v) for k, v in frame.values.items()}})

    def simulate() -> None:
        while not ready.wait(0.2):
            if stop.is_set():
                return
        sim = Simulation(get_scenario(scenario_name), SimConfig(duration_s=float(duration),
                                                                seed=7))
        with open_node_bus(f"virtual:{channel}") as tx:
            n = send_live(sim.messages(), tx, stop=stop.is_set)
        emit({"event": "sim_done", "frames": n})

    threads = [threading.Thread(target=f, daemon=True, name=f.__name__)
               for f in (read_notify, monitor, simulate)]
    for t in threads:
        t.start()
    script = Path(sys.executable).parent / "railgw"
    sys.argv = [str(script), *railgw_args]
    code: object = 0
    try:
        runpy.run_path(str(script), run_name="__main__")
    except SystemExit as exc:
        code = exc.code
    stop.set()
    for t in threads:
        t.join(timeout=2.0)
    status = code if isinstance(code, int) else (0 if code is None else 1)
    emit({"event": "exit", "code": status})
    notify.close()
    out.close()
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
