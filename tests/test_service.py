"""The live service on python-can's virtual bus: frames out, worker crash, SIGTERM, SIGKILL."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import open_bus, open_node_bus
from gateway.can.codec import default_codec
from gateway.config import Config, with_overrides
from gateway.errors import FrameError
from gateway.service.daemon import Service

ROOT = Path(__file__).resolve().parent.parent


def _wait(cond, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


class Running:
    """A Service in a thread on its own virtual channel, with a frame recorder."""

    def __init__(self, tmp_path: Path, name: str, particles: int = 200,
                 overrides: dict[str, object] | None = None) -> None:
        self.channel = f"svc-{name}-{time.monotonic_ns()}"
        cfg = with_overrides(Config(), {
            "bus.interface": "virtual", "bus.channel": self.channel,
            "state.directory": str(tmp_path / "state"), "estimator.particles": particles,
            "estimator.checkpoint_interval_s": 1.0, **(overrides or {})})
        self.service = Service(cfg)
        self.frames: list[can.Message] = []
        self._rx = open_bus(f"virtual:{self.channel}")
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self.service.run, daemon=True),
                         threading.Thread(target=self._record, daemon=True)]

    def _record(self) -> None:
        while not self._stop.is_set():
            msg = self._rx.recv(0.1)
            if msg is not None and msg.arbitration_id >= 0x300:
                self.frames.append(msg)

    def __enter__(self) -> Running:
        for t in self._threads:
            t.start()
        assert self.service.source.opened.wait(10)
        # what READY=1 tells systemd: the worker runs (before that, samples only queue)
        assert _wait(lambda: self.service.pipeline is not None
                     and self.service.pipeline.worker.stats.ready, 120)
        return self

    def play(self, scenario: str, duration_s: float, seed: int = 5) -> threading.Thread:
        sim = Simulation(get_scenario(scenario), SimConfig(duration_s=duration_s, seed=seed))

        def go() -> None:
            with open_node_bus(f"virtual:{self.channel}") as tx:
                send_live(sim.messages(), tx)

        t = threading.Thread(target=go, daemon=True)
        t.start()
        return t

    def decoded(self, message: str) -> list[dict[str, float]]:
        codec = default_codec()
        out = []
        for m in list(self.frames):
            try:
                f = codec.decode_message(m)
            except FrameError:
                continue
            if f.message == message:
                out.append(f.values)
        return out

    def __exit__(self, *exc: object) -> None:
        self.service.flags.stop = True
        self._threads[0].join(timeout=10)
        self._stop.set()
        self._threads[1].join(timeout=2)
        self._rx.shutdown()


def test_frames_come_back_with_e2e_and_health(tmp_path):
    with Running(tmp_path, "frames") as run:
        run.play("nominal", 6.0).join()
        assert _wait(lambda: len(run.decoded("GW_EstCsy")) >= 5, 60)
        time.sleep(1.5)
    codec = default_codec()
    for m in run.frames:
        codec.decode_message(m)                     # every frame of ours passes E2E
    est = run.decoded("GW_EstCsy")
    assert all(0 < v["GW_EstCsy_Mean"] < 131_000 for v in est)
    health = run.decoded("GW_Health")
    assert len(health) >= 3
    assert health[-1]["GW_Health_FramesRx"] > 0
    assert {v["GW_Health_BusState"] for v in health} == {0}


def test_start_time_out_is_extended_until_the_worker_is_up(tmp_path, monkeypatch):
    """A cold numba cache makes the worker's first start take minutes, longer than the
    unit's TimeoutStartSec: the service extends the start time-out until READY=1."""
    path = str(tmp_path / "notify")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    server.settimeout(120)
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    got: list[dict[str, str]] = []

    def read() -> None:                 # at once: the datagram queue holds only ~10
        while not any(m.get("READY") == "1" for m in got):
            text = server.recv(4096).decode()
            got.append(dict(line.split("=", 1) for line in text.splitlines()))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    with Running(tmp_path, "extend"):
        reader.join(timeout=120)
    server.close()
    first_ready = next(k for k, m in enumerate(got) if m.get("READY") == "1")
    extends = [m for m in got[:first_ready] if "EXTEND_TIMEOUT_USEC" in m]
    assert extends, got
    assert all(int(m["EXTEND_TIMEOUT_USEC"]) == 30_000_000 for m in extends)
    assert "warming up" in extends[0]["STATUS"]
    # Nothing overwrites the warm-up STATUS before READY (systemctl status shows it).
    statuses = [m["STATUS"] for m in got[:first_ready] if "STATUS" in m]
    assert all("warming up" in st for st in statuses), statuses


