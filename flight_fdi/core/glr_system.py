"""The GLR hypotheses as signature systems and the forward filter's arrays for the compiled
recursion (:mod:`flight_fdi.core.glr_kernel`); the math is in the :mod:`flight_fdi.core.glr`
docstring. Scaled coordinates throughout (x' = diag(scale)^-1 x); magnitudes in SI units."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from . import glr_kernel as kernel
from .discretize import VanLoanSeries
from .errors import CoreError
from .models import LinearModel
from .scaled import scaled_model

NONE = "none"


@dataclass(frozen=True)
class Hypothesis:
    """One fault hypothesis: ``kind`` step | ramp | jump | outlier, ``index`` the state (step,
    ramp) or measurement row (jump, outlier), ``scale`` SI units per scaled unit of the
    magnitude."""

    name: str
    kind: str
    index: int
    unit: str
    scale: float


def _measurement_unit(model: LinearModel, row: int) -> str:
    h = model.H[row]
    nz = np.flatnonzero(h)
    return model.state_units[nz[0]] if nz.size == 1 and h[nz[0]] == 1.0 else ""


def _state_hypothesis(model: LinearModel, name: str, sname: str, kind: str) -> Hypothesis:
    if sname not in model.state_names:
        raise CoreError(
            f"GlrConfig.hypotheses: {name!r} needs a state {sname!r}; model {model.name!r} has "
            f"states {', '.join(model.state_names)} (use '{kind}:<state>')")
    j = model.state_names.index(sname)
    unit = model.state_units[j]
    if kind == "ramp":  # per second: m/s^2 -> m/s^3, rad/s -> rad/s^2
        unit = (unit[:-4] + "/s^3" if unit.endswith("/s^2") else
                unit[:-2] + "/s^2" if unit.endswith("/s") else unit + "/s")
    return Hypothesis(name, kind, j, unit, float(model.scale[j]))


def _row_hypothesis(model: LinearModel, name: str, kind: str, mname: str | None) -> Hypothesis:
    if mname is None:
        if model.m != 1:
            raise CoreError(
                f"GlrConfig.hypotheses: {name!r} needs a one-row measurement; model "
                f"{model.name!r} measures {', '.join(model.measurement_names)} "
                f"(use '{kind}:<measurement>')")
        r = 0
    elif mname in model.measurement_names:
        r = model.measurement_names.index(mname)
    else:
        raise CoreError(f"GlrConfig.hypotheses: {name!r}: model {model.name!r} has no "
                        f"measurement {mname!r}; measurements are "
                        f"{', '.join(model.measurement_names)}")
    return Hypothesis(name, kind, r, _measurement_unit(model, r), 1.0)


def resolve(model: LinearModel, name: str) -> Hypothesis:
    """The hypothesis a name in ``GlrConfig.hypotheses`` stands for (glr module doc)."""
    for prefix, kind in (("step:", "step"), ("ramp:", "ramp")):
        if name.startswith(prefix):
            return _state_hypothesis(model, name, name[len(prefix):], kind)
    for prefix, kind in (("jump:", "jump"), ("outlier:", "outlier")):
        if name.startswith(prefix):
            return _row_hypothesis(model, name, kind, name[len(prefix):])
    if name in ("reference_jump", "reference_outlier"):
        return _row_hypothesis(model, name, name[10:], None)
    for suffix, kind in (("_step", "step"), ("_ramp", "ramp")):
        if name.endswith(suffix):
            return _state_hypothesis(model, name, name[:-5], kind)
    raise CoreError(f"GlrConfig.hypotheses: unknown hypothesis {name!r}; use '<state>_step', "
                    f"'step:<state>', '<state>_ramp', 'ramp:<state>', 'reference_jump', "
                    f"'jump:<measurement>', 'reference_outlier' or 'outlier:<measurement>'")


# --------------------------------------------------------------------------------------------
# the forward result

def _field(fwd: Any, name: str, shape: tuple, what: str = "") -> np.ndarray:
    if not hasattr(fwd, name):
        raise CoreError(f"isolate: the forward result has no field {name!r}")
    arr = np.asarray(getattr(fwd, name))
    if arr.shape != shape:
        raise CoreError(f"isolate: forward result field {name!r} has shape {arr.shape}, "
                        f"expected {shape}{what}")
    return arr


@dataclass
class Filter:
    """The forward filter in scaled coordinates, per sample k (N samples): H'_k, S_k^-1 and
    w_k = S_k^-1 nu_k (zero where the sample is missing), dt, the transitions A_k, G_k of the
    step k -> k+1 and the hypothesis-free blocks M_dd, lambda_d of step k+1 as their products
    with G_k (:func:`.glr_kernel.filter_information`)."""

    t: np.ndarray
    dt: np.ndarray
    H: np.ndarray
    Sinv: np.ndarray
    w: np.ndarray
    A: np.ndarray
    G: np.ndarray
    MG: np.ndarray
    GMG: np.ndarray
    Glam: np.ndarray

    def with_innovations(self, w: np.ndarray) -> "Filter":
        """The same filter with other S^-1 nu (the second pass): lambda_d recomputed, M_dd
        kept (it does not depend on the innovations)."""
        w = np.ascontiguousarray(w)
        Glam = np.empty_like(self.Glam)
        _, m, n = self.H.shape
        kernel.kernel_for("filter_information", n, m)(self.A, self.G, self.H, self.Sinv, w,
                                                      False, self.MG, self.GMG, Glam)
        return Filter(self.t, self.dt, self.H, self.Sinv, w, self.A, self.G, self.MG, self.GMG,
                      Glam)


def _checked(model: LinearModel, fwd: Any) -> tuple:
    n, m = model.n, model.m
    t = np.asarray(getattr(fwd, "t", None), dtype=float) if hasattr(fwd, "t") else None
    if t is None or t.ndim != 1 or t.size == 0:
        raise CoreError("isolate: the forward result needs a non-empty 1-D time array 't'")
    N = t.size
    dt = np.ascontiguousarray(_field(fwd, "dt", (N,)), dtype=float)  # (no copies: read only)
    nu = np.asarray(_field(fwd, "nu", (N, m), f" (model {model.name!r} has m = {m})"),
                    dtype=float)
    S = np.asarray(_field(fwd, "S", (N, m, m)), dtype=float)
    K = np.asarray(_field(fwd, "K", (N, n, m), f" (model {model.name!r} has n = {n})"),
                   dtype=float)
    H = np.asarray(_field(fwd, "H", (N, m, n)), dtype=float)
    fused = np.asarray(_field(fwd, "fused", (N,)), dtype=bool)
    if not np.all(np.isfinite(t)):
        raise CoreError("isolate: forward result time 't' contains NaN or Inf")
    if N > 1 and (not np.all(np.isfinite(dt[1:])) or np.any(dt[1:] < 0)):
        raise CoreError("isolate: forward result 'dt' must be finite and >= 0")
    valid = np.all(np.isfinite(nu), axis=1) & np.all(np.isfinite(S), axis=(1, 2))
    if np.any(fused & ~valid):
        k = int(np.flatnonzero(fused & ~valid)[0])
        raise CoreError(f"isolate: sample {k} was fused but its innovation or S is not finite")
    if not np.all(np.isfinite(K[fused])) or not np.all(np.isfinite(H)):
        raise CoreError("isolate: forward result gains 'K' (where fused) or 'H' are not finite")
    return t, dt, nu, S, K, H, fused, valid


def prepare(model: LinearModel, fwd: Any) -> Filter:
    """Check the forward result and compute the filter's part of the recursion."""
    t, dt, nu, S, K, H, fused, valid = _checked(model, fwd)
    N, m = nu.shape
    sc = model.scale
    Hs = np.ascontiguousarray(H * sc)                                     # H' = H T
    Ks = np.ascontiguousarray(np.where(fused[:, None, None], K / sc[:, None], 0.0))  # T^-1 K
    Sinv = np.zeros((N, m, m))
    w = np.zeros((N, m))
    if np.any(valid):
        if m == 1:
            s = S[valid, 0, 0]
            if np.any(s == 0.0):
                raise CoreError("isolate: an innovation covariance S is singular")
            Sinv[valid, 0, 0] = 1.0 / s
        else:
            try:
                Sinv[valid] = np.linalg.inv(S[valid])
            except np.linalg.LinAlgError:
                raise CoreError("isolate: an innovation covariance S is singular") from None
        w[valid] = np.einsum("kij,kj->ki", Sinv[valid], nu[valid])
    sm = scaled_model(model)
    n = model.n
    A, G = np.empty((N, n, n)), np.empty((N, n, m))
    kernel.transitions(sm.series.F, sm.series.norm, dt, Hs, Ks, A, G)
    MG, GMG, Glam = np.empty((N, n, m)), np.empty((N, m, m)), np.empty((N, m))
    kernel.kernel_for("filter_information", n, m)(A, G, Hs, Sinv, w, True, MG, GMG, Glam)
    return Filter(t, dt, Hs, Sinv, w, A, G, MG, GMG, Glam)


