"""Playback of an interchange CSV: the frames the sensor nodes would have sent for it.

Each row becomes one frame per node whose columns are present: the bogie node
(``bogie_lat_acc_mps2``, ``bogie_yaw_rate_radps``), the body node, the wheelset node
when both wheelset columns exist, and the vehicle node every 10 ms of data time when
``speed_mps`` exists. A node's sample index is the row time in its own sample periods
(``round((t - t_first) / period)``), so uneven CSV times survive as the receiver's
reconstructed times. An empty cell is sent as the signal's "not available" raw value.
Values outside a signal's range saturate at its limit, as a real sensor does.
"""

from __future__ import annotations

from collections.abc import Iterator

import can
import numpy as np

from firmware_sim.nodes import (
    NODE_BY_NAME,
    SAMPLE_INDEX_MODULUS,
    FramePacker,
    NodeSpec,
    NodeState,
    counters_from,
    default_latency,
)
from gateway.can.codec import default_codec
from gateway.errors import InputError
from gateway.offline.interchange import Recording


def _na_raw(packer: FramePacker, signal: str) -> int:
    sig = packer.message.get_signal_by_name(signal)
    for raw, name in (sig.choices or {}).items():
        if str(name) == "NotAvailable":
            return int(raw)
    raise InputError(f"expected a NotAvailable value for {signal} in the DBC, got none")


def playback_frames(rec: Recording, *, seed: int = 0, t0_s: float = 0.0) -> Iterator[can.Message]:
    """All frames for a recording, in bus (timestamp) order."""
    codec = default_codec()
    rng = np.random.default_rng(seed)
    nodes: list[NodeSpec] = [NODE_BY_NAME["BGN"], NODE_BY_NAME["BDN"]]
    if "acc_w1" in rec.signals and "acc_w2" in rec.signals:
        nodes.insert(0, NODE_BY_NAME["WSN"])
    if "speed" in rec.signals:
        nodes.append(NODE_BY_NAME["VEH"])
    t = rec.t_s - rec.t_s[0]
    frames: list[tuple[float, int, can.Message]] = []
    for node in nodes:
        msg = codec.cantools_message(node.message)
        packer = FramePacker(msg, codec.message(node.message).data_id)
        idx = np.rint(t / node.period_s).astype(np.int64)
        rows = np.nonzero(np.diff(np.concatenate([[-1], idx])) > 0)[0]  # one frame per index
        values: dict[str, np.ndarray] = {}
        for quantity, _signal in node.signals:
            if quantity == "odometer":
                speed = np.nan_to_num(rec.signals["speed"])
                dist = np.concatenate([[0.0], np.cumsum(np.diff(t) * speed[1:])])
                values[quantity] = dist[rows]
            else:
                values[quantity] = rec.signals[quantity][rows]
        raws = {}
        for quantity, signal in node.signals:
            v = values[quantity]
            raw = packer.raw(signal, np.nan_to_num(v))
            raw[np.isnan(v)] = _na_raw(packer, signal)
            raws[signal] = raw
        raws[f"{node.message}_SampleIdx"] = idx[rows] % SAMPLE_INDEX_MODULUS
        payloads = packer.pack(raws, counters_from(NodeState(), len(rows)))
        t_bus = t[rows] + default_latency(rng, len(rows))
        for tb, payload in zip(t_bus, payloads, strict=True):
            frames.append((float(tb), msg.frame_id,
                           can.Message(timestamp=t0_s + float(tb), arbitration_id=msg.frame_id,
                                       is_extended_id=False, dlc=8, data=payload)))
    frames.sort(key=lambda f: (f[0], f[1]))
    for f in frames:
        yield f[2]