@pytest.mark.serial
def test_worker_sigkill_resumes_from_checkpoint_within_2_s(tmp_path):
    with Running(tmp_path, "kill") as run:
        sender = run.play("nominal", 20.0)
        svc = run.service
        assert _wait(lambda: svc.pipeline is not None and svc.pipeline.worker.stats.checkpoints
                     >= 2, 90)
        worker = svc.pipeline.worker
        before = worker.stats.estimates
        os.kill(worker.pid, signal.SIGKILL)
        t_kill = time.monotonic()
        assert _wait(lambda: worker.stats.restarts == 1, 5)
        assert _wait(lambda: worker.stats.estimates > before + 1, 10)
        resumed_s = time.monotonic() - t_kill
        sender.join()
    assert resumed_s < 2.0, f"resumed after {resumed_s:.2f} s"
    assert worker.stats.restarts == 1


def _demo(state: Path, scenario: str, duration_s: float, log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "gateway", "-v", "demo", "--scenario", scenario, "--duration",
         str(duration_s), "--particles", "200", "--state-dir", str(state)],
        cwd=ROOT, stdout=open(log, "w"), stderr=subprocess.STDOUT)


def test_the_demo_runs_the_services_particle_count() -> None:
    """The README's first command shows the product as it ships: the paper's m = 1000,
    the service's default (issue 14), not a lighter filter of its own."""
    from gateway.cli import build_parser

    args = build_parser(["demo"]).parse_args(["demo"])
    assert args.particles == Config().estimator.particles == 1000


@pytest.mark.serial
def test_sigterm_stops_cleanly_within_5_s_and_restart_resumes(tmp_path):
    state = tmp_path / "state"
    proc = _demo(state, "nominal", 120, tmp_path / "one.log")
    try:
        assert _wait(lambda: (state / "checkpoint.bin").exists(), 120)
        stamp = (state / "checkpoint.bin").stat().st_mtime_ns
        proc.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        assert proc.wait(timeout=10) == 0
        assert time.monotonic() - t0 < 5.0
    finally:
        proc.kill()
    assert (state / "checkpoint.bin").stat().st_mtime_ns > stamp    # final checkpoint
    proc = _demo(state, "nominal", 120, tmp_path / "two.log")
    try:
        assert _wait(lambda: "resuming the estimator" in (tmp_path / "two.log").read_text(), 60)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)


@pytest.mark.slow
def test_sigkill_of_the_service_loses_no_alert(tmp_path):
    state = tmp_path / "state"
    proc = _demo(state, "lateral-failing", 60, tmp_path / "one.log")
    alerts = state / "alerts.jsonl"
    try:
        assert _wait(lambda: alerts.exists() and '"RAISED"' in alerts.read_text().upper(), 120)
        time.sleep(0.5)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    before = [json.loads(x) for x in alerts.read_text().splitlines() if x.strip()]
    proc = _demo(state, "nominal", 20, tmp_path / "two.log")
    try:
        assert _wait(lambda: "resuming the estimator" in (tmp_path / "two.log").read_text(), 60)
        time.sleep(3)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=15)
    after = [json.loads(x) for x in alerts.read_text().splitlines() if x.strip()]
    assert after[: len(before)] == before                    # nothing lost or rewritten
    seqs = [a["seq"] for a in after]
    raised = [a["seq"] for a in after if a["state"] == "RAISED"]
    assert len(set(raised)) == len(raised)                   # nothing raised twice
    assert all(b >= a for a, b in zip(seqs, seqs[1:], strict=False))   # seq survives restart
    policy = json.loads((state / "alert_policy.json").read_text())
    assert policy                                            # restored and saved again


def _last(run: Running, message: str, signal_name: str) -> float:
    values = run.decoded(message)
    assert values, f"no {message} frame came back"
    return values[-1][signal_name]


