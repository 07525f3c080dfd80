"""The source seam of identification: a recorded run's file -> Dataset, by suffix."""

from __future__ import annotations

from pathlib import Path

from gateway.config import Config
from gateway.errors import InputError
from gateway.identify.data import Dataset, dataset_from_recording
from gateway.offline.interchange import read_csv


def load_dataset(source: str | Path, sensors: tuple[str, ...] | None = None,
                 speed_mps: float | None = None, config: Config | None = None) -> Dataset:
    """The source seam: read a recorded run into a Dataset, chosen by the file ending.

    ``.csv``: interchange CSV. ``.log``, ``.asc``, ``.blf``, ``.trc``, ``.mf4``: a CAN log
    (python-can), put through the gateway's front end with ``config``'s resampler and
    gating settings (default: built-in). ``speed_mps`` replaces the recorded speed.
    """
    from gateway.identify.canlog import CAN_LOG_SUFFIXES, read_can_log

    path = Path(source)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        rec = read_csv(path)
    elif suffix in CAN_LOG_SUFFIXES:
        rec = read_can_log(path, config, speed_mps)
    else:
        raise InputError(f"expected an interchange CSV (.csv) or a CAN log "
                         f"({', '.join(CAN_LOG_SUFFIXES)}), got {str(path)!r}")
    return dataset_from_recording(rec, sensors, speed_mps)
