"""A simulated vehicle on the bus: truth -> nodes -> faults -> timestamped CAN frames.

:class:`Simulation` produces the frames of a scenario block by block (explicit state,
bounded memory), in bus order. It does no I/O: senders and log writers consume it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import can
import numpy as np

from firmware_sim.nodes import (
    FRAME_TIME_S,
    NODE_BY_NAME,
    NODES,
    SAMPLE_INDEX_MODULUS,
    FramePacker,
    NodeClock,
    NodeSpec,
    NodeState,
    counters_from,
    default_latency,
)
from firmware_sim.scenarios import Fault, Scenario
from firmware_sim.truth import NonlinearDampers, simulate
from gateway.can.codec import default_codec
from gateway.model.vehicle import AR_PAPER_DEFAULT, SENSOR_NOISE_VAR, SENSORS_5, VehicleParams


@dataclass(frozen=True)
class SimConfig:
    """Settings of a simulated run; ``seed`` makes the whole run reproducible."""

    duration_s: float
    seed: int = 0
    truth_fs_hz: float = 4000.0
    ar_paper: float = AR_PAPER_DEFAULT
    nonlinear_dampers: bool = False
    max_drift_ppm: float = 50.0
    t0_s: float = 0.0
    block_s: float = 1.0
    nodes: tuple[str, ...] = ("WSN", "BGN", "BDN", "VEH")
    noise_scale: float = 1.0
    """Sensor noise std relative to the paper's Qv (``SENSOR_NOISE_VAR``)."""
    noise_by_sample: bool = False
    """Each node draws its sensor noise from its own stream, one row per sample number,
    so a sample's noise does not depend on any node's clock: runs that differ only in
    their node clocks (phase, drift) carry the same noise on the same sample. False (the
    default, and every run before 2026-11-29's tenth session) draws from one stream that
    all nodes share in block order, so a drift, which changes how many samples a block
    holds, draws another noise realisation."""
    second_sender: str | None = None
    """A second node sending the same message as this one (a masquerader with valid CRCs,
    its own clock, alive counter and SampleIdx ``second_sender_idx_offset`` ahead, values
    x ``second_sender_gain``); it is named ``<node>2`` in ``records``."""
    second_sender_gain: float = 1.5
    second_sender_idx_offset: int = 20_000
    second_sender_window_s: tuple[float, float] = (0.0, float("inf"))
    """The second sender sends only in [start, stop), s."""


@dataclass
class NodeRecord:
    """What one node sent (for tests): sample indices, true times and physical values."""

    sample_idx: list[np.ndarray] = field(default_factory=list)
    t_true_s: list[np.ndarray] = field(default_factory=list)
    values: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def array(self, name: str) -> np.ndarray:
        """Concatenated values of one quantity (sensor name), shape (n,)."""
        return np.concatenate(self.values[name]) if self.values.get(name) else np.empty(0)