@pytest.mark.slow
def test_live_estimates_reach_the_estimator_accuracy_on_the_paper_scenario(tmp_path):
    """Simulator -> virtual bus -> service -> estimate frames read back: the paper's Sec. 4.2
    vehicle, 3 sensors, 5 s of data, the service's default particle count; within 10 %
    (the estimator issue's 3-sensor target), as decoded from our own frames."""
    with Running(tmp_path, "paper", particles=Config().estimator.particles) as run:
        run.play("paper", 5.0, seed=0).join()
        svc = run.service
        # the worker has consumed the whole run once it estimates past the end of the
        # data: the grid goes on as a marked gap, where the filter predicts only and the
        # parameter estimates stay put
        assert _wait(lambda: _predicting_only(svc), 90)
        time.sleep(0.5)                               # the last 10 Hz frames go out
        stats = svc.pipeline.stats()
    truth = {"GW_EstCsy": 20e3, "GW_EstCsay": 3000e3, "GW_EstConicity": 0.15}
    for message, value in truth.items():
        mean = _last(run, message, f"{message}_Mean")
        # the pipeline's counters say whether the worker kept up (samples dropped at its
        # queue leave gaps the filter bridges by prediction: less data, wider posterior)
        assert abs(mean / value - 1) < 0.10, (message, mean, value, stats)


def _predicting_only(svc: Service) -> bool:
    last = svc.pipeline.last_estimate if svc.pipeline is not None else None
    return last is not None and not last.updated


@pytest.mark.slow
def test_live_failed_lateral_damper_raises_an_alarm_frame_within_15_s(tmp_path):
    """lateral-failing on the live bus: Csy steps 40 -> 10 kNs/m at half-time; an ALARM
    frame for Csy comes back within 15 s of the step (sender clock), none before it.
    250 particles: the worker must keep up in real time for 40 s on a CI machine that may
    be busy (500, the default, keeps up on an idle 2-core machine: README, latency)."""
    duration_s = 40.0
    with Running(tmp_path, "alarm", particles=250) as run:
        t_start = time.time()
        run.play("lateral-failing", duration_s, seed=5).join()
        t_fail = t_start + duration_s / 2
        assert _wait(lambda: _alarm_frames(run), 20)
    codec = default_codec()
    alerts = [(m.timestamp, codec.decode_message(m).values) for m in list(run.frames)
              if m.arbitration_id == codec.message("GW_Alert").frame_id]
    assert all(t > t_fail for t, _ in alerts), alerts          # nothing before the fault
    first = _alarm_frames(run)[0]
    assert 0.0 < first.timestamp - t_fail <= 15.0, first.timestamp - t_fail


def _alarm_frames(run: Running) -> list[can.Message]:
    codec = default_codec()
    out = []
    for m in list(run.frames):
        if m.arbitration_id != codec.message("GW_Alert").frame_id:
            continue
        v = codec.decode_message(m).values
        if v["GW_Alert_Param"] == 0 and v["GW_Alert_Severity"] == 3 and v["GW_Alert_State"] == 0:
            out.append(m)
    return out


@pytest.mark.soak
@pytest.mark.skipif(os.environ.get("RAILGW_SOAK") != "1",
                    reason="10 real-time minutes: opt-in with RAILGW_SOAK=1 (CI checks the "
                           "same pipeline on 10 simulated minutes under replay)")
def test_live_ten_nominal_minutes_raise_no_alert_frame(tmp_path):
    with Running(tmp_path, "soak", particles=Config().estimator.particles) as run:
        run.play("nominal", 600.0, seed=11).join()
        time.sleep(5.0)
        # estimates throughout (10 Hz when the worker keeps up; on a busy machine it
        # falls behind, drops samples at its queue and sends fewer)
        assert len(run.decoded("GW_EstCsy")) > 1000
        assert run.decoded("GW_Alert") == []


