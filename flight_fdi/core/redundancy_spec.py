"""The ``redundancy:`` section of a model file (seed 001; docs/criticality.md): the redundant
sensors (their measurement rows and anomaly variances), the weight D of J = tr(D P), the bound of
an admissible fault set. Used by :func:`flight_fdi.core.redundancy.criticality`."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import CoreError
from .models import LinearModel, model_from_dict, read_yaml

#: largest number of sensors whose 2^s fault sets are enumerated
MAX_SENSORS = 12


@dataclass(frozen=True)
class Sensor:
    """A redundant sensor: its measurement rows and the anomaly variance of each row."""

    name: str
    rows: tuple[int, ...]
    gamma: tuple[float, ...]


@dataclass(frozen=True, eq=False)
class RedundancySpec:
    """The ``redundancy:`` section of a model file (see docs/criticality.md)."""

    dt: float
    sensors: tuple[Sensor, ...]
    D: np.ndarray                 # n x n weight of J = tr(D P)
    bound: float                  # J above the bound: inadmissible fault set
    vital_threshold: float = 0.01  # relative growth of J making a sensor vital
    max_failed: int | None = None  # enumerate fault sets up to this many failed sensors

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    def gamma_rows(self, m: int) -> np.ndarray:
        """Anomaly variance per measurement row (NaN for rows of no sensor)."""
        g = np.full(m, math.nan)
        for s in self.sensors:
            g[list(s.rows)] = s.gamma
        return g

    def rows_of(self, failed: Sequence[int]) -> list[int]:
        return sorted(r for k in failed for r in self.sensors[k].rows)


def _positive(value: Any, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CoreError(f"{what}: {value!r} is not a number") from None
    if not math.isfinite(v) or v <= 0:
        raise CoreError(f"{what}: must be a positive number, got {value!r}")
    return v


def redundancy_from_dict(data: Any, model: LinearModel, source: str = "model") -> RedundancySpec:
    """Validate the ``redundancy:`` mapping against ``model`` (see docs/criticality.md)."""
    what = f"{source}: redundancy"
    if not isinstance(data, Mapping):
        raise CoreError(f"{what}: expected a mapping (dt, sensors, D, bound, ...)")
    unknown = set(data) - {"dt", "sensors", "D", "bound", "vital_threshold", "max_failed"}
    if unknown:
        raise CoreError(f"{what}: unknown keys {sorted(unknown)}")
    for key in ("dt", "sensors", "bound"):
        if key not in data:
            raise CoreError(f"{what}: missing key {key!r}")
    dt = _positive(data["dt"], f"{what}.dt")
    bound = _positive(data["bound"], f"{what}.bound")
    vital = _positive(data.get("vital_threshold", 0.01), f"{what}.vital_threshold")
    n, m = model.n, model.m
    sensors_data = data["sensors"]
    if not isinstance(sensors_data, Sequence) or isinstance(sensors_data, str) or not sensors_data:
        raise CoreError(f"{what}.sensors: expected a non-empty list of {{name, rows, gamma}}")
    if len(sensors_data) > MAX_SENSORS:
        raise CoreError(f"{what}.sensors: {len(sensors_data)} sensors; at most {MAX_SENSORS} "
                        f"(2^s fault sets are enumerated)")
    sensors, used, names = [], set(), set()
    for k, sd in enumerate(sensors_data):
        sw = f"{what}.sensors[{k}]"
        if not isinstance(sd, Mapping):
            raise CoreError(f"{sw}: expected a mapping with name, rows, gamma")
        extra = set(sd) - {"name", "rows", "gamma"}
        if extra:
            raise CoreError(f"{sw}: unknown keys {sorted(extra)}")
        name = str(sd.get("name", f"sensor{k + 1}"))
        if name in names:
            raise CoreError(f"{sw}: sensor name {name!r} used twice")
        names.add(name)
        rows = sd.get("rows")
        if isinstance(rows, (int, np.integer)) and not isinstance(rows, bool):
            rows = [rows]
        if not isinstance(rows, Sequence) or isinstance(rows, str) or not rows:
            raise CoreError(f"{sw} ({name}): 'rows' must be a non-empty list of row indices "
                            f"of H (0..{m - 1})")
        for r in rows:
            if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or not 0 <= r < m:
                raise CoreError(f"{sw} ({name}): row {r!r} is not a row index of H "
                                f"(0..{m - 1})")
            if r in used:
                raise CoreError(f"{sw} ({name}): row {r} belongs to two sensors")
            used.add(int(r))
        if "gamma" not in sd:
            raise CoreError(f"{sw} ({name}): missing 'gamma' (anomaly variance for KF2)")
        g = sd["gamma"]
        gl = list(g) if isinstance(g, Sequence) and not isinstance(g, str) else [g] * len(rows)
        if len(gl) != len(rows):
            raise CoreError(f"{sw} ({name}): gamma gives {len(gl)} variances for {len(rows)} rows")
        gamma = tuple(_positive(v, f"{sw} ({name}).gamma") for v in gl)
        sensors.append(Sensor(name, tuple(int(r) for r in rows), gamma))
    D_raw = data.get("D", [1.0] * n)
    try:
        D = np.array(D_raw, dtype=float)
    except (TypeError, ValueError):
        raise CoreError(f"{what}.D: not a numeric vector or matrix") from None
    if D.ndim == 1 and D.shape == (n,):
        D = np.diag(D)
    if D.shape != (n, n) or not np.all(np.isfinite(D)):
        raise CoreError(f"{what}.D: expected {n} weights or an {n} x {n} matrix, got shape "
                        f"{D.shape}")
    if not np.allclose(D, D.T) or np.min(np.linalg.eigvalsh(0.5 * (D + D.T))) < \
            -1e-12 * max(1.0, float(np.abs(D).max())):
        raise CoreError(f"{what}.D: must be symmetric positive semidefinite")
    if not np.any(D):
        raise CoreError(f"{what}.D: all weights are zero")
    max_failed = data.get("max_failed")
    if max_failed is not None:
        if isinstance(max_failed, bool) or not isinstance(max_failed, int) \
                or not 0 <= max_failed <= len(sensors):
            raise CoreError(f"{what}.max_failed: must be an integer in 0..{len(sensors)}")
    D.setflags(write=False)
    return RedundancySpec(dt, tuple(sensors), D, bound, vital, max_failed)


def redundant_model_from_dict(data: Any, source: str = "model"
                              ) -> tuple[LinearModel, RedundancySpec]:
    """A model mapping with a ``redundancy:`` section -> (LinearModel, RedundancySpec)."""
    if not isinstance(data, Mapping):
        raise CoreError(f"{source}: expected a mapping at the top level")
    if "redundancy" not in data:
        raise CoreError(f"{source}: no 'redundancy:' section (which rows belong to which sensor, "
                        "gamma, D, bound; see docs/criticality.md)")
    rest = {k: v for k, v in data.items() if k != "redundancy"}
    model = model_from_dict(rest, source)
    return model, redundancy_from_dict(data["redundancy"], model, source)


def load_redundant_model(path: str | Path) -> tuple[LinearModel, RedundancySpec]:
    """Load a model YAML file with a ``redundancy:`` section."""
    return redundant_model_from_dict(read_yaml(path), str(path))
