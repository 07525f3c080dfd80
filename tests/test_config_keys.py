"""Every key of the example configuration is a real key: it loads into ``Config`` with
its documented default, and the product reads it (so a documented key that nothing
uses fails here: make it real or remove it)."""

from __future__ import annotations

import ast
import dataclasses
import tomllib
from functools import cache
from pathlib import Path

from gateway.config import Config, load_config

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "systemd" / "railgw.example.toml"
PRODUCT = ROOT / "gateway"


def _example() -> dict[str, dict[str, object]]:
    return tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))


def _sections() -> dict[str, type]:
    """Config section name -> its dataclass (BusConfig, ...)."""
    return {f.name: type(getattr(Config(), f.name)) for f in dataclasses.fields(Config)
            if f.name != "source"}


@cache
def _module_names(root: Path = PRODUCT) -> list[tuple[Path, frozenset[str], frozenset[str]]]:
    """Per module under ``root`` except config.py: (path, attribute names accessed as
    ``x.name``, plain and imported names used)."""
    out = []
    for path in sorted(root.rglob("*.py")):
        if path == root / "config.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        attrs = frozenset(n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute))
        names = frozenset(n.id for n in ast.walk(tree) if isinstance(n, ast.Name)) | \
            frozenset(a.name.rsplit(".", 1)[-1] for n in ast.walk(tree)
                      if isinstance(n, ast.ImportFrom) for a in n.names)
        out.append((path, attrs, names))
    return out


def readers(section: str, key: str, root: Path = PRODUCT) -> list[str]:
    """Modules under ``root`` that read ``[section] key``: they access ``.key`` and get at
    the section, as ``cfg.section`` or by its dataclass (``EstimatorConfig``, a parameter
    type), so ``r = cfg.resampler; r.fs_hz`` counts."""
    cls = _sections()[section].__name__
    return [path.relative_to(root).as_posix() for path, attrs, names in _module_names(root)
            if key in attrs and (section in attrs or cls in names)]


def test_every_example_key_loads_into_config_with_its_documented_default():
    cfg = load_config(EXAMPLE)
    defaults = Config()
    example = _example()
    assert set(example) == set(_sections()), "the example lists every section"
    for section, table in example.items():
        fields = {f.name for f in dataclasses.fields(getattr(cfg, section))}
        assert set(table) == fields, (section, set(table) ^ fields)
        for key, value in table.items():
            got = getattr(getattr(cfg, section), key)
            assert got == value, (section, key, got, value)
            assert got == getattr(getattr(defaults, section), key), \
                f"[{section}] {key}: the example's value is not the default"


def test_every_example_key_is_read_by_the_product():
    unused = [f"[{section}] {key}" for section, table in _example().items()
              for key in table if not readers(section, key)]
    assert not unused, f"documented but read nowhere in gateway/: {unused}"


def test_the_reader_check_finds_an_unused_key(tmp_path):
    """The check itself, on a small tree: a key read as ``cfg.output.key``, one read via
    the section's dataclass, one whose name appears only on another record, one unread
    (and config.py, which names every key, does not count)."""
    (tmp_path / "config.py").write_text("def f(c):\n    return c.output.estimate_rate_hz\n")
    (tmp_path / "a.py").write_text("def f(cfg):\n    return cfg.output.health_rate_hz\n")
    (tmp_path / "b.py").write_text("from gateway.config import SerialConfig\n\n\n"
                                   "def f(s: SerialConfig):\n    return s.baudrate\n")
    (tmp_path / "c.py").write_text("def f(spec):\n    return spec.channel\n")
    assert readers("output", "health_rate_hz", tmp_path) == ["a.py"]
    assert readers("serial", "baudrate", tmp_path) == ["b.py"]
    assert readers("bus", "channel", tmp_path) == []
    assert readers("output", "estimate_rate_hz", tmp_path) == []
    assert "service/daemon.py" in readers("output", "estimate_rate_hz")