# ------------------------------------------------- receive filters, health flags, hygiene
def test_the_service_bus_delivers_only_the_dbc_sensor_ids(tmp_path):
    """The bus the service opens carries the DBC's receive filters (kernel filters on
    SocketCAN, tests/vcan; python-can's software filter here on ``virtual``): a flood of
    foreign ids never reaches the source's queue, so never the decode path."""
    channel = f"filters-{time.monotonic_ns()}"
    cfg = with_overrides(Config(), {"bus.interface": "virtual", "bus.channel": channel,
                                    "state.directory": str(tmp_path / "state")})
    svc = Service(cfg)
    codec = default_codec()
    assert sorted(f["can_id"] for f in svc.rx_filters) == sorted(codec.sensor_ids())
    speed = codec.encode_message("VEH_Speed", {"VEH_Speed_SampleIdx": 1, "VEH_Speed": 42.5,
                                               "VEH_Odometer": 0.0}, 1)
    sensors = set(codec.sensor_ids())
    foreign = [i for i in range(0x800) if i not in sensors]
    svc.source.start()
    try:
        assert svc.source.opened.wait(10)
        with open_bus(f"virtual:{channel}") as tx:
            for i in foreign:
                tx.send(can.Message(arbitration_id=i, data=bytes(8), is_extended_id=False))
            for i in sensors:                       # 29-bit ids with a sensor's low bits
                tx.send(can.Message(arbitration_id=0x1000000 | i, data=bytes(8)))
            tx.send(speed)                          # the end marker: a sensor frame
        assert _wait(lambda: svc.source.stats.frames_rx >= 1, 10)
        got = [svc.source.get(1.0)]
        assert svc.source.get() is None
    finally:
        svc.close()
    assert [(m.arbitration_id, bytes(m.data)) for m in got if m] == \
        [(speed.arbitration_id, bytes(speed.data))]
    assert svc.source.stats.frames_rx == 1          # of 2048 + 4 frames sent


def refuse_nice(increment: int) -> int:
    """os.nice under a seccomp filter that denies setpriority (pickled to the worker)."""
    raise PermissionError(1, "Operation not permitted")


def test_a_worker_priority_not_applied_shows_in_health_frame_status_and_journal(
        tmp_path, monkeypatch, caplog):
    import dataclasses

    import gateway.runtime.pipeline
    from gateway.service.daemon import status_line

    real = gateway.runtime.pipeline.worker_settings
    monkeypatch.setattr(gateway.runtime.pipeline, "worker_settings",
                        lambda cfg: dataclasses.replace(real(cfg), lower_priority=refuse_nice))
    caplog.set_level(logging.WARNING, logger="gateway.runtime.worker")
    with Running(tmp_path, "nice", particles=32) as run:       # the worker is up
        n0 = len(run.decoded("GW_HealthFlags"))
        assert _wait(lambda: len(run.decoded("GW_HealthFlags")) >= n0 + 2, 10)
        flags = run.service.health_flags()
    last = run.decoded("GW_HealthFlags")[-1]
    assert last["GW_HealthFlags_PriorityNotApplied"] == 1
    assert last["GW_HealthFlags_StateQuarantined"] == 0
    assert last["GW_HealthFlags_PersistFailing"] == 0
    assert flags.names() == ["priority-not-applied"]
    assert status_line(None, 0, "ERROR_ACTIVE", 1.0, flags.names()).endswith(
        "; flags priority-not-applied")
    assert any("runs at the service's priority" in r.getMessage() for r in caplog.records)


def test_health_flags_are_clear_when_the_priority_is_lowered(tmp_path):
    with Running(tmp_path, "nice-ok", particles=32) as run:    # the worker is up
        n0 = len(run.decoded("GW_HealthFlags"))
        assert _wait(lambda: len(run.decoded("GW_HealthFlags")) >= n0 + 2, 10)
        assert run.service.pipeline is not None
        assert run.service.pipeline.worker.stats.priority_error == ""
    last = run.decoded("GW_HealthFlags")[-1]
    assert last["GW_HealthFlags_PriorityNotApplied"] == 0


class GatewayRun:
    """``python -m gateway run`` in its own process group, with a NOTIFY_SOCKET of ours."""

    def __init__(self, tmp_path: Path) -> None:
        self.state = tmp_path / "state"
        self._notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._notify.bind(str(tmp_path / "notify"))
        self.stderr_path = tmp_path / "stderr.log"
        self._stderr = self.stderr_path.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "gateway", "run", "--bus", f"virtual:run-{os.getpid()}",
             "--state-dir", str(self.state), "--particles", "32"],
            cwd=ROOT, env=dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify")),
            stdout=subprocess.DEVNULL, stderr=self._stderr,
            start_new_session=True)

    def wait_ready(self, timeout_s: float = 180) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and self.proc.poll() is None:
            self._notify.settimeout(1.0)
            try:
                if b"READY=1" in self._notify.recv(4096).split(b"\n"):
                    return True
            except TimeoutError:
                continue
        return False

    def children(self) -> list[int]:
        """Pids of the gateway's child processes (workers, multiprocessing's tracker)."""
        out: list[int] = []
        for task in Path(f"/proc/{self.proc.pid}/task").iterdir():
            with contextlib.suppress(OSError):
                out += [int(p) for p in (task / "children").read_text().split()]
        return out

    def close(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)
        self._notify.close()
        self._stderr.close()