class Simulation:
    """Frames of a scenario, in bus order. Iterate :meth:`messages` or :meth:`blocks`."""

    def __init__(self, scenario: Scenario, config: SimConfig,
                 params: VehicleParams | None = None, record: bool = False) -> None:
        self.scenario = scenario
        self.config = config
        self.params = params or VehicleParams()
        codec = default_codec()
        seeds = np.random.SeedSequence(config.seed).spawn(5)
        self._rng_truth, self._rng_noise, self._rng_bus, rng_clock = (
            np.random.default_rng(s) for s in seeds[:4])
        self.nodes: list[NodeSpec] = [n for n in NODES if n.node in config.nodes]
        self._idx_offset: dict[str, int] = {}
        self._gain: dict[str, float] = {}
        if config.second_sender is not None:
            twin = NODE_BY_NAME[config.second_sender]
            rogue = NodeSpec(f"{twin.node}2", twin.message, twin.signals, twin.period_s)
            self.nodes.append(rogue)
            self._idx_offset[rogue.node] = config.second_sender_idx_offset
            self._gain[rogue.node] = config.second_sender_gain
        self.clocks = {n.node: NodeClock(
            drift_ppm=float(rng_clock.uniform(-1, 1) * config.max_drift_ppm),
            phase_s=float(rng_clock.uniform(0, n.period_s))) for n in self.nodes}
        self.packers = {}
        for n in self.nodes:
            self.packers[n.node] = FramePacker(codec.cantools_message(n.message),
                                               codec.message(n.message).data_id)
        self.states = {n.node: NodeState() for n in self.nodes}
        self._rng_node_noise = {n.node: np.random.default_rng(s) for n, s in
                                zip(self.nodes, seeds[4].spawn(len(self.nodes)), strict=True)}
        self.records = {n.node: NodeRecord() for n in self.nodes} if record else None
        self._stuck: dict[str, dict[str, float]] = {}
        self._frozen: dict[str, int] = {}
        self._odometer_m = 0.0

    def messages(self) -> Iterator[can.Message]:
        """All frames of the run in timestamp order."""
        for block in self.blocks():
            yield from block

    def blocks(self) -> Iterator[list[can.Message]]:
        """The frames in blocks of about ``block_s``, each sorted by timestamp."""
        cfg = self.config
        fs = cfg.truth_fs_hz
        n_total = int(round(cfg.duration_s * fs))
        per_block = max(1, int(round(cfg.block_s * fs)))
        x0 = None
        held: list[tuple[float, int, can.Message]] = []
        for i0 in range(0, n_total, per_block):
            i1 = min(i0 + per_block, n_total)
            t_grid = np.arange(i0, i1 + 1) / fs
            theta = self.scenario.theta(t_grid, cfg.duration_s)
            speed = self.scenario.speed(t_grid, cfg.duration_s)
            truth = simulate(theta, speed, fs, self._rng_truth, params=self.params,
                             ar_paper=cfg.ar_paper, x0=x0,
                             dampers=NonlinearDampers() if cfg.nonlinear_dampers else None)
            x0 = truth.states[-1]
            frames = held
            for node in self.nodes:
                frames.extend(self._node_frames(node, t_grid, truth.outputs, speed, cfg))
            frames.sort(key=lambda f: (f[0], f[1]))
            t_cut = i1 / fs if i1 < n_total else np.inf
            ready = [f for f in frames if f[0] < t_cut]
            held = [f for f in frames if f[0] >= t_cut]
            yield [f[2] for f in ready]
        if held:
            yield [f[2] for f in held]

    def _node_frames(self, node: NodeSpec, t_grid: np.ndarray, outputs: np.ndarray,
                     speed: np.ndarray, cfg: SimConfig) -> list[tuple[float, int, can.Message]]:
        clock, state = self.clocks[node.node], self.states[node.node]
        packer = self.packers[node.node]
        k = clock.samples_in(t_grid[0], t_grid[-1], node.period_s)
        k = k[k >= state.next_k]
        if len(k) == 0:
            return []
        state.next_k = int(k[-1]) + 1
        t_true = clock.sample_time_s(k, node.period_s)
        values: dict[str, np.ndarray] = {}
        sensed = [q for q, _signal in node.signals if q in SENSORS_5]
        unit: dict[str, np.ndarray] = {}
        if cfg.noise_by_sample:      # row i: sample k[i], whatever the blocks hold
            rows = self._rng_node_noise[node.node].standard_normal((len(k), len(sensed)))
            unit = dict(zip(sensed, rows.T, strict=True))
        for quantity, _signal in node.signals:
            if quantity in SENSORS_5:
                col = SENSORS_5.index(quantity)
                clean = np.interp(t_true, t_grid, outputs[:, col])
                std = float(np.sqrt(SENSOR_NOISE_VAR[quantity])) * cfg.noise_scale
                draw = (unit[quantity] if cfg.noise_by_sample
                        else self._rng_noise.standard_normal(len(k)))
                values[quantity] = clean * self._gain.get(node.node, 1.0) + draw * std
            elif quantity == "speed":
                values[quantity] = np.interp(t_true, t_grid, speed)
                step_m = values[quantity] * node.period_s
                values["odometer"] = self._odometer_m + np.cumsum(step_m)
                self._odometer_m = float(values["odometer"][-1])
        counters = counters_from(state, len(k))
        keep = np.ones(len(k), dtype=bool)
        if node.node in self._idx_offset:
            start_s, stop_s = cfg.second_sender_window_s
            keep &= (t_true >= start_s) & (t_true < stop_s)
        bad_crc = np.zeros(len(k), dtype=bool)
        # a node's transmit queue is FIFO: its frames never overtake each other
        t_bus = np.maximum.accumulate(np.maximum(
            t_true + default_latency(self._rng_bus, len(k)), state.last_bus_s + FRAME_TIME_S))
        state.last_bus_s = float(t_bus[-1])
        latency = t_bus - t_true
        for fault in self.scenario.faults:
            if fault.node == node.node:
                inside = ((t_true >= fault.start_frac * cfg.duration_s)
                          & (t_true < fault.stop_frac * cfg.duration_s))
                if inside.any():
                    self._apply(fault, node, inside, values, counters, keep, bad_crc, latency)
        if self.records is not None:
            rec = self.records[node.node]
            rec.sample_idx.append(k[keep] % SAMPLE_INDEX_MODULUS)
            rec.t_true_s.append(t_true[keep])
            for q, v in values.items():
                rec.values.setdefault(q, []).append(v[keep])
        raws = {signal: packer.raw(signal, values[q]) for q, signal in node.signals}
        idx_signal = f"{node.message}_SampleIdx"
        raws[idx_signal] = (k + self._idx_offset.get(node.node, 0)) % SAMPLE_INDEX_MODULUS
        payloads = packer.pack({s: r[keep] for s, r in raws.items()}, counters[keep])
        t_bus = (t_true + latency)[keep]
        out = []
        arb = packer.message.frame_id
        for t, payload, corrupt in zip(t_bus, payloads, bad_crc[keep], strict=True):
            if corrupt:
                payload = bytes([payload[0] ^ 0x5A]) + payload[1:]
            msg = can.Message(timestamp=cfg.t0_s + float(t), arbitration_id=arb,
                              is_extended_id=False, dlc=8, data=payload)
            out.append((float(t), arb, msg))
        return out

    def _apply(self, fault: Fault, node: NodeSpec, inside: np.ndarray,
               values: dict[str, np.ndarray], counters: np.ndarray, keep: np.ndarray,
               bad_crc: np.ndarray, latency: np.ndarray) -> None:
        """Inject one fault into the frames of ``node`` where ``inside`` is True."""
        sensors = [q for q, _ in node.signals if q in SENSORS_5]
        if fault.kind == "stuck":
            held = self._stuck.setdefault(node.node, {
                q: float(values[q][np.argmax(inside)]) for q in sensors})
            for q in sensors:
                values[q][inside] = held[q]
        elif fault.kind == "dropout":
            keep[inside] = False
        elif fault.kind == "noise_burst":
            for q in sensors:
                std = float(np.sqrt(SENSOR_NOISE_VAR[q]))
                values[q][inside] += self._rng_noise.standard_normal(int(inside.sum())) * 20 * std
        elif fault.kind == "frozen_counter":
            frozen = self._frozen.setdefault(node.node, int(counters[np.argmax(inside)]))
            counters[inside] = frozen
        elif fault.kind == "bad_crc":
            bad_crc[inside] = True
        elif fault.kind == "out_of_order":
            idx = np.nonzero(inside)[0]
            pairs = idx[: len(idx) // 2 * 2].reshape(-1, 2)
            if len(pairs):
                # the later sample reaches the bus first: a late frame overtaken by the next
                latency[pairs[:, 0]] += 1.5 * node.period_s
        else:  # pragma: no cover - scenarios only use FAULT_KINDS
            raise ValueError(fault.kind)