# --------------------------------------------------------------------------------------------
# a hypothesis as a signature system

def _reachable(Abar: np.ndarray, start: int) -> list:
    """The states a fault entering at ``start`` can reach through the nonzero entries of Abar
    (the others stay exactly zero): the fault state needs only these."""
    seen = [start]
    for i in seen:
        for j in np.flatnonzero(Abar[:, i]):
            if int(j) not in seen:
                seen.append(int(j))
    return seen


class System:
    """The fault state of one or more hypotheses (glr_kernel docstring): E, R_sel, Psi's series
    and, per hypothesis, the element i0 where its unit fault enters. A step in state j:
    beta' = A_bar beta (A with row j zeroed), beta(theta) = e_j; a ramp adds its rate r
    (beta_j' = r, r' = 0, r(theta) = 1). Only the states the fault reaches are kept, and a step
    shares the system of the ramp of the same state (its states are part of the ramp's, with the
    same dynamics). A jump or an outlier: one element in row r of z (the jumps and outliers of
    one row share a System, one element each).

    The ramp's rate r is carried in scaled units of state j per T seconds, T = 1 / ||A'||_1
    (the model's own time scale; ``rate_unit`` = 1 / T), not per second: the fault system's
    norm is then the model's, and Psi = expm(A_bar dt) needs no more series terms than Phi
    (``discretize.SHORT``). :meth:`scan`, :meth:`num` and :meth:`signature` return per-second
    values (l = num^2 / den does not depend on the unit)."""

    def __init__(self, model: LinearModel, hyps: list) -> None:
        n, m = model.n, model.m
        self.hyps = list(hyps)
        main = self.hyps[0]
        self.rate_unit = 1.0
        if main.kind in ("step", "ramp"):
            j = main.index
            ramp = main.kind == "ramp"
            sm = scaled_model(model)
            Abar = np.zeros((n + ramp, n + ramp))
            Abar[:n, :n] = sm.A
            Abar[j, :] = 0.0  # the instrument error stays at the step: beta_j' = 0
            if ramp:
                self.rate_unit = sm.series.norm if sm.series.norm > 0.0 else 1.0
                Abar[j, n] = self.rate_unit  # beta_j' = r (r in units of state j per T)
            keep = _reachable(Abar, n if ramp else j)
            E = np.zeros((n, len(keep)))
            for a, i in enumerate(keep):
                if i < n:
                    E[i, a] = 1.0
            self.E, self.R_sel = E, np.zeros((m, len(keep)))
            Ar = Abar[np.ix_(keep, keep)]
            self.persists = np.ones(len(keep), dtype=bool)
            self.i0 = np.array([keep.index(n if h.kind == "ramp" else j) for h in self.hyps])
        else:  # jumps and outliers of one measurement row: one element each
            q = len(self.hyps)
            self.E = np.zeros((n, q))
            self.R_sel = np.zeros((m, q))
            self.R_sel[main.index, :] = 1.0
            Ar = np.zeros((q, q))  # an offset persists (Psi = 1); an outlier is gone (Psi = 0)
            self.persists = np.array([h.kind == "jump" for h in self.hyps])
            self.i0 = np.arange(q)
        self.i0 = self.i0.astype(np.int64)
        series = VanLoanSeries(Ar, np.zeros_like(Ar), None)
        self.Fpsi, self.norm_psi = series.F, series.norm
        self._D: tuple = (None, None)

    def _args(self, flt: Filter) -> tuple:
        """(D_all, Fpsi, norm_psi, persists): the kernels' fault arguments for a filter, with
        D_k = H_k E + R_sel of every sample (how the fault state shows in the measurement;
        computed once per filter's H)."""
        if self._D[0] is not flt.H:
            N, m, _ = flt.H.shape
            D = np.empty((N, m, self.E.shape[1]))
            kernel.fault_measurement(flt.H, self.E, self.R_sel, D)
            self._D = (flt.H, D)
        return self._D[1], self.Fpsi, self.norm_psi, self.persists

    def _per_second(self, name: str) -> float:
        """The factor from the kernel's unit fault to one per second (1 but for a ramp: the
        kernel's unit rate is rate_unit per second, its signature rate_unit times as large)."""
        kind = next(h.kind for h in self.hyps if h.name == name)
        return 1.0 / self.rate_unit if kind == "ramp" else 1.0

    def scan(self, flt: Filter) -> dict:
        """{hypothesis name: (num, den, cross)} for every onset."""
        N, h = flt.t.size, len(self.hyps)
        num, den, cross = np.empty((h, N)), np.empty((h, N)), np.empty((h, N))
        _, m, n = flt.H.shape
        scan = kernel.kernel_for("hypothesis_scan", n, m, self.E.shape[1])
        scan(flt.A, flt.G, flt.H, flt.Sinv, flt.w, flt.dt, flt.MG, flt.GMG, flt.Glam,
             *self._args(flt), self.i0, num, den, cross)
        out = {}
        for i, hyp in enumerate(self.hyps):
            c = self._per_second(hyp.name)
            out[hyp.name] = ((num[i], den[i], cross[i]) if c == 1.0 else
                             (num[i] * c, den[i] * c ** 2, cross[i] * c ** 2))
        return out

    def num(self, flt: Filter) -> dict:
        """{hypothesis name: num} alone (the lambda recursion)."""
        out = np.empty((len(self.hyps), flt.t.size))
        _, m, n = flt.H.shape
        kernel.kernel_for("hypothesis_num", n, m, self.E.shape[1])(
            flt.w, flt.dt, flt.Glam, *self._args(flt), self.i0, out)
        return {hyp.name: out[i] * self._per_second(hyp.name) for i, hyp in enumerate(self.hyps)}

    def signature(self, flt: Filter, k0: int, name: str) -> np.ndarray:
        """rho_k (N, m) of a unit fault of hypothesis ``name`` starting at sample k0."""
        i0 = self.i0[[h.name for h in self.hyps].index(name)]
        rho = np.empty((flt.t.size, flt.H.shape[1]))
        kernel.signature(flt.A, flt.G, flt.H, flt.dt, *self._args(flt), int(i0), int(k0),
                         rho)
        c = self._per_second(name)
        return rho if c == 1.0 else rho * c


