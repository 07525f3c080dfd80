"""Where the packaged CAN database of the gateway lives: :data:`DBC_PATH`.

The DBC file is package data (see ``[tool.setuptools.package-data]``), so this path
is valid both in a source checkout and in an installed wheel.
"""

from __future__ import annotations

from pathlib import Path

DBC_PATH: Path = Path(__file__).resolve().parent / "railgw.dbc"
"""The gateway's DBC database (classic CAN, 11-bit ids, 1 Mbit/s)."""

__all__ = ["DBC_PATH"]
