"""Configuration: defaults, the example file, and errors naming file, line and key (exit 78)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from gateway.config import Config, as_toml, check_value, load_config, with_overrides
from gateway.errors import ConfigError

EXAMPLE = Path(__file__).resolve().parent.parent / "systemd" / "railgw.example.toml"


def test_example_file_is_valid_and_equals_the_defaults():
    cfg = load_config(EXAMPLE)
    assert dataclass_values(cfg) == dataclass_values(Config())


def dataclass_values(cfg: Config) -> str:
    return as_toml(cfg)


def test_round_trip_through_toml(tmp_path):
    cfg = with_overrides(Config(), {"estimator.particles": 200, "bus.interface": "virtual"})
    path = tmp_path / "c.toml"
    path.write_text(as_toml(cfg))
    again = load_config(path)
    assert again.estimator.particles == 200 and again.bus.interface == "virtual"


@pytest.mark.parametrize("text, line, words", [
    ("[bus]\ninterface = \"socketcan\"\nchannel = 5\n", 3, "[bus] channel: expected str"),
    ("[bus]\n\n[estimator]\nparticles = 0\n", 4, "[estimator] particles: expected a value in [2,"),
    ("[estimator]\nsensors = 4\n", 2, "expected one of [3, 5], got 4"),
    ("[estimatr]\nparticles = 10\n", 1, "expected a section from"),
    ("[bus]\nchanel = \"can0\"\n", 2, "expected a key from"),
    ("[bus]\ninterface = \n", 2, "expected valid TOML"),
    ("[gating]\nspeed_min_mps = 50\nspeed_max_mps = 40\n", 3, "speed_max_mps > speed_min_mps"),
])
def test_errors_name_file_line_and_key(tmp_path, text, line, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.exit_code == 78
    assert str(info.value).startswith(f"{path}:{line}:")
    assert words in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="expected a readable config file"):
        load_config(tmp_path / "nope.toml")


# --- issue 12, finding 3: values that passed validation and then killed the worker, and
# errors that named no line or key. Every one is now exit 78, one line, file:line: [s] key.
@pytest.mark.parametrize("text, line, words", [
    ("[estimator]\nseed = -1\n", 2, "[estimator] seed: expected a value in [0, 4294967295]"),
    ("[estimator]\ndrift_per_sqrt_s = 5.0\n", 2, "[estimator] drift_per_sqrt_s: expected a "
                                                  "value in [0, 0.5], got 5.0"),
    ("[estimator]\nparticles = 1\n", 2, "[estimator] particles: expected a value in [2,"),
    ("[estimator]\nkernel_delta = 0.9\n", 2, "[estimator] kernel_delta: expected a value "
                                            "in [0.95, 0.9999] (or 0 = auto), got 0.9"),
    ("[resampler]\ndeadline_s = inf\n", 2, "[resampler] deadline_s: expected a finite number"),
    ("[resampler]\nfs_hz = inf\n", 2, "[resampler] fs_hz: expected a finite number"),
    ("[resampler]\nfs_hz = nan\n", 2, "[resampler] fs_hz: expected a finite number"),
    ("[bus]\n\n[resampler]\nlowpass_gyro_hz = 600\n", 4,
     "[resampler] lowpass_gyro_hz: expected 0 (off) or a cut-off below fs_hz / 2 = 500 Hz"),
    ("[bus]\n\n[estimator]\n\"particles\" = 0\n", 4, "[estimator] particles: expected a value"),
    ("[bus]\n\n[estimator]\n'particles' = 0\n", 4, "[estimator] particles: expected a value"),
    ("# inline\n\nestimator = { sensors = 3, particles = 0 }\n", 3, "[estimator] particles"),
    ("# dotted\n\nestimator.particles = 0\n", 3, "[estimator] particles: expected a value"),
    ("[bus]\n[estimator]\n[estimator.foo]\nx = 1\n", 3, "[estimator] foo: expected a key from"),
    ("[bus]\n\n[estimator.particles]\nx = 1\n", 3, "[estimator] particles: expected int, got dict"),
    ("[ \"estimator\" ]  # quoted header\n\nqueue_samples = 1\n", 3, "[estimator] queue_samples"),
    ("[state]\ndirectory = \"\"\n", 2, "[state] directory: expected a directory path of 1 to"),
    ("[resampler]\n\nfs_hz = 1" + "0" * 400 + "\n", 3, "[resampler] fs_hz: expected a value in "
                                                      "[10, 10000], got an integer of"),
    ("[bus]\nrx_queue_frames = 10000000000\n", 2, "[bus] rx_queue_frames: expected a value in"),
    ("[estimator]\noutput_rate_hz = 10.0\n[output]\nestimate_rate_hz = 20.0\n", 4,
     "[output] estimate_rate_hz: expected at most [estimator] output_rate_hz (10)"),
    ("[serial]\npin_sha256 = \"1234\"\n", 2, "[serial] pin_sha256: expected pin_hash"),
    ("[serial]\n\npin_hash = \"1234\"\n", 3, "[serial] pin_hash: expected"),
    ("[bus]\nchannel = \"can0\\u0000\"\n", 2, "[bus] channel: expected printable"),
    # WATCHDOG=1 rides on the health tick: below 0.2 Hz the unit's WatchdogSec=10 would trip
    ("[output]\nhealth_rate_hz = 0.05\n", 2, "[output] health_rate_hz: expected a value in "
                                             "[0.2, 100]"),
])
def test_domain_errors_name_file_line_and_key(tmp_path, text, line, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert info.value.exit_code == 78 and "\n" not in message
    assert message.startswith(f"{path}:{line}: "), message
    assert words in message, message


def test_non_utf8_names_the_line_and_column(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"[bus]\n\nchannel = \"b\xe4hn\"\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}:3: expected UTF-8 TOML text, got byte 0xe4 at column 13"


def test_oversized_file_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.toml"
    path.write_text("# " + "x" * (1 << 20) + "\n")
    with pytest.raises(ConfigError, match="expected a config file of at most 1048576 bytes"):
        load_config(path)


def test_every_key_has_a_checked_domain():
    from gateway.config import DOMAINS
    keys = {(s.name, k.name) for s in dataclasses.fields(Config) if s.name != "source"
            for k in dataclasses.fields(getattr(Config(), s.name))}
    assert keys == set(DOMAINS)
    for (section, key), _ in DOMAINS.items():   # the defaults are inside their domains
        assert check_value(section, key, getattr(getattr(Config(), section), key)) is None


def test_overrides_are_checked_too():
    with pytest.raises(ConfigError) as info:
        with_overrides(Config(), {"estimator.seed": -1})
    assert str(info.value) == ("<defaults> (with command-line overrides): [estimator] seed: "
                               "expected a value in [0, 4294967295], got -1")
