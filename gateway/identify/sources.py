"""The source seam of identification: a recorded run's file -> Dataset, by file ending.

:data:`READERS` is the registry: file ending -> reader of a
:class:`~gateway.offline.interchange.Recording`. ``data`` (the Dataset and its checks)
knows no reader and ``canlog`` knows no registry, so neither imports the other's
importer: the old ``canlog`` <-> ``data`` cycle is gone.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from gateway.config import Config
from gateway.errors import InputError
from gateway.identify.canlog import CAN_LOG_SUFFIXES, read_can_log
from gateway.identify.data import Dataset, dataset_from_recording
from gateway.offline.interchange import Recording, read_csv

Reader = Callable[[Path, Config | None, float | None], Recording]
"""``(path, gateway config or None, speed_mps or None) -> Recording``."""

READERS: dict[str, Reader] = {
    ".csv": lambda path, _config, _speed: read_csv(path),
    **{suffix: read_can_log for suffix in CAN_LOG_SUFFIXES},
}


def load_dataset(source: str | Path, sensors: tuple[str, ...] | None = None,
                 speed_mps: float | None = None, config: Config | None = None) -> Dataset:
    """The source seam: read a recorded run into a Dataset, chosen by the file ending.

    ``.csv``: interchange CSV. ``.log``, ``.asc``, ``.blf``, ``.trc``, ``.mf4``: a CAN log
    (python-can), put through the gateway's front end with ``config``'s resampler and
    gating settings (default: built-in). ``speed_mps`` replaces the recorded speed.
    """
    path = Path(source)
    reader = READERS.get(path.suffix.lower())
    if reader is None:
        raise InputError(f"expected an interchange CSV (.csv) or a CAN log "
                         f"({', '.join(CAN_LOG_SUFFIXES)}), got {str(path)!r}")
    return dataset_from_recording(reader(path, config, speed_mps), sensors, speed_mps)
