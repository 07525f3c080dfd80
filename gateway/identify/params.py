"""The identification parameter space: every model parameter by name, nominal and tolerance.

A *parameter point* is the full set of 25 model parameters (the 22 fields of
:class:`gateway.model.vehicle.VehicleParams` plus the monitored ``theta`` = Csy, Csay, conicity),
all in SI units and named as in the model (``ksy_n_per_m``, ``csy_ns_per_m``...).
Optimisers work on a short vector of *free* parameters in relative units:
``value = nominal * (1 + u)`` with ``u`` in ``[-tolerance, +tolerance]``, optionally
followed by one more entry for the track position offset (:class:`OffsetRange`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from gateway.errors import InputError
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL, VehicleParams

VEHICLE_NAMES: tuple[str, ...] = tuple(f.name for f in fields(VehicleParams))
"""The fixed-parameter names, in dataclass order."""
ALL_NAMES: tuple[str, ...] = VEHICLE_NAMES + PARAM_NAMES
"""All 25 model parameters: VehicleParams fields, then Csy, Csay, conicity."""

SHORT_NAMES: dict[str, str] = {
    "mw_kg": "mw", "iw_kgm2": "Iw", "mb_kg": "mb", "ib_kgm2": "Ib", "mbd_kg": "mbd",
    "ky_n_per_m": "Ky", "kray_n_per_m": "Kray", "kx_n_per_m": "Kx", "ksy_n_per_m": "Ksy",
    "ksry_n_per_m": "Ksry", "ksarb_n_per_m": "Ksarb", "ksyaw_nm_per_rad": "Ksyaw",
    "f11_n": "f11", "f22_n": "f22", "a_m": "a", "b_m": "b", "c_m": "c", "d_m": "d",
    "e_m": "e", "l_m": "l", "lbw_m": "lbw", "r0_m": "r0",
    "csy_ns_per_m": "Csy", "csay_ns_per_m": "Csay", "conicity": "lambda",
}
"""Symbols as the papers write them, for tables and plots."""


def nominal_values() -> dict[str, float]:
    """The nominal point: Appendix VehicleParams and Appendix dampers (THETA_NOMINAL)."""
    values = {k: float(v) for k, v in asdict(VehicleParams()).items()}
    values.update(zip(PARAM_NAMES, THETA_NOMINAL.as_array().tolist(), strict=True))
    return values


def resolve_names(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Full names for a list of full or short names (``Ksy`` or ``ksy_n_per_m``)."""
    by_short = {s.lower(): n for n, s in SHORT_NAMES.items()}
    out = []
    for name in names:
        if name in ALL_NAMES:
            out.append(name)
        elif name.lower() in by_short:
            out.append(by_short[name.lower()])
        else:
            raise InputError(f"expected parameter names from {list(SHORT_NAMES.values())} "
                             f"or {list(ALL_NAMES)}, got {name!r}")
    if len(set(out)) != len(out):
        raise InputError(f"expected distinct parameter names, got {list(names)}")
    return tuple(out)


@dataclass(frozen=True)
class ParamPoint:
    """A complete model parameter set; ``values`` maps every name in ALL_NAMES to SI."""

    values: tuple[tuple[str, float], ...]

    @classmethod
    def from_dict(cls, values: dict[str, float]) -> ParamPoint:
        missing = [n for n in ALL_NAMES if n not in values]
        unknown = [n for n in values if n not in ALL_NAMES]
        if missing or unknown:
            raise InputError(f"expected exactly the parameters {list(ALL_NAMES)}, "
                             f"got missing {missing}, unknown {unknown}")
        return cls(tuple((n, float(values[n])) for n in ALL_NAMES))

    @classmethod
    def nominal(cls) -> ParamPoint:
        return cls.from_dict(nominal_values())

    def as_dict(self) -> dict[str, float]:
        return dict(self.values)

    def vehicle(self) -> VehicleParams:
        """The fixed parameters as the model's VehicleParams."""
        d = self.as_dict()
        return VehicleParams(**{n: d[n] for n in VEHICLE_NAMES})

    def theta(self) -> np.ndarray:
        """(Csy [N s/m], Csay [N s/m], conicity [-]), shape (3,)."""
        d = self.as_dict()
        return np.array([d[n] for n in PARAM_NAMES])

    def with_values(self, **changes: float) -> ParamPoint:
        d = self.as_dict()
        unknown = [n for n in changes if n not in d]
        if unknown:
            raise InputError(f"expected parameter names from {list(ALL_NAMES)}, got {unknown}")
        d.update({k: float(v) for k, v in changes.items()})
        return ParamPoint.from_dict(d)

    def scaled(self, factors: dict[str, float]) -> ParamPoint:
        """A copy with ``values[name] *= factor`` for each entry of ``factors``."""
        d = self.as_dict()
        return self.with_values(**{k: d[k] * f for k, f in factors.items()})


