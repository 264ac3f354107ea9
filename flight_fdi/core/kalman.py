"""Forward Kalman filter with the beta^2 gate (SPEC section 2).

Two entry points share one algorithm, the compiled kernel :mod:`flight_fdi.core.filter_kernel`
(where the filter's equations are written out):

* :class:`KalmanFilter` -- a streaming filter, one sample at a time (what a ROS node calls);
* :func:`run_forward` -- the same filter over a whole record, returning every intermediate
  quantity as arrays (:class:`~flight_fdi.core.records.ForwardResult`).

For a one-row measurement (the INS channel) both call the kernel's ``step``, so they agree to the
last bit; updates with m > 1 rows use the numpy form of the same equations
(:mod:`flight_fdi.core.multirow`).
The arithmetic is done in scaled coordinates (:mod:`flight_fdi.core.scaled`), the update is in
Joseph form, and the covariance is kept exactly symmetric. Everything a caller sees is in
physical units. The gate and its alarm are :mod:`flight_fdi.core.gate`.

Failed measurement rows (redundant references, SPEC section 2, seed 001): ``KalmanFilter.update``
takes ``failed_rows`` and a ``mode`` -- ``nominal`` (ignore them), ``known_anomaly`` (KF2: their
R grows by C Gamma C^T) or ``exclude`` (AF: the rows E z only). The gains are those of
:mod:`flight_fdi.core.redundancy` (``kf2_gain``, ``af_gain``); beta^2 and its threshold are then
over the rows used. Which rows have failed is decided by :mod:`flight_fdi.core.references`.
"""
from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from .checks import (anomaly_covariance, check_dt, check_prior, check_R, check_times, check_u,
                     check_z, failed_rows)
from .errors import CoreError
from .gate import (ALARM_ACTIVE, ALARM_CLEAR, ALARM_CLEARED, ALARM_RAISED, GATE_ACTIONS,
                   GATE_RULES, AlarmLogic, GateConfig, alarm_states)
from .models import LinearModel
from .multirow import check_finite, overflow_error, update_failed_rows, update_rows
from .records import ForwardResult, MeasurementRecord, measurement_record, output_arrays
from .redundancy import accuracy
from .scaled import ScaledModel, scaled_model

__all__ = ["ALARM_ACTIVE", "ALARM_CLEAR", "ALARM_CLEARED", "ALARM_RAISED", "GATE_ACTIONS",
           "GATE_RULES", "UPDATE_MODES", "AlarmLogic", "ForwardResult", "GateConfig",
           "KalmanFilter", "MeasurementRecord", "ScaledModel", "UpdateResult", "alarm_states",
           "check_times", "measurement_record", "run_forward", "scaled_model"]

#: how ``KalmanFilter.update`` treats ``failed_rows``
UPDATE_MODES = ("nominal", "known_anomaly", "exclude")


class _KernelModule:
    """Stands for :mod:`flight_fdi.core.filter_kernel` until its first use, which imports it
    (and numba, ~0.2 s) and puts the module itself in its place: importing this module, or
    building a filter, does not load numba -- a filter node loads it at its first step."""

    def __getattr__(self, name: str) -> Any:
        from . import filter_kernel

        globals()["fk"] = filter_kernel
        return getattr(filter_kernel, name)


fk: Any = _KernelModule()


class Workspace:
    """The buffers of the kernel's ``step`` for an n-state, p-input model: the discretization
    held (``dt_held``, ``Phi``, ``Qd``, ``Bd``), scratch (``work``), and the prior, posterior and
    gain of the step."""

    def __init__(self, n: int, p: int) -> None:
        self.dt_held = np.full(1, np.nan)
        self.Phi, self.Qd, self.Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, p))
        self.work = np.empty((3, n, n))
        self.x_prior, self.P_prior = np.empty(n), np.empty((n, n))
        self.x_post, self.P_post, self.K = np.empty(n), np.empty((n, n)), np.empty(n)

    def held(self) -> tuple:
        """(dt_held, Phi, Qd, Bd, work): the arguments of ``predict_over`` after P."""
        return self.dt_held, self.Phi, self.Qd, self.Bd, self.work


