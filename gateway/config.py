"""The service configuration: one TOML file plus overrides, validated with line-precise errors.

Over 400 lines, on purpose: every key's default and domain in one table beside the
loader that reports file, line and key; split, one configuration would live in two places.

Every setting has a documented default (``systemd/railgw.example.toml`` lists them all).
Unknown sections or keys are errors (a typo must not silently fall back to a
default). Errors name the file, the line and the key, and carry exit status 78.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.errors import ConfigError


@dataclass(frozen=True)
class BusConfig:
    """Where the sensor traffic comes from and our frames go."""

    interface: str = "socketcan"
    channel: str = "can0"
    reopen_min_s: float = 0.2
    reopen_max_s: float = 10.0
    rx_queue_frames: int = 100_000
    rcvbuf_bytes: int = 4 * 1024 * 1024


@dataclass(frozen=True)
class ResamplerConfig:
    """The fixed-rate grid and the anti-alias low-passes (0 switches a filter off)."""

    fs_hz: float = 1000.0
    deadline_s: float = 0.2
    reorder_s: float = 0.02
    silent_s: float = 1.0
    lowpass_wheelset_acc_hz: float = 0.0
    lowpass_bogie_acc_hz: float = 0.0
    lowpass_gyro_hz: float = 0.0
    lowpass_body_acc_hz: float = 0.0
    interpolation: str = "sinc"


INTERPOLATIONS: tuple[str, ...] = ("sinc", "linear", "nearest")
"""How node samples become grid values (:mod:`gateway.frontend.resample`, "Values")."""


@dataclass(frozen=True)
class GatingConfig:
    """When the estimator may update: speed window and straight track."""

    speed_min_mps: float = 15.0
    speed_max_mps: float = 70.0
    curve_yaw_rate_max_radps: float = 0.01


@dataclass(frozen=True)
class EstimatorConfig:
    """The RBPF worker: particles, sensors, roughness, output and checkpoint cadence.

    The paper's 1000 particles by default, in fast mode (steady-state gains per particle,
    docs/estimator.md "Fast mode"); ``mode = "exact"`` runs the exact recursion, the
    reference, which on a 2-core gateway keeps up at about 500 particles. From 500
    particles on the first particles are drawn with the dampers from 0.1 x nominal, below
    from the paper's 0.3 x (:func:`gateway.estimator.rbpf_config.prior_lo_for`: with
    fewer particles the wider first draw locks more often; docs/estimator.md "The
    thirteenth session").
    ``drift_per_sqrt_s``: random-walk evolution of Csy, Csay and lambda (relative std per
    square root of second of updated data) so that the on-board filter follows a slow
    change; 0 is the paper's static-parameter filter (docs/estimator.md, "Drift").
    ``sensor_noise``: ``"measured"`` tests the model's sensor noise variances against the
    first 5 s of data and uses the measured ones where the data reject them
    (:mod:`gateway.estimator.noisestart`); ``"model"`` keeps the paper's Qv. "measured"
    needs white noise on the grid: the resampler's low-pass filters off, and its
    interpolation "sinc" or "nearest".
    ``start_ramp_s``: after every filter start, the data's weight on the particles rises
    from 0 to full over this much data (s), so that the vehicle's state at the start (at
    rest, or running) cannot pull the cloud onto a wrong value and the information comes
    in at a rate the particles can follow (docs/estimator.md "Calibration of the stated
    sigma"); 0 weighs every sample fully (the paper).
    ``start_ramp_m``: the ramp lasts at least this much track (m) at the speed of the
    first data: at 20 m/s the default 42.5 m is 2.1 s, at the paper's 42.5 m/s and above
    ``start_ramp_s`` rules (docs/estimator.md "The start's ramp in track distance"); 0
    keeps the ramp in seconds alone.
    ``kernel_delta``: the Liu-West discount per sample of the resample-moves' kernel;
    0 (the default) is auto: 0.999 from 250 particles on, the paper's 0.99 below
    (:func:`gateway.estimator.rbpf_config.kernel_delta_for`). The roughening floor is
    scaled to keep the cloud's floor at about 1 % of nominal
    (:func:`gateway.estimator.rbpf_config.floor_for_delta`). At 0.99 a move, compounded
    over the hundreds of samples between moves, re-draws nearly every particle afresh
    around the cloud's mean, and the estimate's Monte Carlo error is 0.3-0.9 of its
    stated sigma at m = 1000; at 0.999 it is about half that. With few particles the
    kernel must re-draw more to keep the cloud diverse: at m = 64, 0.999 is far worse
    (docs/estimator.md "The kernel's discount and the Monte Carlo error").
    ``queue_samples``: the grid samples the worker may be behind before samples are
    dropped (then one contiguous run, and the filters restart after it). A filter start
    runs fast mode's exact recursion over 2 s of data, which a slower gateway box works
    off slower than real time; by arithmetic, 20 s holds that start on a box where the
    exact recursion keeps a tenth of real time, 5 s only down to about 0.3 (computed,
    not measured on such a box: docs/reliability.md "Worker behind").
    """

    particles: int = 1000
    mode: str = "fast"
    sensors: int = 3
    seed: int = 0
    track_roughness: float = 2 * 0.33e-3
    estimate_track_roughness: bool = False
    drift_per_sqrt_s: float = 0.01
    start_ramp_s: float = 1.0
    start_ramp_m: float = 42.5
    kernel_delta: float = 0.0
    sensor_noise: str = "measured"
    output_rate_hz: float = 10.0
    checkpoint_interval_s: float = 5.0
    queue_samples: int = 20_000


@dataclass(frozen=True)
class OutputConfig:
    """Our frames on the bus."""

    estimate_rate_hz: float = 10.0
    health_rate_hz: float = 1.0


@dataclass(frozen=True)
class StateConfig:
    """Where the persisted state lives (systemd StateDirectory)."""

    directory: str = "/var/lib/railgw"


@dataclass(frozen=True)
class SerialConfig:
    """The fitters' maintenance port ('' disables it). ``pin_hash``: the console PIN as
    ``railgw console hash-pin`` makes it (salted scrypt; '' disables writes)."""

    device: str = ""
    baudrate: int = 115200
    pin_hash: str = ""


@dataclass(frozen=True)
class Config:
    """The whole configuration; ``source`` is the file it came from (or '<defaults>')."""

    bus: BusConfig = field(default_factory=BusConfig)
    resampler: ResamplerConfig = field(default_factory=ResamplerConfig)
    gating: GatingConfig = field(default_factory=GatingConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    state: StateConfig = field(default_factory=StateConfig)
    serial: SerialConfig = field(default_factory=SerialConfig)
    source: str = "<defaults>"


MAX_CONFIG_BYTES = 1 << 20
"""A configuration file is a page of text; anything larger is refused before parsing."""


def _describe(value: Any) -> str:
    if isinstance(value, int) and value.bit_length() > 128:
        return f"an integer of {value.bit_length()} bits"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _num(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


@dataclass(frozen=True)
class Range:
    """A closed numeric domain ``lo <= value <= hi`` (``off`` also allowed: 0 = off).

    ``hi_open`` makes the top bound exclusive. Floats must be finite.
    """

    lo: float
    hi: float
    off: float | None = None
    hi_open: bool = False
    off_means: str = "off"
    """What ``off`` stands for in the error text ("off", "auto")."""

    def problem(self, value: float) -> str | None:
        """None when ``value`` is inside, else the "expected ..., got ..." text."""
        if isinstance(value, float) and not math.isfinite(value):
            return f"expected a finite number {self.text()}, got {value!r}"
        if self.off is not None and value == self.off:
            return None
        inside = self.lo <= value and (value < self.hi if self.hi_open else value <= self.hi)
        return None if inside else f"expected a value {self.text()}, got {_describe(value)}"

    def text(self) -> str:
        top = ")" if self.hi_open else "]"
        off = f" (or {_num(self.off)} = {self.off_means})" if self.off is not None else ""
        return f"in [{_num(self.lo)}, {_num(self.hi)}{top}{off}"


@dataclass(frozen=True)
class OneOf:
    """A value from a fixed set."""

    choices: tuple[Any, ...]

    def problem(self, value: Any) -> str | None:
        return None if value in self.choices else \
            f"expected one of {list(self.choices)}, got {_describe(value)}"


@dataclass(frozen=True)
class Text:
    """A string: ``min_len``..``max_len`` characters, printable, optionally a pattern."""

    min_len: int = 0
    max_len: int = 4096
    pattern: str | None = None
    what: str = "text"

    def problem(self, value: str) -> str | None:
        if not self.min_len <= len(value) <= self.max_len:
            return (f"expected {self.what} of {self.min_len} to {self.max_len} characters, "
                    f"got {len(value)}")
        if not value.isprintable():
            return f"expected printable {self.what}, got {_describe(value)}"
        if self.pattern is not None and not re.fullmatch(self.pattern, value):
            return f"expected {self.what}, got {_describe(value)}"
        return None


Domain = Range | OneOf | Text

DOMAINS: dict[tuple[str, str], Domain] = {
    # python-can interfaces the service is built and tested for
    ("bus", "interface"): OneOf(("socketcan", "virtual")),
    # a SocketCAN name has at most 15 characters; virtual channels are free names
    ("bus", "channel"): Text(1, 64, what="a bus channel name"),
    ("bus", "reopen_min_s"): Range(0.01, 600.0),
    ("bus", "reopen_max_s"): Range(0.01, 3600.0),
    # a full 1 Mbit/s bus is ~8 000 frames/s; 1e6 queued frames is ~2 min and ~0.5 GB
    ("bus", "rx_queue_frames"): Range(1000, 1_000_000),
    # the kernel socket's receive buffer (socketcan); 0 keeps the kernel's default
    ("bus", "rcvbuf_bytes"): Range(4096, 2**30, off=0),
    # sensors sample at 1 kHz; the model's modes lie below 40 Hz
    ("resampler", "fs_hz"): Range(10.0, 10_000.0),
    ("resampler", "deadline_s"): Range(0.001, 10.0),
    ("resampler", "reorder_s"): Range(0.001, 10.0),
    ("resampler", "silent_s"): Range(0.001, 60.0),
    ("resampler", "interpolation"): OneOf(INTERPOLATIONS),
    # 0 = off; else a cut-off in [0.1 Hz, fs_hz / 2) (Nyquist, checked below)
    ("resampler", "lowpass_wheelset_acc_hz"): Range(0.1, 5000.0, off=0.0, hi_open=True),
    ("resampler", "lowpass_bogie_acc_hz"): Range(0.1, 5000.0, off=0.0, hi_open=True),
    ("resampler", "lowpass_gyro_hz"): Range(0.1, 5000.0, off=0.0, hi_open=True),
    ("resampler", "lowpass_body_acc_hz"): Range(0.1, 5000.0, off=0.0, hi_open=True),
    # 150 m/s = 540 km/h, beyond any service train
    ("gating", "speed_min_mps"): Range(0.0, 150.0),
    ("gating", "speed_max_mps"): Range(0.1, 150.0),
    ("gating", "curve_yaw_rate_max_radps"): Range(1e-5, 1.0),
    # the estimator needs >= 2; 20 000 is 20x what 2 cores run in real time
    ("estimator", "particles"): Range(2, 20_000),
    ("estimator", "mode"): OneOf(("fast", "exact")),
    ("estimator", "sensor_noise"): OneOf(("measured", "model")),
    ("estimator", "sensors"): OneOf((3, 5)),
    # numpy seeds are non-negative; 32 bits is plenty and fits every log and report
    ("estimator", "seed"): Range(0, 2**32 - 1),
    # the paper's Ar is 6.6e-4; 1e-6..0.1 spans every track class with margin
    ("estimator", "track_roughness"): Range(1e-6, 0.1),
    ("estimator", "estimate_track_roughness"): OneOf((False, True)),
    # the estimator refuses >= 1/sqrt(s); beyond 0.5 the parameters are noise
    ("estimator", "drift_per_sqrt_s"): Range(0.0, 0.5),
    # a few seconds at most: the weights learn slowly while it lasts
    ("estimator", "start_ramp_s"): Range(0.0, 5.0),
    # 42.5 m is 1 s at the paper's speed; 250 m is 12.5 s at the gate's lowest 20 m/s
    ("estimator", "start_ramp_m"): Range(0.0, 250.0),
    # 0 = auto; else the paper's 0.99 to 0.9999 (a kernel that hardly moves the
    # particles); below 0.95 a move forgets the cloud within a few samples
    ("estimator", "kernel_delta"): Range(0.95, 0.9999, off=0.0, off_means="auto"),
    # at most fs_hz (checked below)
    ("estimator", "output_rate_hz"): Range(0.01, 1000.0),
    ("estimator", "checkpoint_interval_s"): Range(0.1, 86_400.0),
    ("estimator", "queue_samples"): Range(100, 1_000_000),
    # at most [estimator] output_rate_hz (checked below): the CAN sink can only drop
    ("output", "estimate_rate_hz"): Range(0.01, 1000.0),
    # WATCHDOG=1 goes with each health tick: under the unit's WatchdogSec=10, 0.2 Hz at least
    ("output", "health_rate_hz"): Range(0.2, 100.0),
    # non-empty: "" would silently put the state into the working directory
    ("state", "directory"): Text(1, 4096, what="a directory path"),
    ("serial", "device"): Text(0, 4096, what="a device path"),
    ("serial", "baudrate"): Range(50, 4_000_000),
    # '' or scrypt$N$r$p$salt$hash (gateway.pin checks the fields, below)
    ("serial", "pin_hash"): Text(0, 256, what="a PIN hash"),
}
"""The checked domain of every key (a test asserts that every key has one)."""


# ---------------------------------------------------------------- line numbers
def _split_key(text: str) -> tuple[str, str] | None:
    """``'a."b".c = rest'`` -> (key text, rest after '='); None when not a key line."""
    quote, escaped = "", False
    for i, ch in enumerate(text):
        if quote:
            if escaped:
                escaped = False
            elif ch == "\\" and quote == '"':
                escaped = True
            elif ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch == "=":
            return text[:i], text[i + 1:]
        elif ch == "#":
            return None
    return None


def _paths(value: Any, prefix: tuple[str, ...]) -> list[tuple[str, ...]]:
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _paths(v, prefix + (k,))
    return out


def _key_paths(key_text: str) -> tuple[str, ...] | None:
    """The dotted key path of ``key_text`` as TOML reads it (quotes and escapes)."""
    try:
        doc = tomllib.loads(f"{key_text} = 0")
    except tomllib.TOMLDecodeError:
        return None
    path: list[str] = []
    node: Any = doc
    while isinstance(node, dict) and len(node) == 1:
        (k, node), = node.items()
        path.append(k)
    return tuple(path)


def _line_map(text: str) -> list[tuple[int, tuple[str, ...]]]:
    """(line, key path) for every header, key and inline-table key in ``text``."""
    out: list[tuple[int, tuple[str, ...]]] = []
    table: tuple[str, ...] = ()
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            try:                              # a header line alone is a TOML document
                node: Any = tomllib.loads(line)
            except tomllib.TOMLDecodeError:
                continue
            path: list[str] = []
            while isinstance(node, dict) and len(node) == 1:
                (k, node), = node.items()
                path.append(k)
                node = node[-1] if isinstance(node, list) and node else node
            table = tuple(path)
            out.append((n, table))
            continue
        split = _split_key(line)
        if split is None:
            continue
        keys = _key_paths(split[0])
        if keys is None:
            continue
        out.append((n, table + keys))
        rest = split[1].strip()
        if rest.startswith("{"):
            try:
                inline = tomllib.loads(f"x = {rest}")["x"]
            except tomllib.TOMLDecodeError:
                continue
            out += [(n, table + keys + p) for p in _paths(inline, ())[1:]]
    return out


def _line_of(text: str, section: str, key: str | None) -> int:
    """1-based line of ``[section] key`` (or of the section) however it was written:
    a header, a dotted or quoted key, an inline table; the closest enclosing table's
    line when the key itself is not written (1 when nothing matches)."""
    target = (section,) if key is None else (section, key)
    best_line, best_len = 1, 0
    for n, path in _line_map(text):
        if path == target:
            return n
        common = 0
        for a, b in zip(path, target, strict=False):
            if a != b:
                break
            common += 1
        if common > best_len and len(path) == common:
            best_line, best_len = n, common
    return best_line


# ------------------------------------------------------------------ validation
def _type_ok(value: Any, default: Any) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    return isinstance(value, type(default))


def check_value(section: str, key: str, value: Any) -> str | None:
    """The domain problem of ``[section] key = value`` (None when it is fine)."""
    domain = DOMAINS.get((section, key))
    return None if domain is None else domain.problem(value)


def _build(data: dict[str, Any], source: str, text: str | None) -> Config:
    def fail(section: str, key: str | None, message: str) -> ConfigError:
        where = f"[{section}]" + (f" {key}" if key else "")
        if text is None:
            return ConfigError(f"{source}: {where}: {message}")
        return ConfigError(f"{source}:{_line_of(text, section, key)}: {where}: {message}")

    sections: dict[str, Any] = {}
    known = {f.name: f for f in dataclasses.fields(Config) if f.name != "source"}
    for name, table in data.items():
        if name not in known:
            raise fail(name, None, f"expected a section from {sorted(known)}, "
                                   f"got [{_describe(name)[1:-1]}]")
        if not isinstance(table, dict):
            raise fail(name, None, f"expected a table [{name}], got {type(table).__name__}")
        defaults = getattr(Config(), name)
        fields = {f.name for f in dataclasses.fields(defaults)}
        values = {}
        for key, value in table.items():
            if (name, key) == ("serial", "pin_sha256"):
                raise fail(name, key, "expected pin_hash, a salted PIN hash, got the old "
                                      "unsalted pin_sha256: make one with 'railgw console "
                                      "hash-pin' and replace this line by pin_hash = \"...\"")
            if key not in fields:
                raise fail(name, key, f"expected a key from {sorted(fields)}, "
                                      f"got {_describe(key)}")
            default = getattr(defaults, key)
            if not _type_ok(value, default):
                raise fail(name, key, f"expected {type(default).__name__}, "
                                      f"got {type(value).__name__} {_describe(value)}")
            problem = check_value(name, key, value)
            if not problem and (name, key) == ("serial", "pin_hash"):
                from gateway.pin import pin_hash_problem  # the format has one home
                problem = pin_hash_problem(value)
            if problem:
                raise fail(name, key, problem)
            values[key] = float(value) if isinstance(default, float) else value
        sections[name] = dataclasses.replace(defaults, **values)
    cfg = Config(**sections, source=source)
    if cfg.gating.speed_min_mps >= cfg.gating.speed_max_mps:
        raise fail("gating", "speed_max_mps", f"expected speed_max_mps > speed_min_mps "
                   f"({cfg.gating.speed_min_mps}), got {cfg.gating.speed_max_mps}")
    if cfg.bus.reopen_min_s > cfg.bus.reopen_max_s:
        raise fail("bus", "reopen_max_s", f"expected reopen_max_s >= reopen_min_s "
                   f"({cfg.bus.reopen_min_s}), got {cfg.bus.reopen_max_s}")
    r = cfg.resampler
    for key in ("lowpass_wheelset_acc_hz", "lowpass_bogie_acc_hz", "lowpass_gyro_hz",
                "lowpass_body_acc_hz"):
        if getattr(r, key) >= r.fs_hz / 2:
            raise fail("resampler", key, f"expected 0 (off) or a cut-off below fs_hz / 2 = "
                       f"{r.fs_hz / 2:g} Hz, got {getattr(r, key)!r}")
    colouring = _noise_colouring(r)
    if colouring and cfg.estimator.sensor_noise == "measured":
        raise fail("estimator", "sensor_noise", f"expected \"model\" with {colouring} (the "
                   f"estimator's noise test needs white sensor noise on the grid), got "
                   f"\"measured\"")
    if cfg.estimator.output_rate_hz > r.fs_hz:
        raise fail("estimator", "output_rate_hz", f"expected at most [resampler] fs_hz "
                   f"({r.fs_hz:g}), got {cfg.estimator.output_rate_hz!r}")
    if cfg.output.estimate_rate_hz > cfg.estimator.output_rate_hz:
        raise fail("output", "estimate_rate_hz", f"expected at most [estimator] "
                   f"output_rate_hz ({cfg.estimator.output_rate_hz:g}), got "
                   f"{cfg.output.estimate_rate_hz!r}")
    return cfg


def _noise_colouring(r: ResamplerConfig) -> str:
    """What in the resampler filters or colours the sensor noise on the grid ('' if
    nothing): a low-pass filter removes the band the noise is measured in, linear
    interpolation colours it."""
    on = [key for key in ("lowpass_wheelset_acc_hz", "lowpass_bogie_acc_hz",
                          "lowpass_gyro_hz", "lowpass_body_acc_hz") if getattr(r, key)]
    if on:
        return f"[resampler] {on[0]} on"
    return '[resampler] interpolation = "linear"' if r.interpolation == "linear" else ""


def load_config(path: str | Path | None) -> Config:
    """Read and validate the TOML file (None: all defaults)."""
    if path is None:
        return Config()
    p = str(path)
    try:
        with open(p, "rb") as handle:
            raw = handle.read(MAX_CONFIG_BYTES + 1)
    except OSError as err:
        raise ConfigError(f"{p}: expected a readable config file, got "
                          f"{err.strerror or err}") from err
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{p}: expected a config file of at most {MAX_CONFIG_BYTES} bytes, "
                          f"got more")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        column = err.start - (raw.rfind(b"\n", 0, err.start) + 1) + 1
        raise ConfigError(f"{p}:{line}: expected UTF-8 TOML text, got byte "
                          f"0x{raw[err.start]:02x} at column {column}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        found = re.search(r"line (\d+)", str(err))
        line = getattr(err, "lineno", None) or (int(found.group(1)) if found else 1)
        raise ConfigError(f"{p}:{line}: expected valid TOML, got {err}") from None
    except RecursionError:
        raise ConfigError(f"{p}: expected TOML nested a few levels deep, got nesting "
                          f"too deep to read") from None
    return _build(data, p, text)


def with_overrides(cfg: Config, overrides: dict[str, Any]) -> Config:
    """Apply command-line overrides ``{"section.key": value}`` with the same checks."""
    data: dict[str, dict[str, Any]] = {}
    for name in ("bus", "resampler", "gating", "estimator", "output", "state", "serial"):
        data[name] = dataclasses.asdict(getattr(cfg, name))
    for dotted, value in overrides.items():
        section, _, key = dotted.partition(".")
        data.setdefault(section, {})[key] = value
    return _build(data, f"{cfg.source} (with command-line overrides)", None)


def as_toml(cfg: Config) -> str:
    """The configuration as TOML text (for ``config`` on the console and the example)."""
    out = []
    for f in dataclasses.fields(cfg):
        if f.name == "source":
            continue
        out.append(f"[{f.name}]")
        for key, value in dataclasses.asdict(getattr(cfg, f.name)).items():
            if isinstance(value, bool):
                text = "true" if value else "false"
            elif isinstance(value, str):
                text = '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
            else:
                text = repr(value)
            out.append(f"{key} = {text}")
        out.append("")
    return "\n".join(out)
