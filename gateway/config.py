"""The service configuration: one TOML file plus overrides, validated with line-precise errors.

Every setting has a documented default (``systemd/railgw.example.toml`` lists them all).
Unknown sections or keys are errors (a typo must not silently fall back to a
default). Errors name the file, the line and the key, and carry exit status 78.
"""

from __future__ import annotations

import dataclasses
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


@dataclass(frozen=True)
class ResamplerConfig:
    """The fixed-rate grid and the anti-alias low-passes (0 switches a filter off)."""

    fs_hz: float = 1000.0
    deadline_s: float = 0.2
    lowpass_wheelset_acc_hz: float = 0.0
    lowpass_bogie_acc_hz: float = 0.0
    lowpass_gyro_hz: float = 0.0
    lowpass_body_acc_hz: float = 0.0


@dataclass(frozen=True)
class GatingConfig:
    """When the estimator may update: speed window and straight track."""

    speed_min_mps: float = 15.0
    speed_max_mps: float = 70.0
    curve_yaw_rate_max_radps: float = 0.01


@dataclass(frozen=True)
class EstimatorConfig:
    """The RBPF worker: particles, sensors, roughness, output and checkpoint cadence.

    500 particles by default: on a 2-core gateway the live worker keeps up with the bus
    at 500 (end-to-end latency ~1.5 s) but falls behind at 1000 (README, figures).
    ``drift_per_sqrt_s``: random-walk evolution of Csy, Csay and lambda (relative std per
    square root of second of updated data) so that the on-board filter follows a slow
    change; 0 is the paper's static-parameter filter (docs/estimator.md, "Drift").
    """

    particles: int = 500
    sensors: int = 3
    seed: int = 0
    track_roughness: float = 2 * 0.33e-3
    estimate_track_roughness: bool = False
    drift_per_sqrt_s: float = 0.01
    output_rate_hz: float = 10.0
    checkpoint_interval_s: float = 5.0
    queue_samples: int = 5000


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
    """The fitters' maintenance port ('' disables it)."""

    device: str = ""
    baudrate: int = 115200
    pin_sha256: str = ""


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


_RULES: dict[tuple[str, str], tuple[str, Any]] = {
    ("bus", "interface"): ("one of", ("socketcan", "virtual")),
    ("bus", "reopen_min_s"): (">", 0.0),
    ("bus", "reopen_max_s"): (">", 0.0),
    ("bus", "rx_queue_frames"): (">", 0),
    ("resampler", "fs_hz"): (">", 0.0),
    ("resampler", "deadline_s"): (">", 0.0),
    ("resampler", "lowpass_wheelset_acc_hz"): (">=", 0.0),
    ("resampler", "lowpass_bogie_acc_hz"): (">=", 0.0),
    ("resampler", "lowpass_gyro_hz"): (">=", 0.0),
    ("resampler", "lowpass_body_acc_hz"): (">=", 0.0),
    ("gating", "speed_min_mps"): (">=", 0.0),
    ("gating", "speed_max_mps"): (">", 0.0),
    ("gating", "curve_yaw_rate_max_radps"): (">", 0.0),
    ("estimator", "particles"): (">", 0),
    ("estimator", "sensors"): ("one of", (3, 5)),
    ("estimator", "track_roughness"): (">", 0.0),
    ("estimator", "drift_per_sqrt_s"): (">=", 0.0),
    ("estimator", "output_rate_hz"): (">", 0.0),
    ("estimator", "checkpoint_interval_s"): (">", 0.0),
    ("estimator", "queue_samples"): (">", 0),
    ("output", "estimate_rate_hz"): (">", 0.0),
    ("output", "health_rate_hz"): (">", 0.0),
    ("serial", "baudrate"): (">", 0),
}


