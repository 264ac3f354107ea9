"""A model in scaled coordinates, the form every estimation kernel works in.

The INS states differ by ten orders of magnitude (velocity ~0.1 m/s, gyro drift ~5e-8 rad/s), so
the arithmetic is done on x' = T^-1 x with T = diag(scale) (SPEC): every scaled state is of order
one. The model becomes::

    A' = T^-1 A T,   Qc' = T^-1 Qc T^-1,   B' = T^-1 B,   H' = H T

and its discretization Phi' = T^-1 Phi T, Qd' = T^-1 Qd T^-1, Bd' = T^-1 Bd. Covariances convert
as P = P' * SS with SS = s s^T.
"""
from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from .errors import CoreError
from .models import LinearModel
from .vanloan import VanLoanSeries


class ScaledModel:
    """``model`` in scaled coordinates: ``A``, ``Qc``, ``B`` ((n, 0) without input), ``H``,
    ``HT`` (scaled), ``s`` = scale, ``SS`` = s s^T, and its :class:`VanLoanSeries`."""

    def __init__(self, model: LinearModel) -> None:
        self.model = model
        self.n = n = model.n
        self.s = np.asarray(model.scale, dtype=float)
        self.inv_s = 1.0 / self.s
        self.SS = np.outer(self.s, self.s)
        self.A = np.ascontiguousarray(model.A * self.inv_s[:, None] * self.s[None, :])
        Qc = model.Qc / self.SS
        self.Qc = np.ascontiguousarray(0.5 * (Qc + Qc.T))
        self.B = (np.zeros((n, 0)) if model.B is None
                  else np.ascontiguousarray(model.B * self.inv_s[:, None]))
        self.p = self.B.shape[1]
        self.H = np.ascontiguousarray(model.H * self.s)
        self.HT = np.ascontiguousarray(self.H.T)
        self.I = np.eye(n)
        self.series = VanLoanSeries(self.A, self.Qc, self.B)

    def discretize_all(self, dt: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Scaled Phi (N, n, n), Qd (N, n, n), Bd (N, n, p) for every dt of an array."""
        from .discretize import discretize_all  # (numba: imported at the first use)

        return discretize_all(self.series, np.asarray(dt, dtype=float).reshape(-1))

    def to_scaled(self, x: np.ndarray | None, P: np.ndarray | None):
        xs = None if x is None else np.asarray(x, dtype=float) * self.inv_s
        Ps = None if P is None else np.asarray(P, dtype=float) / self.SS
        return xs, Ps

    def to_physical(self, xs: np.ndarray | None, Ps: np.ndarray | None):
        x = None if xs is None else xs * self.s
        P = None if Ps is None else Ps * self.SS
        return x, P


_SCALED: "weakref.WeakKeyDictionary[LinearModel, ScaledModel]" = weakref.WeakKeyDictionary()


def scaled_model(model: LinearModel) -> ScaledModel:
    """The (cached) scaled form of ``model``."""
    if not isinstance(model, LinearModel):
        raise CoreError(f"expected a LinearModel, got {type(model).__name__}")
    sm = _SCALED.get(model)
    if sm is None:
        sm = ScaledModel(model)
        _SCALED[model] = sm
    return sm