@dataclass(frozen=True)
class OffsetRange:
    """The track position offset as a free dimension: ``base_m + half_width_m * v``.

    ``base_m`` (m) is the given registration (odometry), ``half_width_m`` (m) the
    uncertainty either side; the optimiser's coordinate ``v`` lies in [-1, 1].
    """

    base_m: float
    half_width_m: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.base_m) and math.isfinite(self.half_width_m)
                and self.half_width_m > 0):
            raise InputError(f"expected a finite offset and a positive half-width in m, got "
                             f"{self.base_m} and {self.half_width_m}")

    def offset_m(self, v: float) -> float:
        """The offset [m] at coordinate ``v``."""
        return self.base_m + self.half_width_m * float(v)

    def coordinate(self, offset_m: float) -> float:
        """The coordinate ``v`` of ``offset_m`` [m]."""
        return (float(offset_m) - self.base_m) / self.half_width_m


@dataclass(frozen=True)
class FreeSpace:
    """The free parameters of a fit and their box: ``value = base * (1 + u)``.

    ``names`` (k,) full names; ``tolerance`` (k,) relative half-widths of the box.
    Parameters not named stay at ``base``. With ``offset``, the optimiser's vector has
    one more entry, last, the track-offset coordinate of :class:`OffsetRange`.
    """

    names: tuple[str, ...]
    tolerance: tuple[float, ...]
    base: ParamPoint
    offset: OffsetRange | None = None

    def __post_init__(self) -> None:
        if len(self.names) != len(self.tolerance) or not self.names:
            raise InputError(f"expected one tolerance per free parameter, got "
                             f"{len(self.names)} names and {len(self.tolerance)} tolerances")
        for n, t in zip(self.names, self.tolerance, strict=True):
            if not 0 < t < 1:
                raise InputError(f"expected a tolerance in (0, 1) for {n}, got {t}")

    @classmethod
    def uniform(cls, names: tuple[str, ...], tolerance: float,
                base: ParamPoint | None = None, offset: OffsetRange | None = None) -> FreeSpace:
        return cls(tuple(names), (float(tolerance),) * len(names), base or ParamPoint.nominal(),
                   offset)

    @property
    def size(self) -> int:
        """Length of the optimiser's vector: k, plus one with a free offset."""
        return len(self.names) + (self.offset is not None)

    @property
    def bounds(self) -> list[tuple[float, float]]:
        """Box of the optimiser's vector: one (low, high) per name, then (-1, 1) for the offset."""
        box = [(-t, t) for t in self.tolerance]
        return box + [(-1.0, 1.0)] if self.offset is not None else box

    def _vector(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape != (self.size,):
            raise InputError(f"expected {self.size} free coordinates, got {u.shape}")
        return u

    def point(self, u: np.ndarray) -> ParamPoint:
        """The full parameter point for the optimiser's vector ``u`` (size,)."""
        u = self._vector(u)
        d = self.base.as_dict()
        return self.base.with_values(**{n: d[n] * (1.0 + float(x))
                                        for n, x in zip(self.names, u, strict=False)})

    def offset_m(self, u: np.ndarray) -> float | None:
        """The track offset [m] at ``u`` (size,), or None when the offset is not free."""
        u = self._vector(u)
        return None if self.offset is None else self.offset.offset_m(u[-1])

    def relative(self, point: ParamPoint, offset_m: float | None = None) -> np.ndarray:
        """The optimiser's vector (size,) of ``point`` and, with a free offset, ``offset_m``."""
        d, b = point.as_dict(), self.base.as_dict()
        u = [d[n] / b[n] - 1.0 for n in self.names]
        if self.offset is not None:
            if offset_m is None:
                raise InputError("expected a track offset in m for the free offset, got None")
            u.append(self.offset.coordinate(offset_m))
        return np.array(u)
