"""The interchange CSV format: read and write recorded runs, with line-precise errors.

Format: a header line, then one row per sample time. Columns:

============================  ========  =========
column                        unit      required
============================  ========  =========
``time_s``                    s         yes (strictly increasing, may be uneven)
``bogie_lat_acc_mps2``        m/s^2     yes
``bogie_yaw_rate_radps``      rad/s     yes
``body_lat_acc_mps2``         m/s^2     yes
``wheelset1_lat_acc_mps2``    m/s^2     no
``wheelset2_lat_acc_mps2``    m/s^2     no
``speed_mps``                 m/s       no
============================  ========  =========

Unknown extra columns are ignored. An empty cell or ``nan`` means "no value at this
time" for that signal (a dropout); ``time_s`` may never be empty. Anything else that
is not a finite number inside the column's physical domain (:data:`LIMITS`: |time| up
to 1e10 s, e.g. Unix time; |acceleration| up to 1000 m/s^2, 60x the CAN sensors' own
range; |yaw rate| up to 100 rad/s; speed 0 to 150 m/s) is an error naming the file,
line and column.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.errors import CsvFormatError

TIME_COLUMN = "time_s"
SENSOR_COLUMNS: dict[str, str] = {
    "acc_w1": "wheelset1_lat_acc_mps2",
    "acc_w2": "wheelset2_lat_acc_mps2",
    "acc_b": "bogie_lat_acc_mps2",
    "gyro_b": "bogie_yaw_rate_radps",
    "acc_bd": "body_lat_acc_mps2",
}
SPEED_COLUMN = "speed_mps"
REQUIRED = (TIME_COLUMN, SENSOR_COLUMNS["acc_b"], SENSOR_COLUMNS["gyro_b"],
            SENSOR_COLUMNS["acc_bd"])
OPTIONAL = (SENSOR_COLUMNS["acc_w1"], SENSOR_COLUMNS["acc_w2"], SPEED_COLUMN)
LIMITS: dict[str, tuple[float, float]] = {
    TIME_COLUMN: (-1e10, 1e10),
    **{c: (-1000.0, 1000.0) for c in SENSOR_COLUMNS.values()},
    SENSOR_COLUMNS["gyro_b"]: (-100.0, 100.0),
    SPEED_COLUMN: (0.0, 150.0),
}
"""The physical domain [lo, hi] of each column (module docstring)."""


@dataclass(frozen=True)
class Recording:
    """A recorded run. ``t_s`` (T,); ``signals[name]`` (T,) with NaN where missing.

    ``signals`` is keyed by sensor name (``acc_b``, ``gyro_b``, ...) and ``speed``;
    only columns present in the file appear.
    """

    t_s: np.ndarray
    signals: dict[str, np.ndarray]
    source: str

    @property
    def sensors(self) -> tuple[str, ...]:
        """The sensors present, in the 5-sensor order."""
        return tuple(s for s in SENSOR_COLUMNS if s in self.signals)

    def matrix(self, sensors: tuple[str, ...]) -> np.ndarray:
        """Measurements for ``sensors``, shape (T, len(sensors))."""
        missing = [s for s in sensors if s not in self.signals]
        if missing:
            cols = [SENSOR_COLUMNS[s] for s in missing]
            raise CsvFormatError(self.source, 1, cols[0],
                                 f"expected columns {cols} for the chosen sensor set, "
                                 f"got header without them")
        return np.column_stack([self.signals[s] for s in sensors])


def _parse(text: str, path: str, line: int, column: str, allow_empty: bool) -> float:
    s = text.strip()
    if s == "" or s.lower() == "nan":
        if allow_empty:
            return math.nan
        raise CsvFormatError(path, line, column, "expected a number, got an empty value")
    try:
        value = float(s)
    except ValueError:
        raise CsvFormatError(path, line, column, f"expected a number, got {s!r}") from None
    if not math.isfinite(value):
        raise CsvFormatError(path, line, column, f"expected a finite number, got {s!r}")
    lo, hi = LIMITS[column]
    if not lo <= value <= hi:
        raise CsvFormatError(path, line, column, f"expected a value in [{lo:g}, {hi:g}], "
                                                 f"got {s[:40]!r}")
    return value


def read_csv(path: str | Path) -> Recording:
    """Read an interchange CSV; raises CsvFormatError naming line and column."""
    p = str(path)
    try:
        handle = open(p, newline="", encoding="utf-8")  # noqa: SIM115 (closed by `with` below)
    except OSError as err:
        raise CsvFormatError(p, 0, None, f"expected a readable file, got {err.strerror}") from err
    with handle:
        reader = csv.reader(handle)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise CsvFormatError(p, 1, None, "expected a header line, got an empty file") from None
        except (csv.Error, UnicodeDecodeError) as err:
            raise CsvFormatError(p, 1, None, f"expected CSV text, got {err}") from err
        missing = [c for c in REQUIRED if c not in header]
        if missing:
            raise CsvFormatError(p, 1, missing[0],
                                 f"expected header columns {list(REQUIRED)}, "
                                 f"got {header} (missing {missing})")
        wanted = [c for c in REQUIRED + OPTIONAL if c in header]
        index = {c: header.index(c) for c in wanted}
        columns: dict[str, list[float]] = {c: [] for c in wanted}
        last_t = -math.inf
        line = 1
        try:
            for line, row in enumerate(reader, start=2):
                if not row or all(not f.strip() for f in row):
                    continue
                if len(row) != len(header):
                    raise CsvFormatError(p, line, None, f"expected {len(header)} fields, "
                                         f"got {len(row)}")
                for c in wanted:
                    columns[c].append(_parse(row[index[c]], p, line, c, c != TIME_COLUMN))
                t = columns[TIME_COLUMN][-1]
                if t <= last_t:
                    raise CsvFormatError(p, line, TIME_COLUMN,
                                         f"expected time to increase past {last_t}, got {t}")
                last_t = t
        except (csv.Error, UnicodeDecodeError) as err:
            raise CsvFormatError(p, line, None, f"expected CSV text, got {err}") from err
    if not columns[TIME_COLUMN]:
        raise CsvFormatError(p, 2, None, "expected at least one data row, got none")
    by_name = {v: k for k, v in SENSOR_COLUMNS.items()}
    signals = {by_name.get(c, "speed" if c == SPEED_COLUMN else c): np.asarray(v)
               for c, v in columns.items() if c != TIME_COLUMN}
    return Recording(t_s=np.asarray(columns[TIME_COLUMN]), signals=signals, source=p)


def write_csv(path: str | Path, t_s: np.ndarray, signals: dict[str, np.ndarray]) -> None:
    """Write an interchange CSV. ``signals`` keyed by sensor name or ``speed``; (T,) each."""
    names = [s for s in SENSOR_COLUMNS if s in signals] + (["speed"] if "speed" in signals
                                                           else [])
    header = [TIME_COLUMN] + [SENSOR_COLUMNS.get(n, SPEED_COLUMN) for n in names]
    data = np.column_stack([np.asarray(t_s, dtype=float)]
                           + [np.asarray(signals[n], dtype=float) for n in names])
    with open(path, "w", newline="", encoding="utf-8") as handle:
        handle.write(",".join(header) + "\n")
        for row in data:
            handle.write(",".join("" if math.isnan(v) else repr(float(v)) for v in row) + "\n")
