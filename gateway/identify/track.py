"""Track lateral alignment: the known input of the misfit path (CSV, generators, lookup).

Track CSV format (one header line, one row per point, strictly increasing position):

=========================  ====  ===========================================
column                     unit  meaning
=========================  ====  ===========================================
``position_m``             m     distance along the line (leading wheelset)
``lateral_alignment_m``    m     lateral alignment of the track centre line
=========================  ====  ===========================================

Extra columns are ignored. Alignment between points is linearly interpolated. The
trailing wheelset of a bogie with semi-wheelbase ``a`` sees the same track ``2a``
metres later: ``y_t2(t) = alignment(x(t) - 2a)``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.errors import CsvFormatError, InputError

POSITION_COLUMN = "position_m"
ALIGNMENT_COLUMN = "lateral_alignment_m"


@dataclass(frozen=True)
class Track:
    """Lateral alignment along the line: ``position_m`` (N,), ``alignment_m`` (N,)."""

    position_m: np.ndarray
    alignment_m: np.ndarray
    source: str = "generated"

    def __post_init__(self) -> None:
        x, y = np.asarray(self.position_m), np.asarray(self.alignment_m)
        if x.ndim != 1 or x.shape != y.shape or len(x) < 2:
            raise InputError(f"expected position and alignment of equal shape (N>=2,), "
                             f"got {x.shape} and {y.shape}")
        if not np.all(np.diff(x) > 0):
            raise InputError(f"{self.source}: expected strictly increasing track positions")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise InputError(f"{self.source}: expected finite track positions and alignment")

    def at(self, x_m: np.ndarray) -> np.ndarray:
        """Alignment [m] at positions ``x_m`` (any shape); outside the track is an error."""
        x = np.asarray(x_m, dtype=float)
        lo, hi = float(self.position_m[0]), float(self.position_m[-1])
        if x.size and (float(np.min(x)) < lo - 1e-9 or float(np.max(x)) > hi + 1e-9):
            raise InputError(f"{self.source}: expected positions within the track "
                             f"[{lo:.3f}, {hi:.3f}] m, got [{float(np.min(x)):.3f}, "
                             f"{float(np.max(x)):.3f}] m (track too short for the sections)")
        return np.interp(x, self.position_m, self.alignment_m)

    def shifted(self, offset_m: float) -> Track:
        """The same track with positions moved by ``offset_m``."""
        return Track(self.position_m + offset_m, self.alignment_m, self.source)


def wheel_alignment(track: Track, position_m: np.ndarray, a_m: float) -> np.ndarray:
    """Track alignment under the (leading, trailing) wheelsets, shape (T, 2), m.

    ``position_m`` (T,) is the leading wheelset's position; the trailing one is 2a behind.
    """
    x = np.asarray(position_m, dtype=float)
    return np.column_stack([track.at(x), track.at(x - 2.0 * a_m)])


def random_track(length_m: float, dx_m: float, rms_m: float, rng: np.random.Generator,
                 wavelength_min_m: float = 3.0, wavelength_max_m: float = 200.0) -> Track:
    """Random alignment with PSD ~ 1/Omega^2 in a wavelength band (as measured by IRIS 320).

    Omega [rad/m] is the spatial frequency; the alignment is scaled to ``rms_m``.
    """
    if not (length_m > 0 and dx_m > 0 and rms_m > 0 and 0 < wavelength_min_m
            < wavelength_max_m):
        raise InputError(f"expected positive length, spacing, rms and a wavelength band, got "
                         f"{length_m}, {dx_m}, {rms_m}, [{wavelength_min_m}, {wavelength_max_m}]")
    n = int(math.ceil(length_m / dx_m)) + 1
    omega = 2 * np.pi * np.fft.rfftfreq(n, d=dx_m)
    band = (omega >= 2 * np.pi / wavelength_max_m) & (omega <= 2 * np.pi / wavelength_min_m)
    amp = np.zeros_like(omega)
    amp[band] = 1.0 / omega[band]
    spec = amp * (rng.standard_normal(len(omega)) + 1j * rng.standard_normal(len(omega)))
    y = np.fft.irfft(spec, n=n)
    y *= rms_m / float(np.std(y))
    return Track(np.arange(n) * dx_m, y, "random track")


def sine_track(length_m: float, dx_m: float, wavelengths_m: tuple[float, ...],
               amplitudes_m: tuple[float, ...], phases_rad: tuple[float, ...]) -> Track:
    """A sum of sines ``sum A_i sin(2 pi x / L_i + phi_i)``; e.g. cyclic (jointed-rail) defects."""
    if not len(wavelengths_m) == len(amplitudes_m) == len(phases_rad):
        raise InputError(f"expected equal numbers of wavelengths, amplitudes and phases, got "
                         f"{len(wavelengths_m)}, {len(amplitudes_m)}, {len(phases_rad)}")
    x = np.arange(int(math.ceil(length_m / dx_m)) + 1) * dx_m
    y = np.zeros_like(x)
    for lam, amp, ph in zip(wavelengths_m, amplitudes_m, phases_rad, strict=True):
        y += amp * np.sin(2 * np.pi * x / lam + ph)
    return Track(x, y, "sine track")


def jointed_track(length_m: float, dx_m: float, rng: np.random.Generator,
                  rail_m: float = 25.0, cusp_m: float = 3e-3, decay_m: float = 1.0,
                  random_rms_m: float = 0.5e-3, first_joint_m: float = 0.0) -> Track:
    """Jointed rails: a lateral cusp at every joint plus a small random alignment.

    Joints lie at ``first_joint_m + i * rail_m`` (m). Each adds
    ``cusp_m * exp(-|x - x_joint| / decay_m)`` (m; ``decay_m`` the 1/e half-width, m),
    so the alignment repeats with the rail length; on top sits a random alignment of
    ``random_rms_m`` (m RMS) from :func:`random_track`, which makes each rail differ a
    little, as a real line does. ``random_rms_m`` 0 gives a purely periodic track.
    """
    if not (length_m > 0 and dx_m > 0 and rail_m > 0 and decay_m > 0 and cusp_m >= 0
            and random_rms_m >= 0):
        raise InputError(f"expected positive length, spacing, rail length and decay and "
                         f"non-negative cusp and rms, got {length_m}, {dx_m}, {rail_m}, "
                         f"{decay_m}, {cusp_m}, {random_rms_m}")
    x = np.arange(int(math.ceil(length_m / dx_m)) + 1) * dx_m
    phase = np.mod(x - first_joint_m, rail_m)              # distance past the last joint
    distance = np.minimum(phase, rail_m - phase)           # to the nearest joint
    y = cusp_m * np.exp(-distance / decay_m)
    if random_rms_m > 0:
        y = y + random_track(length_m, dx_m, random_rms_m, rng).alignment_m[:len(x)]
    return Track(x, y, f"jointed track ({rail_m:g} m rails)")


def read_track_csv(path: str | Path) -> Track:
    """Read a track CSV (``position_m``, ``lateral_alignment_m``); line-precise errors."""
    p = str(path)
    try:
        text = Path(p).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise CsvFormatError(p, 0, None, f"expected a readable UTF-8 file, got {err}") from err
    rows = csv.reader(text.splitlines())
    header = [h.strip() for h in next(rows, [])]
    missing = [c for c in (POSITION_COLUMN, ALIGNMENT_COLUMN) if c not in header]
    if missing:
        raise CsvFormatError(p, 1, missing[0], f"expected header columns "
                             f"{[POSITION_COLUMN, ALIGNMENT_COLUMN]}, got {header}")
    ix, iy = header.index(POSITION_COLUMN), header.index(ALIGNMENT_COLUMN)
    xs: list[float] = []
    ys: list[float] = []
    for line, row in enumerate(rows, start=2):
        if not row or all(not f.strip() for f in row):
            continue
        for col, idx, dest in ((POSITION_COLUMN, ix, xs), (ALIGNMENT_COLUMN, iy, ys)):
            try:
                value = float(row[idx])
            except (ValueError, IndexError):
                got = row[idx] if idx < len(row) else "a missing field"
                raise CsvFormatError(p, line, col, f"expected a number, got {got!r}") from None
            if not math.isfinite(value):
                raise CsvFormatError(p, line, col, f"expected a finite number, got {value}")
            dest.append(value)
        if len(xs) > 1 and xs[-1] <= xs[-2]:
            raise CsvFormatError(p, line, POSITION_COLUMN,
                                 f"expected position to increase past {xs[-2]}, got {xs[-1]}")
    if len(xs) < 2:
        raise CsvFormatError(p, 2, None, f"expected at least 2 track points, got {len(xs)}")
    return Track(np.asarray(xs), np.asarray(ys), p)


def write_track_csv(path: str | Path, track: Track) -> None:
    """Write a track CSV readable by :func:`read_track_csv`."""
    with open(path, "w", newline="", encoding="utf-8") as handle:
        handle.write(f"{POSITION_COLUMN},{ALIGNMENT_COLUMN}\n")
        for x, y in zip(track.position_m, track.alignment_m, strict=True):
            handle.write(f"{float(x)!r},{float(y)!r}\n")