def _line_of(text: str, section: str, key: str | None) -> int:
    """1-based line of ``[section]`` or of ``key`` inside it; 1 when not found."""
    current = None
    for i, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        m = re.match(r"^\[\s*([A-Za-z0-9_.-]+)\s*\]", line)
        if m:
            current = m.group(1)
            if key is None and current == section:
                return i
            continue
        if current == section and key is not None and re.match(rf"^{re.escape(key)}\s*=", line):
            return i
    return 1


def _type_ok(value: Any, default: Any) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    return isinstance(value, type(default))


def _check_rule(section: str, key: str, value: Any) -> str | None:
    rule = _RULES.get((section, key))
    if rule is None:
        return None
    op, arg = rule
    ok = {"one of": lambda: value in arg, ">": lambda: value > arg,
          ">=": lambda: value >= arg}[op]()
    return None if ok else f"expected a value {op} {arg}, got {value!r}"


def _build(data: dict[str, Any], source: str, text: str) -> Config:
    def fail(section: str, key: str | None, message: str) -> ConfigError:
        line = _line_of(text, section, key)
        where = f"[{section}]" + (f" {key}" if key else "")
        return ConfigError(f"{source}:{line}: {where}: {message}")

    sections: dict[str, Any] = {}
    known = {f.name: f for f in dataclasses.fields(Config) if f.name != "source"}
    for name, table in data.items():
        if name not in known:
            raise fail(name, None, f"expected a section from {sorted(known)}, got [{name}]")
        if not isinstance(table, dict):
            raise fail(name, None, f"expected a table [{name}], got {type(table).__name__}")
        defaults = getattr(Config(), name)
        fields = {f.name for f in dataclasses.fields(defaults)}
        values = {}
        for key, value in table.items():
            if key not in fields:
                raise fail(name, key, f"expected a key from {sorted(fields)}, got {key!r}")
            default = getattr(defaults, key)
            if not _type_ok(value, default):
                raise fail(name, key, f"expected {type(default).__name__}, "
                                      f"got {type(value).__name__} {value!r}")
            if isinstance(default, float):
                value = float(value)
            problem = _check_rule(name, key, value)
            if problem:
                raise fail(name, key, problem)
            values[key] = value
        sections[name] = dataclasses.replace(defaults, **values)
    cfg = Config(**sections, source=source)
    if cfg.gating.speed_min_mps >= cfg.gating.speed_max_mps:
        raise fail("gating", "speed_max_mps", f"expected speed_max_mps > speed_min_mps "
                   f"({cfg.gating.speed_min_mps}), got {cfg.gating.speed_max_mps}")
    if cfg.bus.reopen_min_s > cfg.bus.reopen_max_s:
        raise fail("bus", "reopen_max_s", f"expected reopen_max_s >= reopen_min_s "
                   f"({cfg.bus.reopen_min_s}), got {cfg.bus.reopen_max_s}")
    return cfg


def load_config(path: str | Path | None) -> Config:
    """Read and validate the TOML file (None: all defaults)."""
    if path is None:
        return Config()
    p = str(path)
    try:
        text = Path(p).read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{p}: expected a readable config file, got {err.strerror}") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{p}: expected UTF-8 TOML text, got {err}") from err
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        found = re.search(r"line (\d+)", str(err))
        line = getattr(err, "lineno", None) or (int(found.group(1)) if found else 1)
        raise ConfigError(f"{p}:{line}: expected valid TOML, got {err}") from err
    return _build(data, p, text)


def with_overrides(cfg: Config, overrides: dict[str, Any]) -> Config:
    """Apply command-line overrides ``{"section.key": value}`` with the same checks."""
    data: dict[str, dict[str, Any]] = {}
    for name in ("bus", "resampler", "gating", "estimator", "output", "state", "serial"):
        data[name] = dataclasses.asdict(getattr(cfg, name))
    for dotted, value in overrides.items():
        section, _, key = dotted.partition(".")
        data.setdefault(section, {})[key] = value
    return _build(data, f"{cfg.source} (with command-line overrides)", "")


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
