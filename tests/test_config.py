"""Configuration: defaults, the example file, and errors naming file, line and key (exit 78)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config import Config, as_toml, load_config, with_overrides
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
    ("[bus]\n\n[estimator]\nparticles = 0\n", 4, "[estimator] particles: expected a value > 0"),
    ("[estimator]\nsensors = 4\n", 2, "expected a value one of (3, 5), got 4"),
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