def _gone(pid: int) -> bool:
    """No such process, or a zombie (dead, waiting for whoever adopted it to reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def test_workers_die_with_a_killed_gateway(tmp_path):
    run = GatewayRun(tmp_path)
    try:
        assert run.wait_ready(), run.stderr_path.read_text()
        workers = run.children()
        assert len(workers) >= 2, workers               # the worker and its warm spare
        os.kill(run.proc.pid, signal.SIGKILL)
        run.proc.wait(10)
        assert _wait(lambda: all(_gone(p) for p in workers), 10), \
            [p for p in workers if not _gone(p)]
    finally:
        run.close()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_the_process_group_stops_cleanly_with_a_final_checkpoint(tmp_path, sig):
    """Ctrl-C in a terminal (SIGINT to the foreground process group), or ``kill -TERM
    -PGID``: the workers get it too, ignore it, and the parent stops them as for SIGTERM
    to itself alone: exit 0, no traceback, the final checkpoint written."""
    run = GatewayRun(tmp_path)
    try:
        assert run.wait_ready(), run.stderr_path.read_text()
        workers = run.children()
        assert not (run.state / "checkpoint.bin").exists()  # no data yet: none periodic
        os.killpg(run.proc.pid, sig)
        assert run.proc.wait(15) == 0
        stderr = run.stderr_path.read_text()
        assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
        assert (run.state / "checkpoint.bin").stat().st_size > 0
        assert _wait(lambda: all(_gone(p) for p in workers), 10)
    finally:
        run.close()


def test_a_quarantined_state_file_raises_its_health_flag_and_status(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    (state / "alert_policy.json").write_text("{not json")
    cfg = with_overrides(Config(), {"bus.interface": "virtual",
                                    "bus.channel": f"q-{time.monotonic_ns()}",
                                    "state.directory": str(state)})
    svc = Service(cfg)
    try:
        flags = svc.health_flags()
    finally:
        svc.close()
    assert flags.state_quarantined and flags.names() == ["state-quarantined"]
    assert list(state.glob("alert_policy.json.corrupt-*"))


@pytest.mark.parametrize(("before", "after", "said"), [
    ({}, {"estimator.sensors": 5}, "sensors 3 -> 5"),
    ({"estimator.sensor_noise": "model"}, {},
     "sensor_noise 'model' -> 'measured' (its variances never tested)"),
], ids=["another sensor set", "model noise, then measured"])
def test_a_restart_with_other_estimator_settings_starts_a_fresh_estimator(tmp_path, before, after,
                                                                      said):
    """A checkpoint of the 3-sensor estimator, then a restart configured for 5 sensors:
    the service sets the checkpoint aside (kept, named in the health's problems) and
    estimates with a fresh 5-sensor filter, whose frames come off the bus. Before, the
    restored 3-sensor filter refused every 5-sensor sample: three worker deaths, and the
    service stopped (systemd would start it on the same checkpoint again). The same for
    a switch from the model's sensor noise to measured noise: before, the restored filter
    went on with variances it had never tested."""
    state = tmp_path / "state"
    with Running(tmp_path, "first", overrides=before) as run:
        run.play("nominal", 3.0).join()
        assert _wait(lambda: (state / "checkpoint.bin").exists(), 60)
    old = (state / "checkpoint.bin").read_bytes()
    with Running(tmp_path, "second", overrides=after) as run:
        run.play("nominal", 3.0)
        assert _wait(lambda: len(run.decoded("GW_EstCsy")) >= 5, 60)
        svc = run.service
        assert svc.pipeline is not None and svc.pipeline.worker.stats.restarts == 0
        assert svc.health_flags().state_quarantined
        assert any(said in p and "starts fresh" in p for p in svc.store.problems), \
            svc.store.problems
    assert (state / "checkpoint.bin.corrupt-1").read_bytes() == old