# --------------------------------------------------------------------------- streaming filter

@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update (measurement units)."""

    nu: np.ndarray          # innovation z - H x_prior, (m,)
    S: np.ndarray           # innovation covariance, (m, m)
    beta2: float            # nu^T S^-1 nu
    threshold: float        # gate threshold for m rows
    exceeded: bool          # beta2 > threshold
    fused: bool             # the sample was fused (False only with action="reject")
    alarm_state: int        # ALARM_CLEAR / RAISED / ACTIVE / CLEARED
    row_beta2: np.ndarray   # nu_k^2 / S_kk per row
    # With failed rows (known_anomaly / exclude), what was fused; None = every row, R as given.
    # nu, S and row_beta2 are always the nominal ones (S = H P- H^T + R) of all m rows; beta2 and
    # threshold are over the rows used (known_anomaly: with S + C Gamma C^T).
    rows_used: tuple[int, ...] | None = None  # exclude: the rows E keeps (may be empty)
    R_used: np.ndarray | None = None          # known_anomaly: R + C Gamma C^T (m, m)


@dataclass(frozen=True)
class FilterSnapshot:
    """The whole state of a :class:`KalmanFilter` (scaled x, P, the alarm window, the step
    count), from :meth:`KalmanFilter.snapshot`, for :meth:`KalmanFilter.restore`."""

    x: np.ndarray
    P: np.ndarray
    alarm: tuple
    steps: int


class KalmanFilter:
    """Streaming Kalman filter over a :class:`LinearModel`, one sample at a time.

    ``predict(dt, u)`` then ``update(z, R, H)``, or ``step(dt, z, R, u)``. Bad input (non-finite
    z, R or dt, negative dt, R not positive semidefinite, wrong shapes) raises
    :class:`CoreError` and leaves the filter unchanged. ``x`` and ``P`` are in physical units.
    Several calls that must succeed or fail together go in ``with kf.transaction():``.
    """

    def __init__(self, model: LinearModel, gate: GateConfig = GateConfig(),
                 x0: Any = None, P0: Any = None) -> None:
        if not isinstance(gate, GateConfig):
            raise CoreError(f"gate must be a GateConfig, got {type(gate).__name__}")
        self.model = model
        self.gate = gate
        sm = self._sm = scaled_model(model)
        n = sm.n
        self._vl = sm.series.args()
        self._h = np.ascontiguousarray(sm.H[0])
        self._threshold1 = gate.threshold(1)
        self._no_u = np.zeros(sm.p)
        # the kernel's buffers: the discretization of the last dt, and the prior and posterior
        # it writes (a step is committed by swapping the posterior in)
        self._ws = Workspace(n, sm.p)
        self._alarm = AlarmLogic(gate.alarm_m, gate.alarm_n)
        self._reject = gate.action == "reject"
        self.reset(x0, P0)

    def reset(self, x0: Any = None, P0: Any = None) -> None:
        """Back to the prior (x0 default zeros, P0 default model.P0); clears the alarm."""
        x, P = check_prior(self.model, x0, P0)
        xs, Ps = self._sm.to_scaled(x, P)
        self._x = np.ascontiguousarray(xs)
        self._P = np.ascontiguousarray(Ps)
        self._alarm.reset()
        self.steps = 0

    @property
    def x(self) -> np.ndarray:
        """Current state estimate, physical units."""
        return self._x * self._sm.s

    @property
    def P(self) -> np.ndarray:
        """Current covariance, physical units."""
        return self._P * self._sm.SS

    def state_lists(self) -> tuple[list[float], list[float]]:
        """(x, P row-major) in physical units as plain lists: the same numbers as ``x`` and
        ``P.ravel()``, for a node's per-message output."""
        return self.x.tolist(), self.P.ravel().tolist()

    @property
    def alarm_active(self) -> bool:
        return self._alarm.active

    # -- transactions

    def snapshot(self) -> FilterSnapshot:
        """The filter's whole state, for :meth:`restore`."""
        a = self._alarm
        return FilterSnapshot(self._x.copy(), self._P.copy(),
                              (list(a._window), a._pos, a._count, a.active), self.steps)

    def restore(self, snap: FilterSnapshot) -> None:
        """Back to a state from :meth:`snapshot` (of this filter)."""
        if not isinstance(snap, FilterSnapshot) or snap.x.shape != self._x.shape:
            raise CoreError("restore: not a snapshot of this filter")
        self._x, self._P = snap.x.copy(), snap.P.copy()
        a = self._alarm
        window, a._pos, a._count, a.active = snap.alarm
        a._window = list(window)
        self.steps = snap.steps

    @contextlib.contextmanager
    def transaction(self) -> Iterator["KalmanFilter"]:
        """``with kf.transaction(): kf.predict(...); kf.update(...)`` -- when anything inside
        raises, the filter is put back as it was before the block."""
        snap = self.snapshot()
        try:
            yield self
        except BaseException:
            self.restore(snap)
            raise

    # -- the filter

    def predict(self, dt: float, u: Any = None) -> None:
        """Propagate over ``dt`` seconds (>= 0) with optional control input ``u``."""
        dt = check_dt(dt)
        uv = check_u(self.model, u)
        ws = self._ws
        fk.predict_over(*self._vl, dt, self._no_u if uv is None else uv, self._x, self._P,
                        *ws.held(), ws.x_prior, ws.P_prior)
        self._x, ws.x_prior = ws.x_prior, self._x
        self._P, ws.P_prior = ws.P_prior, self._P

    def _commit_post(self, status: int, nu: float, s: float, beta2: float) -> None:
        """Take the kernel's posterior as the state, or raise (the state unchanged)."""
        if status == fk.S_NOT_POSITIVE:
            raise CoreError(f"innovation covariance S = {s:.3g} is not positive")
        if status == fk.NOT_FINITE:
            raise overflow_error(nu, beta2)
        ws = self._ws
        self._x, ws.x_post = ws.x_post, self._x
        self._P, ws.P_post = ws.P_post, self._P

    def _measurement(self, z: Any, R: Any, H: Any):
        """Validated (z, R, scaled H, its transpose)."""
        sm = self._sm
        if H is None:
            Hs, HsT = sm.H, sm.HT
        else:
            Hp = np.asarray(H, dtype=float)
            if Hp.ndim == 1:
                Hp = Hp.reshape(1, -1)
            if Hp.ndim != 2 or Hp.shape[1] != sm.n or not np.all(np.isfinite(Hp)):
                raise CoreError(f"H must be a finite matrix with {sm.n} columns")
            Hs = np.ascontiguousarray(Hp * sm.s)
            HsT = np.ascontiguousarray(Hs.T)
        m = Hs.shape[0]
        zv = check_z(z, m)
        if R is None:
            if m != self.model.m:
                raise CoreError(f"R must be given for a {m}-row H (the model has {self.model.m})")
            Rm = self.model.R
        else:
            Rm = check_R(R, m)
        return zv, Rm, Hs, HsT

    def innovation(self, z: Any, R: Any = None, H: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """The innovation ``nu = z - H x`` and its covariance ``S = H P H^T + R`` against the
        current state (after ``predict``: the prior), without changing the filter."""
        zv, Rm, Hs, HsT = self._measurement(z, R, H)
        return self._innovation(zv, Rm, Hs, HsT)

    def _innovation(self, zv: np.ndarray, Rm: np.ndarray, Hs: np.ndarray, HsT: np.ndarray):
        nu = zv - Hs.dot(self._x)
        S = Hs.dot(self._P).dot(HsT) + Rm
        return nu, 0.5 * (S + S.T)

    def update(self, z: Any, R: Any = None, H: Any = None, failed_rows: Any = (),
               mode: str = "nominal", Gamma: Any = None) -> UpdateResult:
        """Fuse measurement ``z`` (R default model.R, H default model.H).

        ``failed_rows`` (row indices of z) are handled by ``mode``: ``"nominal"`` -- ignored (the
        plain filter); ``"known_anomaly"`` -- KF2, ``S = H P- H^T + R + C Gamma C^T`` with
        ``Gamma`` the anomaly variance of each failed row (a number, one per failed row in
        increasing row order, or an r x r matrix); ``"exclude"`` -- AF, the failed rows are
        struck out (``E z``). beta^2 and the gate threshold are then over the rows used; when
        every row is excluded nothing is fused (``fused`` False, beta2 0, threshold NaN, the
        alarm window is not advanced). The gains are ``redundancy.kf2_gain`` /
        ``redundancy.af_gain``; the covariance update is the Joseph form with the R used.
        """
        if mode not in UPDATE_MODES:
            raise CoreError(f"update mode must be one of {UPDATE_MODES}, got {mode!r}")
        zv, Rm, Hs, HsT = self._measurement(z, R, H)
        return self._update_checked(zv, Rm, Hs, HsT, failed_rows, mode, Gamma)

    def _update_checked(self, zv: np.ndarray, Rm: np.ndarray, Hs: np.ndarray, HsT: np.ndarray,
                        failed_rows_: Any, mode: str, Gamma: Any) -> UpdateResult:
        """``update`` after ``_measurement`` validated z, R and H."""
        m = Hs.shape[0]
        failed = failed_rows(failed_rows_, m)
        if failed and mode != "nominal":
            return self._update_failed(zv, Rm, Hs, failed, mode, Gamma)
        thr = self.gate.threshold(m)
        if m == 1:
            ws = self._ws
            status, nu, s, beta2, exceeded, fused = fk.update(
                self._x, self._P, np.ascontiguousarray(Hs[0]), float(Rm[0, 0]), float(zv[0]),
                thr, self._reject, ws.x_post, ws.P_post, ws.K, ws.work)
            self._commit_post(status, nu, s, beta2)
            return self._result(nu, s, beta2, thr, exceeded, fused)
        x, P, nu, S, _, beta2, exceeded, fused = update_rows(
            self._x, self._P, zv, Rm, Hs, HsT, self._sm.I, thr, self._reject)
        check_finite(x, P, beta2, nu, S)
        self._x, self._P = x, P
        self.steps += 1
        state = self._alarm.push(exceeded)
        return UpdateResult(nu=nu, S=S, beta2=float(beta2), threshold=thr,
                            exceeded=bool(exceeded), fused=bool(fused), alarm_state=state,
                            row_beta2=nu * nu / np.diag(S))

    def _update_failed(self, zv: np.ndarray, Rm: np.ndarray, Hs: np.ndarray,
                       failed: tuple[int, ...], mode: str, Gamma: Any) -> UpdateResult:
        G = anomaly_covariance(Gamma, len(failed)) if mode == "known_anomaly" else None
        x, P, nu, S, beta2, thr, exceeded, fused, used, R_used = update_failed_rows(
            self._x, self._P, zv, Rm, Hs, self._sm.I, failed, mode, G, self.gate, self._reject)
        check_finite(x, P, beta2, nu, S)
        self._x, self._P = x, P
        self.steps += 1
        if used:
            state = self._alarm.push(exceeded)
        else:  # nothing fused: the alarm window is not advanced
            state = ALARM_ACTIVE if self._alarm.active else ALARM_CLEAR
        return UpdateResult(nu=nu, S=S, beta2=float(beta2), threshold=thr,
                            exceeded=bool(exceeded), fused=bool(fused), alarm_state=state,
                            row_beta2=nu * nu / np.diag(S), rows_used=used, R_used=R_used)

    def _result(self, nu: float, s: float, beta2: float, thr: float, exceeded: bool,
                fused: bool) -> UpdateResult:
        """Count a committed one-row update and push its gate result to the alarm."""
        self.steps += 1
        state = self._alarm.push(exceeded)
        return UpdateResult(nu=np.array([nu]), S=np.array([[s]]), beta2=beta2, threshold=thr,
                            exceeded=bool(exceeded), fused=bool(fused), alarm_state=state,
                            row_beta2=np.array([beta2]))

    def accuracy(self, D: Any = None) -> float:
        """The seed's estimation accuracy J = tr(D P) of the current covariance
        (``redundancy.accuracy``). ``D`` (n x n, physical units) defaults to the identity on the
        scaled states, D = diag(1 / scale^2): J = sum_i P_ii / scale_i^2, dimensionless (the
        prior std of every state counts as 1)."""
        if D is None:
            return accuracy(self._sm.I, self._P)
        Dm = np.asarray(D, dtype=float)
        if Dm.shape != (self._sm.n, self._sm.n) or not np.all(np.isfinite(Dm)):
            raise CoreError(f"D must be a finite {self._sm.n} x {self._sm.n} matrix")
        return accuracy(Dm, self.P)

    def step(self, dt: float, z: Any, R: Any = None, u: Any = None) -> UpdateResult:
        """predict(dt, u) then update(z, R); everything is validated before the state changes.
        For a one-row model this is the kernel step that ``run_forward`` runs."""
        m = self.model.m
        zv = check_z(z, m)
        Rm = self.model.R if R is None else check_R(R, m)
        dt = check_dt(dt)
        uv = check_u(self.model, u)
        if m != 1:
            with self.transaction():
                self.predict(dt, uv)
                return self.update(zv, Rm)
        return self._step1(dt, float(zv[0]), float(Rm[0, 0]), uv)

    def step1(self, dt: float, z: float, r: float) -> UpdateResult:
        """:meth:`step` of a one-row model without a control input, on plain numbers: the
        same kernel, for a node's per-message path (NumPy's checks of a one-element z and R
        cost more than the step itself). CoreError, filter unchanged, on bad input."""
        if self.model.m != 1:
            raise CoreError(f"step1 needs a one-row model; {self.model.name!r} has "
                            f"{self.model.m} rows")
        try:
            zf, rf = float(z), float(r)
        except (TypeError, ValueError):
            raise CoreError(f"step1: z and r must be numbers, got {z!r}, {r!r}") from None
        if not math.isfinite(zf):
            raise CoreError(f"measurement z contains NaN or Inf: [{zf!r}]")
        if not math.isfinite(rf):
            raise CoreError("measurement covariance R contains NaN or Inf")
        if rf < 0:
            raise CoreError(f"measurement covariance R = {rf:.3g} is negative")
        return self._step1(check_dt(dt), zf, rf, None)

    def _step1(self, dt: float, z: float, r: float, uv: np.ndarray | None) -> UpdateResult:
        """The kernel's one-row prediction + update on validated inputs."""
        thr = self._threshold1
        ws = self._ws
        status, nu, s, beta2, exceeded, fused = fk.step(
            *self._vl, self._h, dt, self._no_u if uv is None else uv, z, r, thr, self._reject,
            self._x, self._P, *ws.held(), ws.x_prior, ws.P_prior, ws.x_post, ws.P_post, ws.K)
        self._commit_post(status, nu, s, beta2)
        return self._result(nu, s, beta2, thr, exceeded, fused)


# --------------------------------------------------------------------------- batch

def run_forward(model: LinearModel, t: Any, z: Any, R: Any = None, u: Any = None,
                gate: GateConfig = GateConfig(), x0: Any = None, P0: Any = None,
                record: MeasurementRecord | None = None) -> ForwardResult:
    """Run the forward filter over a record (the kernel step of :class:`KalmanFilter`).

    t: (N,) strictly increasing seconds; z: (N, m) (or (N,) when m = 1); R: None (model.R) or
    (N, m, m); u: None or (N, p), the control applied in the prediction to step k. The first step
    is an update on the prior (x0, P0) (default 0, model.P0). ``record``: the same inputs already
    checked by :func:`measurement_record` (then t, z, R and u are not used).
    """
    if not isinstance(gate, GateConfig):
        raise CoreError(f"gate must be a GateConfig, got {type(gate).__name__}")
    sm = scaled_model(model)
    n, m = model.n, model.m
    if record is None:
        record = measurement_record(model, t, z, R, u)
    elif not isinstance(record, MeasurementRecord):
        raise CoreError(f"record must be a MeasurementRecord, got {type(record).__name__}")
    N = len(record)
    x0v, P0m = check_prior(model, x0, P0)
    xs0, Ps0 = sm.to_scaled(x0v, P0m)
    thr = gate.threshold(m)
    ua = np.zeros((N, sm.p)) if record.u is None else np.ascontiguousarray(record.u)
    out = output_arrays({"x_prior": (N, n), "P_prior": (N, n, n), "x": (N, n), "P": (N, n, n),
                         "K": (N, n, m), "nu": (N, m), "S": (N, m, m), "beta2": (N,)})
    out["fused"] = np.empty(N, dtype=bool)
    args = (xs0, Ps0, record.dt, ua, record.z, record.R, thr, gate.action == "reject")
    if m == 1:
        _forward1(sm, *args, out)
    else:
        _forward_rows(sm, *args, out)
    exceeded = out["beta2"] > thr
    return ForwardResult(
        t=record.t, dt=record.dt, z=record.z, R=record.R, H=record.H, u=record.u, gate=gate,
        threshold=np.full(N, thr), exceeded=exceeded, alarm_state=alarm_states(exceeded, gate),
        **out)


def _forward1(sm: ScaledModel, x0: np.ndarray, P0: np.ndarray, dt: np.ndarray, u: np.ndarray,
              z: np.ndarray, R: np.ndarray, thr: float, reject: bool, out: dict) -> None:
    """The one-row record through the kernel's ``forward_pass`` (physical outputs into
    ``out``)."""
    N = dt.size
    S, K = out["S"].reshape(N), out["K"].reshape(N, sm.n)   # (views: m = 1)
    bad, status = fk.forward_pass(
        *sm.series.args(), np.ascontiguousarray(sm.H[0]), x0, P0, dt, u,
        np.ascontiguousarray(z[:, 0]), np.ascontiguousarray(R[:, 0, 0]), thr, reject, sm.s,
        sm.SS, out["x_prior"], out["P_prior"], out["x"], out["P"], K, out["nu"].reshape(N), S,
        out["beta2"], out["fused"])
    if status == fk.S_NOT_POSITIVE:
        raise CoreError(f"step {bad}: innovation covariance S = {S[bad]:.3g} is not positive")
    if status == fk.NOT_FINITE:
        raise CoreError(f"step {bad}: {overflow_error(out['nu'][bad], out['beta2'][bad])}")


def _forward_rows(sm: ScaledModel, x: np.ndarray, P: np.ndarray, dt: np.ndarray, u: np.ndarray,
                  z: np.ndarray, R: np.ndarray, thr: float, reject: bool, out: dict) -> None:
    """A record with m > 1 rows: the kernel's prediction and the numpy update, step by step."""
    held = Workspace(sm.n, sm.p).held()
    vl = sm.series.args()
    for k in range(dt.size):
        fk.predict_over(*vl, float(dt[k]), u[k], x, P, *held, out["x_prior"][k],
                        out["P_prior"][k])
        x, P, out["nu"][k], out["S"][k], out["K"][k], out["beta2"][k], _, out["fused"][k] = \
            update_rows(out["x_prior"][k], out["P_prior"][k], z[k], R[k], sm.H, sm.HT, sm.I, thr,
                    reject)
        out["x"][k], out["P"][k] = x, P
    s, SS = sm.s, sm.SS
    for name, scale in (("x_prior", s), ("x", s), ("P_prior", SS), ("P", SS)):
        out[name] *= scale
    out["K"] *= s[None, :, None]