def systems(model: LinearModel, hyps: list) -> dict:
    """{hypothesis name: its System}: one System per hypothesis, except that a step shares the
    System of the ramp of the same state when both are tested, and the jumps and outliers of one
    measurement row share one System."""
    ramps = {h.index: h for h in hyps if h.kind == "ramp"}
    groups: dict = {}
    for h in hyps:
        key = (("ramp", h.index) if h.kind in ("step", "ramp") and h.index in ramps else
               ("row", h.index) if h.kind in ("jump", "outlier") else h.name)
        groups.setdefault(key, []).append(h)
    out = {}
    for members in groups.values():
        members.sort(key=lambda h: h.kind != "ramp")  # the ramp defines the fault state
        system = System(model, members)
        out.update({h.name: system for h in members})
    return out


def each_system(fn: Callable, systems: dict, threads: int = 1) -> dict:
    """The union of ``fn(system)`` (a dict by hypothesis name) over the distinct Systems of
    :func:`systems`; on ``threads`` threads when more than one (the compiled kernels release the
    GIL; the largest fault state first, so that two threads share the work evenly)."""
    distinct = sorted({id(s): s for s in systems.values()}.values(), key=lambda s: -s.E.shape[1])
    if threads > 1 and len(distinct) > 1:
        with ThreadPoolExecutor(max_workers=min(threads, len(distinct))) as pool:
            parts = list(pool.map(fn, distinct))
    else:
        parts = [fn(s) for s in distinct]
    out: dict = {}
    for part in parts:
        out.update(part)
    return out
