"""Forward Kalman filter with the beta^2 gate (SPEC section 2).

Two entry points share one algorithm:

* :class:`KalmanFilter` -- a streaming filter, one sample at a time (what a ROS node calls);
* :func:`run_forward` -- the same filter over a whole record, returning every intermediate
  quantity as arrays (:class:`ForwardResult`).

Both call the same step functions (see "the algorithm" below), so they agree to the last bit.
The arithmetic is done in scaled coordinates ``x' = T^-1 x`` with ``T = diag(model.scale)``
(the INS states differ by ten orders of magnitude), the update is in Joseph form, and the
covariance is kept exactly symmetric (only its upper triangle is computed). Everything a caller
sees is in physical units.

Gate: ``beta2 = nu^T S^-1 nu`` is chi-square with m degrees of freedom on a healthy system. A sample
*exceeds* the gate when ``beta2 > threshold(m)``; an *alarm* is raised when M of the last N
updates exceeded and cleared when fewer than M of the last N did (:class:`AlarmLogic`).

Failed measurement rows (redundant references, SPEC section 2, seed 001): ``KalmanFilter.update``
takes ``failed_rows`` and a ``mode`` -- ``nominal`` (ignore them), ``known_anomaly`` (KF2: their
R grows by C Gamma C^T) or ``exclude`` (AF: the rows E z only). The gains are those of
:mod:`flight_fdi.core.redundancy` (``kf2_gain``, ``af_gain``); beta^2 and its threshold are then
over the rows used. Which rows have failed is decided by :mod:`flight_fdi.core.references`.
"""
from __future__ import annotations

import contextlib
import gc
import math
import weakref
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.special import chdtri

from .errors import CoreError
from .models import LinearModel
from .redundancy import accuracy, af_gain, anomaly_matrix, kf2_gain

# alarm states, as in msg_defs/msg/Innovation.msg
ALARM_CLEAR = 0
ALARM_RAISED = 1
ALARM_ACTIVE = 2
ALARM_CLEARED = 3

GATE_RULES = ("chi2", "seed")
GATE_ACTIONS = ("flag", "reject")
#: how ``KalmanFilter.update`` treats ``failed_rows``
UPDATE_MODES = ("nominal", "known_anomaly", "exclude")


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


@lru_cache(maxsize=256)
def _gate_threshold(rule: str, probability: float, m: int) -> float:
    if rule == "seed":
        return m + 3.0 * math.sqrt(2.0 * m)
    # chdtri(m, p) is the chi2(m) upper quantile chi2.isf(p, m), accurate for tiny p (and it
    # spares importing scipy.stats)
    return float(chdtri(m, probability))


@dataclass(frozen=True)
class GateConfig:
    """The beta^2 gate and the persistence rule of the alarm.

    rule: ``"chi2"`` -- the chi-square(m) quantile with per-sample false-alarm ``probability``;
          ``"seed"`` -- the seed's 3-sigma rule m + 3 sqrt(2m) (``probability`` is then unused).
    alarm_m, alarm_n: an alarm is raised when ``alarm_m`` of the last ``alarm_n`` updates exceeded
          the gate, and cleared when fewer than ``alarm_m`` of the last ``alarm_n`` did.
    action: ``"flag"`` -- fuse a gated sample anyway (post-flight analysis then sees the fault);
            ``"reject"`` -- do not fuse a gated sample.
    """

    rule: str = "chi2"
    probability: float = 1e-3
    alarm_m: int = 3
    alarm_n: int = 5
    action: str = "flag"

    def __post_init__(self) -> None:
        if self.rule not in GATE_RULES:
            raise CoreError(f"GateConfig.rule must be one of {GATE_RULES}, got {self.rule!r}")
        p = self.probability
        if (isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, float, np.floating))
                or not math.isfinite(p) or not 0.0 < p < 1.0):
            raise CoreError(f"GateConfig.probability must be a number in (0, 1), got {p!r}")
        if not _is_int(self.alarm_m) or self.alarm_m < 1:
            raise CoreError(f"GateConfig.alarm_m must be an integer >= 1, got {self.alarm_m!r}")
        if not _is_int(self.alarm_n) or self.alarm_n < self.alarm_m:
            raise CoreError(f"GateConfig.alarm_n must be an integer >= alarm_m ({self.alarm_m}), "
                            f"got {self.alarm_n!r}")
        if self.action not in GATE_ACTIONS:
            raise CoreError(f"GateConfig.action must be one of {GATE_ACTIONS}, got {self.action!r}")
        object.__setattr__(self, "probability", float(p))
        object.__setattr__(self, "alarm_m", int(self.alarm_m))
        object.__setattr__(self, "alarm_n", int(self.alarm_n))

    def threshold(self, m: int) -> float:
        """Gate threshold on beta^2 for an m-row measurement."""
        if not _is_int(m) or m < 1:
            raise CoreError(f"GateConfig.threshold: m must be an integer >= 1, got {m!r}")
        return _gate_threshold(self.rule, self.probability, int(m))


class AlarmLogic:
    """M-of-N persistence: ``push(exceeded)`` returns the alarm state of that update."""

    def __init__(self, m_of: int, n_of: int) -> None:
        self.m_of = int(m_of)
        self.n_of = int(n_of)
        self.reset()

    def reset(self) -> None:
        self._window = [False] * self.n_of
        self._pos = 0
        self._count = 0
        self.active = False

    def push(self, exceeded: bool) -> int:
        exceeded = bool(exceeded)
        self._count += exceeded - self._window[self._pos]
        self._window[self._pos] = exceeded
        self._pos = (self._pos + 1) % self.n_of
        if self.active:
            if self._count < self.m_of:
                self.active = False
                return ALARM_CLEARED
            return ALARM_ACTIVE
        if self._count >= self.m_of:
            self.active = True
            return ALARM_RAISED
        return ALARM_CLEAR


def alarm_states(exceeded: np.ndarray, gate: GateConfig) -> np.ndarray:
    """Alarm state of every update of a record, from its gate exceedances (vectorised).

    The rule of :class:`AlarmLogic` is memoryless in the window count: the alarm is active after
    update k exactly when at least M of the last N updates exceeded, so the states follow from a
    moving sum and its change.
    """
    e = np.asarray(exceeded, dtype=np.int64).reshape(-1)
    c = np.cumsum(e)
    count = c.copy()
    count[gate.alarm_n:] -= c[:-gate.alarm_n]
    active = count >= gate.alarm_m
    prev = np.concatenate(([False], active[:-1]))
    state = np.full(e.size, ALARM_CLEAR, dtype=np.uint8)
    state[active & ~prev] = ALARM_RAISED
    state[active & prev] = ALARM_ACTIVE
    state[~active & prev] = ALARM_CLEARED
    return state


# --------------------------------------------------------------------------- scaled model

@dataclass(frozen=True, eq=False)
class StepMatrices:
    """Phi, Qd, Bd of one dt in scaled coordinates, as arrays and as float tuples, and the
    generated prediction functions for their sparsity pattern."""

    dt: float
    Phi: np.ndarray
    PhiT: np.ndarray
    Qd: np.ndarray
    Bd: np.ndarray | None
    Phi_t: tuple
    Qd_t: tuple
    predict: Any       # predict(x, P, Phi_t, Qd_t, None)
    predict_bu: Any    # predict(x, P, Phi_t, Qd_t, bu)
    pattern: tuple     # (n, Phi mask, Qd mask): the key of the generated code


class ScaledModel:
    """A model in scaled coordinates x' = T^-1 x, T = diag(model.scale).

    ``matrices(dt)`` gives Phi' = T^-1 Phi T, Qd' = T^-1 Qd T^-1, Bd' = T^-1 Bd (a
    :class:`StepMatrices`), cached per dt with the model's own key (dt rounded to 1 ns).
    ``H = model.H T``. Covariances convert as ``P = P' * SS`` with ``SS = s s^T``.
    """

    def __init__(self, model: LinearModel) -> None:
        self.model = model
        self.n = model.n
        self.s = np.asarray(model.scale, dtype=float)
        self.inv_s = 1.0 / self.s
        self.SS = np.outer(self.s, self.s)
        self.H = np.ascontiguousarray(model.H * self.s)
        self.HT = np.ascontiguousarray(self.H.T)
        self.I = np.eye(self.n)
        self._cache: dict[float, StepMatrices] = {}

    def update1_for(self, Hs: np.ndarray):
        """The generated one-row update for a scaled H row ``Hs`` (1, n)."""
        return _compiled("update", self.n, tuple(bool(v) for v in np.asarray(Hs)[0] != 0))

    def matrices(self, dt: float) -> StepMatrices:
        key = round(float(dt), 9)
        hit = self._cache.get(key)
        if hit is None:
            hit = self._build(key, *self.model.discretize(key))
        return hit

    def _build(self, key: float, Phi: np.ndarray, Qd: np.ndarray,
               Bd: np.ndarray | None) -> StepMatrices:
        """Scale one (Phi, Qd, Bd), generate its prediction code, and cache it under ``key``."""
        Phi_s = np.ascontiguousarray(self.inv_s[:, None] * Phi * self.s[None, :])
        Qd_s = Qd / self.SS
        Qd_s = 0.5 * (Qd_s + Qd_s.T)
        Bd_s = None if Bd is None else np.ascontiguousarray(self.inv_s[:, None] * Bd)
        pattern = (self.n, _mask(Phi_s), _mask(Qd_s))
        hit = StepMatrices(key, Phi_s, np.ascontiguousarray(Phi_s.T), Qd_s, Bd_s,
                           tuple(Phi_s.ravel().tolist()), tuple(Qd_s.ravel().tolist()),
                           _compiled("predict", *pattern, False),
                           _compiled("predict", *pattern, True), pattern)
        if len(self._cache) > 4096:
            self._cache.clear()
        self._cache[key] = hit
        return hit

    def matrices_for(self, dt: np.ndarray) -> tuple[list[StepMatrices], np.ndarray]:
        """Matrices for every entry of ``dt``: (list over unique keys, index of each step).

        Keys not in the cache are discretized together (``LinearModel.discretize_many``), so
        jittered stamps (nearly every dt distinct) do not cost one matrix exponential each.
        """
        keys, inverse = np.unique(np.round(np.asarray(dt, dtype=float), 9), return_inverse=True)
        found = [self._cache.get(float(k)) for k in keys]
        missing = [i for i, hit in enumerate(found) if hit is None]
        if missing:
            Phi, Qd, Bd = self.model.discretize_many(keys[missing])
            for j, i in enumerate(missing):
                found[i] = self._build(float(keys[i]), Phi[j], Qd[j],
                                       None if Bd is None else Bd[j])
        return found, inverse.reshape(-1)

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


# --------------------------------------------------------------------------- the algorithm
#
# predict:  x- = Phi x + Bd u,            P- = Phi P Phi^T + Qd
# update:   S = H P- H^T + R,  K = P- H^T S^-1,  nu = z - H x-,  beta2 = nu^T S^-1 nu
#           x+ = x- + K nu,    P+ = (I - K H) P- (I - K H)^T + K R K^T      (Joseph form)
#
# The prediction, and the update of a one-row measurement (the usual case), are written out
# element by element in plain Python floats: numpy's per-call overhead dominates 4x4 arithmetic,
# and the written-out form is several times faster. The code is generated once per (n, sparsity
# pattern) from the statement lists of ``_predict_lines`` and ``_update_lines``: as ``predict``,
# ``update``, and ``step`` (the two in one call, the same statements); terms whose factor is an
# exact zero of Phi, Qd or H are left out, which changes no bit of the result (x*0 = 0,
# a + 0 = a). Updates with m > 1 rows use numpy (``_update``). The streaming filter and the batch
# run call these same functions, so they agree to the last bit. States: x a tuple of n floats, P
# the upper triangle of the symmetric covariance as a tuple of n(n+1)/2 floats (row by row), in
# scaled coordinates.

def _mask(a: np.ndarray) -> tuple:
    return tuple(tuple(bool(v) for v in row) for row in (np.asarray(a) != 0))


def _sum(terms: list[str]) -> str:
    return " + ".join(terms) if terms else "0.0"


def _tri_names(prefix: str, n: int) -> str:
    return "".join(f"{prefix}{i}_{j}, " for i in range(n) for j in range(i, n))


@lru_cache(maxsize=32)
def _triu(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(n)


def _tri_to_full(tri: np.ndarray, n: int) -> np.ndarray:
    """(..., n(n+1)/2) upper triangles -> (..., n, n) symmetric matrices."""
    tri = np.asarray(tri, dtype=float)
    iu, ju = _triu(n)
    full = np.empty(tri.shape[:-1] + (n, n))
    full[..., iu, ju] = tri
    full[..., ju, iu] = tri
    return full


def _full_to_tri(P: np.ndarray) -> np.ndarray:
    iu, ju = _triu(P.shape[-1])
    return P[..., iu, ju]


def _unpack_lines(n: int, with_bu: bool) -> list[str]:
    r = range(n)
    lines = [f"    ({''.join(f'x{i}, ' for i in r)}) = x",
             f"    ({_tri_names('P', n)}) = P",
             f"    ({''.join(f'F{i}_{j}, ' for i in r for j in r)}) = Phi",
             f"    ({''.join(f'Q{i}_{j}, ' for i in r for j in r)}) = Qd"]
    if with_bu:
        lines.append(f"    ({''.join(f'b{i}, ' for i in r)}) = bu")
    return lines


def _predict_lines(n: int, phi_mask: tuple, q_mask: tuple, with_bu: bool) -> list[str]:
    """x- = Phi x (+ Bd u) -> y_i;  P- = Phi P Phi^T + Qd -> M_i_j (upper triangle)."""
    r = range(n)
    P = lambda i, j: f"P{min(i, j)}_{max(i, j)}"  # noqa: E731  (P is symmetric)
    lines = []
    for i in r:
        terms = [f"F{i}_{k}*x{k}" for k in r if phi_mask[i][k]] + ([f"b{i}"] if with_bu else [])
        lines.append(f"    y{i} = {_sum(terms)}")
    # T = Phi P
    for i in r:
        for j in r:
            terms = [f"F{i}_{k}*{P(k, j)}" for k in r if phi_mask[i][k]]
            lines.append(f"    T{i}_{j} = {_sum(terms)}")
    # P- = T Phi^T + Qd (upper triangle)
    for i in r:
        for j in range(i, n):
            terms = [f"T{i}_{k}*F{j}_{k}" for k in r if phi_mask[j][k]]
            terms += [f"Q{i}_{j}"] if q_mask[i][j] else []
            lines.append(f"    M{i}_{j} = {_sum(terms)}")
    return lines


def _update_lines(n: int, h_mask: tuple, xn: str, Pn: str, x_tuple: str, P_tuple: str,
                  head: str = "", emit: Any = None) -> list[str]:
    """The one-row Joseph update on the scalars ``{xn}i`` and ``{Pn}i_j`` (upper triangle);
    returns ``{head}(x+), (P+), nu, S, (K), beta2, exceeded, fused``. ``emit(rejected)``, when
    given, supplies the statements of the two exits instead of the ``return``s (the posterior
    is then ``{xn}i + Ki*nu`` and ``Ni_j``, or the prior when rejected)."""
    r = range(n)
    hz = [k for k in r if h_mask[k]]
    P = lambda i, j: f"{Pn}{min(i, j)}_{max(i, j)}"  # noqa: E731
    lines = [f"    ({''.join(f'h{i}, ' for i in r)}) = h"]
    # c = P H^T, S = H c + R, nu = z - H x, beta2 = nu^2 / S
    for i in r:
        lines.append(f"    c{i} = {_sum([f'{P(i, k)}*h{k}' for k in hz])}")
    lines.append(f"    s = {_sum([f'h{i}*c{i}' for i in hz])} + r")
    lines.append("    if not s > 0.0:")
    lines.append("        raise CoreError(f'innovation covariance S = {s:.3g} is not positive')")
    lines.append(f"    nu = z - ({_sum([f'h{i}*{xn}{i}' for i in hz])})")
    lines.append("    beta2 = nu * nu / s")
    lines.append("    exceeded = beta2 > threshold")
    lines.append("    if exceeded and reject:")
    if emit is None:
        lines.append(f"        return {head}{x_tuple}, {P_tuple}, nu, s, ({'0.0, ' * n}), beta2, "
                     "True, False")
    else:
        lines += [f"        {line}" for line in emit(True)]
    # K = c / S
    lines.append("    si = 1.0 / s")
    for i in r:
        lines.append(f"    K{i} = c{i}*si")

    # A = I - K H: only the columns where H is non-zero differ from I
    def A(i: int, k: int) -> str | None:
        if h_mask[k]:
            return f"A{i}_{k}"
        return "1" if i == k else None

    for i in r:
        for k in hz:
            lines.append(f"    A{i}_{k} = {'1.0' if i == k else '0.0'} - K{i}*h{k}")
    # U = A P
    for i in r:
        for j in r:
            terms = []
            for k in r:
                a = A(i, k)
                if a == "1":
                    terms.append(P(k, j))
                elif a is not None:
                    terms.append(f"{a}*{P(k, j)}")
            lines.append(f"    U{i}_{j} = {_sum(terms)}")
    # P+ = U A^T + K r K^T (upper triangle)
    for i in r:
        for j in range(i, n):
            terms = []
            for k in r:
                a = A(j, k)
                if a == "1":
                    terms.append(f"U{i}_{k}")
                elif a is not None:
                    terms.append(f"U{i}_{k}*{a}")
            terms.append(f"K{i}*r*K{j}")
            lines.append(f"    N{i}_{j} = {_sum(terms)}")
    if emit is None:
        lines.append(f"    return {head}({''.join(f'{xn}{i} + K{i}*nu, ' for i in r)}), "
                     f"({_tri_names('N', n)}), nu, s, ({''.join(f'K{i}, ' for i in r)}), beta2, "
                     "exceeded, True")
    else:
        lines += [f"    {line}" for line in emit(False)]
    return lines


def _predict_source(n: int, phi_mask: tuple, q_mask: tuple, with_bu: bool) -> str:
    """``predict(x, P, Phi, Qd, bu) -> (x-, P-)`` for one sparsity pattern."""
    lines = ["def predict(x, P, Phi, Qd, bu):"] + _unpack_lines(n, with_bu)
    lines += _predict_lines(n, phi_mask, q_mask, with_bu)
    lines.append(f"    return ({''.join(f'y{i}, ' for i in range(n))}), ({_tri_names('M', n)})")
    return "\n".join(lines) + "\n"


def _update1_source(n: int, h_mask: tuple) -> str:
    """``update(x, P, h, r, z, threshold, reject) -> (x+, P+, nu, S, K, beta2, exceeded,
    fused)`` for one sparsity pattern of h."""
    lines = ["def update(x, P, h, r, z, threshold, reject):",
             f"    ({''.join(f'x{i}, ' for i in range(n))}) = x",
             f"    ({_tri_names('P', n)}) = P"]
    lines += _update_lines(n, h_mask, "x", "P", "x", "P")
    return "\n".join(lines) + "\n"


def _step_source(n: int, phi_mask: tuple, q_mask: tuple, with_bu: bool, h_mask: tuple) -> str:
    """``step(x, P, Phi, Qd, bu, h, r, z, threshold, reject) -> (x-, P-, x+, P+, nu, S, K,
    beta2, exceeded, fused)``: the prediction followed by the one-row update -- the same
    statements as ``predict`` and ``update`` (hence the same bits), without the call between."""
    lines = ["def step(x, P, Phi, Qd, bu, h, r, z, threshold, reject):"] + _unpack_lines(n, with_bu)
    lines += _predict_lines(n, phi_mask, q_mask, with_bu)
    lines.append(f"    xp = ({''.join(f'y{i}, ' for i in range(n))})")
    lines.append(f"    Pp = ({_tri_names('M', n)})")
    lines += _update_lines(n, h_mask, "y", "M", "xp", "Pp", head="xp, Pp, ")
    return "\n".join(lines) + "\n"


def forward_row_width(n: int) -> int:
    """Floats per step in the output of a generated ``run``: x- (n), P- (n(n+1)/2), x+ (n),
    P+ (n(n+1)/2), K (n), nu, S, beta2, fused."""
    return 3 * n + n * (n + 1) + 4


def _run_source(n: int, phi_mask: tuple, q_mask: tuple, with_bu: bool, h_mask: tuple,
                constant: bool) -> str:
    """``run(x, P, Phi, Qd, bus, h, rs, zs, threshold, reject, out) -> (x, P)``: ``step`` over a
    whole record in one generated loop -- the same statements (hence the same bits) with the
    state in local variables. ``constant``: Phi and Qd are one pair for every step (unpacked
    once), else sequences; ``bus`` a sequence when ``with_bu``. Each step calls ``out`` once with
    the :func:`forward_row_width` floats of the step (fused: 1.0 or 0.0)."""
    r = range(n)
    xs = "".join(f"x{i}, " for i in r)
    Ps = _tri_names("P", n)
    unpack = [line[4:] for line in _unpack_lines(n, with_bu)]  # x, P, Phi, Qd (, bu)
    unpack_x_P, unpack_phi, unpack_bu = unpack[:2], unpack[2:4], unpack[4:]
    lines = ["def run(x, P, Phi, Qd, bus, h, rs, zs, threshold, reject, out):"]
    lines += [f"    {line}" for line in unpack_x_P + [f"({''.join(f'h{i}, ' for i in r)}) = h"]]
    seqs = ["rs", "zs"]
    names = ["r", "z"]
    if constant:
        lines += [f"    {line}" for line in unpack_phi]
    else:
        seqs[:0], names[:0] = ["Phi", "Qd"], ["Phi", "Qd"]
    if with_bu:
        seqs.append("bus")
        names.append("bu")
    body = ([] if constant else unpack_phi) + unpack_bu
    body += [line[4:] for line in _predict_lines(n, phi_mask, q_mask, with_bu)]
    prior = f"{''.join(f'y{i}, ' for i in r)}{_tri_names('M', n)}"

    def emit(rejected: bool) -> list[str]:
        if rejected:
            return [f"out(({prior}{prior}{'0.0, ' * n}nu, s, beta2, 0.0))",
                    f"({xs}) = ({''.join(f'y{i}, ' for i in r)})",
                    f"({Ps}) = ({_tri_names('M', n)})", "continue"]
        return [f"({xs}) = ({''.join(f'y{i} + K{i}*nu, ' for i in r)})",
                f"({Ps}) = ({_tri_names('N', n)})",
                f"out(({prior}{xs}{Ps}{''.join(f'K{i}, ' for i in r)}nu, s, beta2, 1.0))"]

    update = _update_lines(n, h_mask, "y", "M", "", "", emit=emit)
    body += [line[4:] for line in update[1:]]  # without the unpacking of h (done once)
    lines.append(f"    for {', '.join(names)} in zip({', '.join(seqs)}):")
    lines += [f"        {line}" for line in body]
    lines.append(f"    return ({xs}), ({Ps})")
    return "\n".join(lines) + "\n"


_GENERATED: dict[tuple, Any] = {}
_SOURCES = {"predict": _predict_source, "update": _update1_source, "step": _step_source,
            "run": _run_source}


def _compiled(kind: str, *key: Any):
    """The generated function ``kind`` ("predict", "update" or "step") for ``key`` (cached)."""
    fn = _GENERATED.get((kind,) + key)
    if fn is None:
        src = _SOURCES[kind](*key)
        namespace: dict[str, Any] = {"CoreError": CoreError}
        exec(compile(src, f"<flight_fdi.kalman.{kind}{key[0]}>", "exec"), namespace)  # noqa: S102
        fn = namespace[kind]
        _GENERATED[(kind,) + key] = fn
    return fn


def _update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, Hs: np.ndarray,
            HsT: np.ndarray, I: np.ndarray, threshold: float, reject: bool):
    """The update with numpy, for any m (used for m > 1 rows): the same equations as the
    generated one-row update. x (n,), P (n, n), Hs = H T (m, n) scaled; z (m,), R (m, m), nu, S
    in measurement units. Returns (x+, P+, nu, S, K, beta2, exceeded, fused); K (n, m) is the
    gain applied (zeros when the sample was not fused)."""
    PHt = P.dot(HsT)
    S = Hs.dot(PHt) + R
    S = 0.5 * (S + S.T)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise CoreError("innovation covariance S is not positive definite") from None
    Linv = np.linalg.inv(L)
    Sinv = Linv.T.dot(Linv)
    nu = z - Hs.dot(x)
    w = Linv.dot(nu)
    with np.errstate(over="ignore"):  # an overflow is refused by the caller's finiteness check
        beta2 = float(w.dot(w))
    exceeded = beta2 > threshold
    K = PHt.dot(Sinv)
    if exceeded and reject:
        return x, P, nu, S, K * 0.0, beta2, True, False
    x = x + K.dot(nu)
    A = I - K.dot(Hs)
    P = A.dot(P).dot(A.T) + K.dot(R).dot(K.T)
    P = (P + P.T) * 0.5
    return x, P, nu, S, K, beta2, exceeded, True


def _check_finite_update(x: Any, P: Any, beta2: float, nu: Any = None, S: Any = None) -> None:
    """CoreError when an update overflowed float64: a finite measurement so far from the
    prediction (e.g. 1e200 m/s) that beta2 = nu^T S^-1 nu, a row's nu_k^2 / S_kk or the
    corrected state is Inf or NaN. The caller then leaves the filter unchanged. (For one row
    beta2 = nu^2 / S is the row's value; ``nu`` and ``S`` are needed for several rows.)"""
    ok = math.isfinite(beta2) and all(map(math.isfinite, x)) and all(map(math.isfinite, P))
    if ok and nu is not None and np.size(nu) > 1:
        with np.errstate(over="ignore", invalid="ignore"):
            ok = bool(np.all(np.isfinite(np.square(nu) / np.diag(S))))
    if not ok:
        raise CoreError(f"the update overflows float64 (innovation "
                        f"{np.ravel(nu).tolist() if nu is not None else '?'}, beta2 {beta2!r}): "
                        "the measurement is not a plausible value")


def _update_any(x: tuple, P: tuple, z: np.ndarray, R: np.ndarray, Hs: np.ndarray,
                HsT: np.ndarray, I: np.ndarray, threshold: float, reject: bool, update1: Any):
    """One update on the tuple state: the generated one-row update when m = 1, else numpy.
    Returns (x+, P+) as tuples and nu (m,), S (m, m), K (n, m) as arrays."""
    m, n = Hs.shape
    if m == 1:
        x, P, nu, s, K, beta2, exceeded, fused = update1(
            x, P, Hs[0].tolist(), R.item(), z.item(), threshold, reject)
        return x, P, np.array([nu]), np.array([[s]]), np.array(K).reshape(n, 1), beta2, \
            exceeded, fused
    xa, Pa, nu, S, K, beta2, exceeded, fused = _update(
        np.array(x), _tri_to_full(P, n), z, R, Hs, HsT, I, threshold, reject)
    return tuple(xa.tolist()), tuple(_full_to_tri(Pa).tolist()), nu, S, K, beta2, exceeded, fused


def _failed_rows(rows: Any, m: int) -> tuple[int, ...]:
    """Sorted unique failed row indices in 0..m-1 (CoreError otherwise)."""
    out = set()
    for r in np.asarray(rows, dtype=object).reshape(-1).tolist() if rows is not None else ():
        if not _is_int(r) or not 0 <= r < m:
            raise CoreError(f"failed row {r!r} is not a row index in 0..{m - 1}")
        out.add(int(r))
    return tuple(sorted(out))


def _anomaly_covariance(Gamma: Any, r: int) -> np.ndarray:
    """Gamma as an r x r matrix: a number (the same variance for every failed row), r
    variances, or an r x r covariance; variances must be > 0."""
    if Gamma is None:
        raise CoreError("known_anomaly mode: Gamma (the anomaly variance) is required")
    try:
        G = np.asarray(Gamma, dtype=float)
    except (TypeError, ValueError):
        raise CoreError(f"Gamma is not numeric: {Gamma!r}") from None
    if G.ndim == 0:
        G = np.full(r, float(G))
    if G.ndim == 1:
        if G.shape != (r,):
            raise CoreError(f"Gamma must give {r} variances (one per failed row), got {G.size}")
        G = np.diag(G)
    if G.shape != (r, r) or not np.all(np.isfinite(G)):
        raise CoreError(f"Gamma must be a finite {r} x {r} matrix, got shape {G.shape}")
    if np.any(np.diag(G) <= 0) or not np.allclose(G, G.T, rtol=1e-9, atol=0.0):
        raise CoreError("Gamma must be symmetric with positive variances")
    return G


def _update_failed(x: tuple, P: tuple, z: np.ndarray, R: np.ndarray, Hs: np.ndarray,
                   I: np.ndarray, failed: tuple[int, ...], mode: str, G: np.ndarray | None,
                   gate: GateConfig, reject: bool):
    """The update with failed rows (numpy, scaled coordinates): KF2 (``known_anomaly``) or AF
    (``exclude``) with the gains of :mod:`.redundancy`. Returns (x+, P+) as tuples and nu, S
    (nominal, all rows), beta2, threshold, exceeded, fused (over the rows used), the rows used
    and the R used."""
    m, n = Hs.shape
    xa = np.array(x)
    Pa = _tri_to_full(P, n)
    nu = z - Hs.dot(xa)
    if mode == "known_anomaly":
        C = anomaly_matrix(m, failed)
        R_used = R + C.dot(G).dot(C.T)
        K, S_used = kf2_gain(Pa, Hs, R, failed, G)
        S = Hs.dot(Pa).dot(Hs.T) + R  # the nominal S, reported (row_beta2) for every row
        S = 0.5 * (S + S.T)
        used = tuple(range(m))
        nu_used = nu
    else:
        R_used = R
        K, S = af_gain(Pa, Hs, R, failed)
        used = tuple(i for i in range(m) if i not in failed)
        S_used = S[np.ix_(used, used)]
        nu_used = nu[list(used)]
    if not used:
        return x, P, nu, S, 0.0, math.nan, False, False, used, R_used
    try:
        L = np.linalg.cholesky(S_used)
    except np.linalg.LinAlgError:
        raise CoreError("innovation covariance S of the rows used is not positive definite") \
            from None
    w = np.linalg.solve(L, nu_used)
    beta2 = float(w.dot(w))
    thr = gate.threshold(len(used))
    exceeded = beta2 > thr
    if exceeded and reject:
        return x, P, nu, S, beta2, thr, True, False, used, R_used
    xa = xa + K.dot(nu)
    A = I - K.dot(Hs)
    Pa = A.dot(Pa).dot(A.T) + K.dot(R_used).dot(K.T)
    Pa = (Pa + Pa.T) * 0.5
    return (tuple(xa.tolist()), tuple(_full_to_tri(Pa).tolist()), nu, S, beta2, thr, exceeded,
            True, used, R_used)


@contextlib.contextmanager
def _gc_paused():
    """Pause Python's cyclic garbage collector around a tight numeric loop.

    The loops below allocate many small tuples and arrays but create no reference cycles; the
    collector's periodic scans otherwise cost as much as the arithmetic.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


# --------------------------------------------------------------------------- validation

def _check_dt(dt: Any) -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise CoreError(f"dt must be a number, got {dt!r}") from None
    if not math.isfinite(dt):
        raise CoreError(f"dt must be finite, got {dt!r}")
    if dt < 0:
        raise CoreError(f"dt must be >= 0, got {dt!r}")
    return dt


def _check_z(z: Any, m: int) -> np.ndarray:
    try:
        arr = np.asarray(z, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CoreError(f"measurement z is not numeric: {z!r}") from None
    if arr.shape != (m,):
        raise CoreError(f"measurement z must have {m} values, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"measurement z contains NaN or Inf: {arr.tolist()}")
    return arr


def _check_R(R: Any, m: int) -> np.ndarray:
    try:
        arr = np.asarray(R, dtype=float)
    except (TypeError, ValueError):
        raise CoreError("measurement covariance R is not numeric") from None
    if arr.size == m * m:
        arr = arr.reshape(m, m)
    if arr.shape != (m, m):
        raise CoreError(f"measurement covariance R must be {m}x{m}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CoreError("measurement covariance R contains NaN or Inf")
    if m == 1:
        if arr[0, 0] < 0:
            raise CoreError(f"measurement covariance R = {arr[0, 0]:.3g} is negative")
        return arr
    if not np.allclose(arr, arr.T, rtol=1e-9, atol=0.0):
        raise CoreError("measurement covariance R is not symmetric")
    eig = np.linalg.eigvalsh(arr)
    if eig[0] < -1e-12 * max(abs(eig[-1]), 1e-300):
        raise CoreError(f"measurement covariance R is not positive semidefinite "
                        f"(smallest eigenvalue {eig[0]:.3g})")
    return 0.5 * (arr + arr.T)


def _check_R_batch(R: np.ndarray, N: int, m: int) -> np.ndarray:
    if R.shape != (N, m, m):
        raise CoreError(f"R must have shape ({N}, {m}, {m}), got {R.shape}")
    bad = ~np.all(np.isfinite(R.reshape(N, -1)), axis=1)
    if np.any(bad):
        raise CoreError(f"R contains NaN or Inf at {int(bad.sum())} steps (first at index "
                        f"{int(np.argmax(bad))})")
    if m == 1:
        neg = R[:, 0, 0] < 0
        if np.any(neg):
            raise CoreError(f"R is negative at {int(neg.sum())} steps (first at index "
                            f"{int(np.argmax(neg))})")
        return R
    asym = ~np.all(np.isclose(R, np.swapaxes(R, 1, 2), rtol=1e-9, atol=0.0).reshape(N, -1), axis=1)
    if np.any(asym):
        raise CoreError(f"R is not symmetric at index {int(np.argmax(asym))}")
    eig = np.linalg.eigvalsh(R)
    neg = eig[:, 0] < -1e-12 * np.maximum(np.abs(eig[:, -1]), 1e-300)
    if np.any(neg):
        raise CoreError(f"R is not positive semidefinite at index {int(np.argmax(neg))}")
    return 0.5 * (R + np.swapaxes(R, 1, 2))


def _check_prior(model: LinearModel, x0: Any, P0: Any) -> tuple[np.ndarray, np.ndarray]:
    n = model.n
    if x0 is None:
        x = np.zeros(n)
    else:
        x = np.asarray(x0, dtype=float).reshape(-1)
        if x.shape != (n,) or not np.all(np.isfinite(x)):
            raise CoreError(f"x0 must be {n} finite numbers")
    if P0 is None:
        P = np.array(model.P0, dtype=float)
    else:
        P = np.asarray(P0, dtype=float)
        if P.shape != (n, n) or not np.all(np.isfinite(P)):
            raise CoreError(f"P0 must be a finite {n}x{n} matrix")
        if not np.allclose(P, P.T, rtol=1e-9, atol=0.0):
            raise CoreError("P0 is not symmetric")
        Ps = P / np.outer(model.scale, model.scale)
        eig = np.linalg.eigvalsh(0.5 * (Ps + Ps.T))
        if eig[0] < -1e-12 * max(abs(eig[-1]), 1e-300):
            raise CoreError(f"P0 is not positive semidefinite (smallest scaled eigenvalue "
                            f"{eig[0]:.3g})")
        P = 0.5 * (P + P.T)
    return x, P


def _check_u(model: LinearModel, u: Any, what: str = "u") -> np.ndarray | None:
    if u is None:
        return None
    if model.B is None:
        raise CoreError(f"model {model.name!r} has no input matrix B; a control input {what} "
                        "was given")
    p = model.B.shape[1]
    arr = np.asarray(u, dtype=float).reshape(-1)
    if arr.shape != (p,) or not np.all(np.isfinite(arr)):
        raise CoreError(f"control input {what} must be {p} finite numbers")
    return arr


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


class KalmanFilter:
    """Streaming Kalman filter over a :class:`LinearModel`, one sample at a time.

    ``predict(dt, u)`` then ``update(z, R, H)``, or ``step(dt, z, R, u)``. Bad input (non-finite
    z, R or dt, negative dt, R not positive semidefinite, wrong shapes) raises
    :class:`CoreError` and leaves the filter unchanged. ``x`` and ``P`` are in physical units.
    """

    def __init__(self, model: LinearModel, gate: GateConfig = GateConfig(),
                 x0: Any = None, P0: Any = None) -> None:
        if not isinstance(gate, GateConfig):
            raise CoreError(f"gate must be a GateConfig, got {type(gate).__name__}")
        self.model = model
        self.gate = gate
        self._sm = scaled_model(model)
        self._update1 = self._sm.update1_for(self._sm.H) if model.m == 1 else None
        self._h = self._sm.H[0].tolist()
        self._h_pattern = tuple(bool(v) for v in self._sm.H[0] != 0)
        self._threshold1 = gate.threshold(1)
        # for state_lists: s, SS row-major, and the upper-triangle index of every P entry
        iu, ju = _triu(model.n)
        k_of = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(iu, ju))}
        self._lists = (self._sm.s.tolist(), self._sm.SS.ravel().tolist(),
                       [k_of[min(i, j), max(i, j)] for i in range(model.n)
                        for j in range(model.n)])
        self._alarm = AlarmLogic(gate.alarm_m, gate.alarm_n)
        self._reject = gate.action == "reject"
        self.reset(x0, P0)

    def reset(self, x0: Any = None, P0: Any = None) -> None:
        """Back to the prior (x0 default zeros, P0 default model.P0); clears the alarm."""
        x, P = _check_prior(self.model, x0, P0)
        xs, Ps = self._sm.to_scaled(x, P)
        self._x = tuple(xs.tolist())
        self._P = tuple(_full_to_tri(Ps).tolist())
        self._alarm.reset()
        self.steps = 0

    @property
    def x(self) -> np.ndarray:
        """Current state estimate, physical units."""
        return np.array(self._x) * self._sm.s

    @property
    def P(self) -> np.ndarray:
        """Current covariance, physical units."""
        return _tri_to_full(self._P, self._sm.n) * self._sm.SS

    def state_lists(self) -> tuple[list[float], list[float]]:
        """(x, P row-major) in physical units as plain lists: the same numbers as ``x`` and
        ``P.ravel()`` (the same products), for a node's per-message output without NumPy."""
        n = self._sm.n
        s, ss, index = self._lists
        x, P = self._x, self._P
        return ([x[i] * s[i] for i in range(n)],
                [P[k] * ss[a] for a, k in enumerate(index)])

    @property
    def alarm_active(self) -> bool:
        return self._alarm.active

    def predict(self, dt: float, u: Any = None) -> None:
        """Propagate over ``dt`` seconds (>= 0) with optional control input ``u``."""
        dt = _check_dt(dt)
        u = _check_u(self.model, u)
        mt = self._sm.matrices(dt)
        if u is None:
            self._x, self._P = mt.predict(self._x, self._P, mt.Phi_t, mt.Qd_t, None)
        else:
            bu = tuple(mt.Bd.dot(u).tolist())
            self._x, self._P = mt.predict_bu(self._x, self._P, mt.Phi_t, mt.Qd_t, bu)

    def _measurement(self, z: Any, R: Any, H: Any):
        """Validated (z, R, scaled H, its transpose, the generated one-row update or None)."""
        sm = self._sm
        if H is None:
            Hs, HsT, update1 = sm.H, sm.HT, self._update1
        else:
            Hp = np.asarray(H, dtype=float)
            if Hp.ndim == 1:
                Hp = Hp.reshape(1, -1)
            if Hp.ndim != 2 or Hp.shape[1] != sm.n or not np.all(np.isfinite(Hp)):
                raise CoreError(f"H must be a finite matrix with {sm.n} columns")
            Hs = np.ascontiguousarray(Hp * sm.s)
            HsT = np.ascontiguousarray(Hs.T)
            update1 = sm.update1_for(Hs) if Hs.shape[0] == 1 else None
        m = Hs.shape[0]
        zv = _check_z(z, m)
        if R is None:
            if m != self.model.m:
                raise CoreError(f"R must be given for a {m}-row H (the model has {self.model.m})")
            Rm = self.model.R
        else:
            Rm = _check_R(R, m)
        return zv, Rm, Hs, HsT, update1

    def innovation(self, z: Any, R: Any = None, H: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """The innovation ``nu = z - H x`` and its covariance ``S = H P H^T + R`` against the
        current state (after ``predict``: the prior), without changing the filter."""
        zv, Rm, Hs, HsT, _ = self._measurement(z, R, H)
        return self._innovation(zv, Rm, Hs, HsT)

    def _innovation(self, zv: np.ndarray, Rm: np.ndarray, Hs: np.ndarray, HsT: np.ndarray):
        P = _tri_to_full(self._P, self._sm.n)
        nu = zv - Hs.dot(np.array(self._x))
        S = Hs.dot(P).dot(HsT) + Rm
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
        zv, Rm, Hs, HsT, update1 = self._measurement(z, R, H)
        return self._update_checked(zv, Rm, Hs, HsT, update1, failed_rows, mode, Gamma)

    def _update_checked(self, zv: np.ndarray, Rm: np.ndarray, Hs: np.ndarray, HsT: np.ndarray,
                        update1: Any, failed_rows: Any, mode: str, Gamma: Any) -> UpdateResult:
        """``update`` after ``_measurement`` validated z, R and H."""
        m = Hs.shape[0]
        failed = _failed_rows(failed_rows, m)
        if failed and mode != "nominal":
            G = _anomaly_covariance(Gamma, len(failed)) if mode == "known_anomaly" else None
            x, P, nu, S, beta2, thr, exceeded, fused, used, R_used = _update_failed(
                self._x, self._P, zv, Rm, Hs, self._sm.I, failed, mode, G, self.gate,
                self._reject)
            _check_finite_update(x, P, beta2, nu, S)
            self._x, self._P = x, P
            self.steps += 1
            if used:
                state = self._alarm.push(exceeded)
            else:  # nothing fused: the alarm window is not advanced
                state = ALARM_ACTIVE if self._alarm.active else ALARM_CLEAR
            return UpdateResult(nu=nu, S=S, beta2=float(beta2), threshold=thr,
                                exceeded=bool(exceeded), fused=bool(fused), alarm_state=state,
                                row_beta2=nu * nu / np.diag(S), rows_used=used, R_used=R_used)
        thr = self.gate.threshold(m)
        x, P, nu, S, _, beta2, exceeded, fused = _update_any(
            self._x, self._P, zv, Rm, Hs, HsT, self._sm.I, thr, self._reject, update1)
        _check_finite_update(x, P, beta2, nu, S)
        self._x, self._P = x, P
        self.steps += 1
        state = self._alarm.push(exceeded)
        return UpdateResult(nu=nu, S=S, beta2=float(beta2), threshold=thr,
                            exceeded=bool(exceeded), fused=bool(fused), alarm_state=state,
                            row_beta2=nu * nu / np.diag(S))

    def accuracy(self, D: Any = None) -> float:
        """The seed's estimation accuracy J = tr(D P) of the current covariance
        (``redundancy.accuracy``). ``D`` (n x n, physical units) defaults to the identity on the
        scaled states, D = diag(1 / scale^2): J = sum_i P_ii / scale_i^2, dimensionless (the
        prior std of every state counts as 1)."""
        if D is None:
            return accuracy(self._sm.I, _tri_to_full(self._P, self._sm.n))
        Dm = np.asarray(D, dtype=float)
        if Dm.shape != (self._sm.n, self._sm.n) or not np.all(np.isfinite(Dm)):
            raise CoreError(f"D must be a finite {self._sm.n} x {self._sm.n} matrix")
        return accuracy(Dm, self.P)

    def step(self, dt: float, z: Any, R: Any = None, u: Any = None) -> UpdateResult:
        """predict(dt, u) then update(z, R); everything is validated before the state changes.
        For a one-row model this is the generated prediction + update that ``run_forward``
        uses."""
        m = self.model.m
        zv = _check_z(z, m)
        Rm = self.model.R if R is None else _check_R(R, m)
        if m != 1:
            dt = _check_dt(dt)
            _check_u(self.model, u)
            self.predict(dt, u)
            return self.update(zv, Rm)
        return self._step1(_check_dt(dt), zv.item(), Rm.item(), _check_u(self.model, u))

    def step1(self, dt: float, z: float, r: float) -> UpdateResult:
        """:meth:`step` of a one-row model without a control input, on plain numbers: the
        same generated code, for a node's per-message path (NumPy's checks of a one-element
        z and R cost more than the step itself). CoreError, filter unchanged, on bad input."""
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
        return self._step1(_check_dt(dt), zf, rf, None)

    def _step1(self, dt: float, z: float, r: float, uv: np.ndarray | None) -> UpdateResult:
        """The one-row prediction + update on validated inputs."""
        sm = self._sm
        mt = sm.matrices(dt)
        bu = None if uv is None else tuple(mt.Bd.dot(uv).tolist())
        thr = self._threshold1
        step = _compiled("step", *mt.pattern, bu is not None, self._h_pattern)
        _, _, x, P, nu, s, _, beta2, exceeded, fused = step(
            self._x, self._P, mt.Phi_t, mt.Qd_t, bu, self._h, r, z, thr, self._reject)
        _check_finite_update(x, P, beta2, (nu,))
        self._x, self._P = x, P
        self.steps += 1
        state = self._alarm.push(exceeded)
        return UpdateResult(nu=np.array([nu]), S=np.array([[s]]), beta2=beta2, threshold=thr,
                            exceeded=exceeded, fused=fused, alarm_state=state,
                            row_beta2=np.array([beta2]))


# --------------------------------------------------------------------------- batch

@dataclass
class ForwardResult:
    """The forward filter over a record (physical units; N steps, n states, m rows, p inputs).

    ``dt[0] = 0``: the first step is an update on the prior. ``Phi`` for step k is
    ``model.discretize(dt[k])[0]``. ``K`` is the gain applied (zeros where not fused).
    """

    t: np.ndarray            # (N,) seconds
    dt: np.ndarray           # (N,)
    z: np.ndarray            # (N, m)
    R: np.ndarray            # (N, m, m)
    H: np.ndarray            # (N, m, n)
    x_prior: np.ndarray      # (N, n)
    P_prior: np.ndarray      # (N, n, n)
    x: np.ndarray            # (N, n) posterior x(i/i)
    P: np.ndarray            # (N, n, n)
    nu: np.ndarray           # (N, m)
    S: np.ndarray            # (N, m, m)
    K: np.ndarray            # (N, n, m)
    beta2: np.ndarray        # (N,)
    threshold: np.ndarray    # (N,)
    exceeded: np.ndarray     # (N,) bool
    fused: np.ndarray        # (N,) bool
    alarm_state: np.ndarray  # (N,) uint8
    u: np.ndarray | None = None  # (N, p)
    gate: GateConfig = field(default_factory=GateConfig)

    def __len__(self) -> int:
        return len(self.t)

    def alarms(self) -> list[dict]:
        """Alarm episodes: ``start_s`` = t of the raising update, ``end_s`` = t of the clearing
        update (or the last t when still active at the end), ``peak_beta2`` over the episode.
        Times are absolute (same base as ``t``)."""
        out: list[dict] = []
        raised = np.flatnonzero(self.alarm_state == ALARM_RAISED)
        cleared = np.flatnonzero(self.alarm_state == ALARM_CLEARED)
        for start in raised:
            later = cleared[cleared > start]
            end = int(later[0]) if later.size else len(self.t) - 1
            out.append({"start_s": float(self.t[start]), "end_s": float(self.t[end]),
                        "peak_beta2": float(np.max(self.beta2[start:end + 1]))})
        return out

    @classmethod
    def from_record(cls, model: LinearModel, t: Any, dt: Any, z: Any, R: Any, H: Any,
                    fused: Any, u: Any, x: Any, P: Any, gate: GateConfig = GateConfig(),
                    x0: Any = None, P0: Any = None) -> "ForwardResult":
        """Rebuild a ForwardResult from what FilterState messages carry (dt, z, R, H, fused, u,
        and the posterior x, P), e.g. from a recorded bag.

        The priors, innovations, S, K and beta2 are recomputed from the posterior of the previous
        step (``x_prior[k] = Phi_k x[k-1] + Bd_k u_k``); the prior of the first step is
        (x0, P0), default (0, model.P0), which a recording does not carry. Alarm states are
        recomputed with ``gate``.
        """
        sm = scaled_model(model)
        n = model.n
        tt = np.asarray(t, dtype=float).reshape(-1)
        N = tt.size
        if N == 0:
            raise CoreError("from_record: empty record")
        dtt = np.asarray(dt, dtype=float).reshape(-1)
        if dtt.shape != (N,) or not np.all(np.isfinite(dtt)) or np.any(dtt < 0):
            raise CoreError(f"from_record: dt must be {N} finite values >= 0")
        xa = np.asarray(x, dtype=float)
        Pa = np.asarray(P, dtype=float)
        if xa.shape != (N, n) or Pa.shape != (N, n, n):
            raise CoreError(f"from_record: x must be ({N}, {n}) and P ({N}, {n}, {n})")
        if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(Pa))):
            raise CoreError("from_record: x or P contains NaN or Inf")
        Ha = np.asarray(H, dtype=float)
        if Ha.ndim != 3 or Ha.shape[0] != N or Ha.shape[2] != n or not np.all(np.isfinite(Ha)):
            raise CoreError(f"from_record: H must be ({N}, m, {n}) and finite")
        m = Ha.shape[1]
        za = np.asarray(z, dtype=float).reshape(N, -1)
        if za.shape != (N, m) or not np.all(np.isfinite(za)):
            raise CoreError(f"from_record: z must be ({N}, {m}) and finite")
        Ra = _check_R_batch(np.asarray(R, dtype=float).reshape(N, m, m), N, m)
        fa = np.asarray(fused, dtype=bool).reshape(-1)
        if fa.shape != (N,):
            raise CoreError(f"from_record: fused must have {N} entries")
        ua = _check_u_batch(model, u, N)
        x0v, P0m = _check_prior(model, x0, P0)
        # priors, in scaled coordinates
        xs, Ps = sm.to_scaled(xa, Pa)
        x0s, P0s = sm.to_scaled(x0v, P0m)
        mats, idx = sm.matrices_for(dtt)
        Phi = np.stack([mt.Phi for mt in mats])[idx]
        Qd = np.stack([mt.Qd for mt in mats])[idx]
        xps = np.empty_like(xs)
        Pps = np.empty_like(Ps)
        xps[0], Pps[0] = x0s, P0s
        if N > 1:
            xps[1:] = np.einsum("kij,kj->ki", Phi[1:], xs[:-1])
            Pps[1:] = Phi[1:] @ Ps[:-1] @ np.swapaxes(Phi[1:], 1, 2) + Qd[1:]
            if ua is not None:
                Bd = np.stack([mt.Bd for mt in mats])[idx]
                xps[1:] += np.einsum("kip,kp->ki", Bd[1:], ua[1:])
        Pps = 0.5 * (Pps + np.swapaxes(Pps, 1, 2))
        Hs = Ha * sm.s
        nu = za - np.einsum("kmi,ki->km", Hs, xps)
        PHt = Pps @ np.swapaxes(Hs, 1, 2)
        S = Hs @ PHt + Ra
        S = 0.5 * (S + np.swapaxes(S, 1, 2))
        Sinv = np.linalg.inv(S)
        K = PHt @ Sinv * fa[:, None, None]
        beta2 = np.einsum("km,kmj,kj->k", nu, Sinv, nu)
        thr = np.full(N, gate.threshold(m))
        exceeded = beta2 > thr
        xp, Pp = sm.to_physical(xps, Pps)
        return cls(t=tt, dt=dtt, z=za, R=Ra, H=Ha, x_prior=xp, P_prior=Pp, x=xa.copy(),
                   P=Pa.copy(), nu=nu, S=S, K=K * sm.s[None, :, None], beta2=beta2,
                   threshold=thr, exceeded=exceeded, fused=fa,
                   alarm_state=alarm_states(exceeded, gate), u=ua, gate=gate)


def _check_u_batch(model: LinearModel, u: Any, N: int) -> np.ndarray | None:
    if u is None:
        return None
    if model.B is None:
        raise CoreError(f"model {model.name!r} has no input matrix B; a control input u was given")
    p = model.B.shape[1]
    arr = np.asarray(u, dtype=float)
    if arr.size == N * p:
        arr = arr.reshape(N, p)
    if arr.shape != (N, p) or not np.all(np.isfinite(arr)):
        raise CoreError(f"control input u must be ({N}, {p}) and finite")
    return arr


def check_times(t: Any, what: str = "t") -> np.ndarray:
    """A 1-D array of finite, strictly increasing times (CoreError otherwise)."""
    try:
        arr = np.asarray(t, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CoreError(f"{what} is not numeric") from None
    if arr.size == 0:
        raise CoreError(f"{what} is empty")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"{what} contains NaN or Inf")
    steps = np.diff(arr)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise CoreError(f"{what} must be strictly increasing; {what}[{k + 1}] = {arr[k + 1]!r} "
                        f"follows {arr[k]!r}")
    return arr


@dataclass
class MeasurementRecord:
    """What the forward filter is given, checked: everything the backward information filter
    needs (:func:`flight_fdi.core.smoother.backward_information` reads only these fields of a
    ForwardResult), so that it can start before the forward pass when every sample is fused
    (gate action ``"flag"``)."""

    t: np.ndarray            # (N,) strictly increasing seconds
    dt: np.ndarray           # (N,), dt[0] = 0
    z: np.ndarray            # (N, m)
    R: np.ndarray            # (N, m, m)
    H: np.ndarray            # (N, m, n)
    fused: np.ndarray        # (N,) bool: all True (what the forward pass fuses with "flag")
    u: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)


def measurement_record(model: LinearModel, t: Any, z: Any, R: Any = None,
                       u: Any = None) -> MeasurementRecord:
    """Check a record's inputs (as :func:`run_forward` takes them) and build its
    :class:`MeasurementRecord`; CoreError on anything invalid."""
    n, m = model.n, model.m
    tt = check_times(t)
    N = tt.size
    try:
        za = np.asarray(z, dtype=float)
    except (TypeError, ValueError):
        raise CoreError("z is not numeric") from None
    if za.size != N * m:
        raise CoreError(f"z must have shape ({N}, {m}), got {za.shape}")
    za = za.reshape(N, m)
    bad = ~np.all(np.isfinite(za), axis=1)
    if np.any(bad):
        raise CoreError(f"z contains NaN or Inf at {int(bad.sum())} steps (first at index "
                        f"{int(np.argmax(bad))})")
    if R is None:
        Ra = np.broadcast_to(model.R, (N, m, m)).copy()
    else:
        Ra = np.asarray(R, dtype=float)
        if Ra.size == N * m * m:
            Ra = Ra.reshape(N, m, m)
        Ra = _check_R_batch(Ra, N, m)
    ua = _check_u_batch(model, u, N)
    dt = np.empty(N)
    dt[0] = 0.0
    dt[1:] = np.diff(tt)
    return MeasurementRecord(t=tt, dt=dt, z=za, R=Ra, H=np.broadcast_to(model.H, (N, m, n)).copy(),
                             fused=np.ones(N, dtype=bool), u=ua)


def run_forward(model: LinearModel, t: Any, z: Any, R: Any = None, u: Any = None,
                gate: GateConfig = GateConfig(), x0: Any = None, P0: Any = None,
                record: MeasurementRecord | None = None) -> ForwardResult:
    """Run the forward filter over a record (the same step functions as :class:`KalmanFilter`).

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
    tt, za, Ra, ua, dt = record.t, record.z, record.R, record.u, record.dt
    N = tt.size
    x0v, P0m = _check_prior(model, x0, P0)

    mats, idx = sm.matrices_for(dt)
    thr = gate.threshold(m)
    reject = gate.action == "reject"

    xs, Ps = sm.to_scaled(x0v, P0m)
    x, P = tuple(xs.tolist()), tuple(_full_to_tri(Ps).tolist())
    with _gc_paused():
        if m == 1:
            rows = _forward1(sm, mats, idx, ua, x, P, za[:, 0].tolist(),
                             Ra[:, 0, 0].tolist(), thr, reject)
        else:
            # outputs in flat lists of floats (the cheapest way to get them into arrays)
            xp_l, Pp_l, x_l, P_l, nu_l, S_l, K_l = [], [], [], [], [], [], []
            b2_l: list = []
            fus_l: list = []
            steps = [mats[i] for i in idx.tolist()]
            bus = [None] * N if ua is None else _control_terms(mats, idx, ua)
            for k in range(N):
                if k:
                    mt = steps[k]
                    bu = bus[k]
                    if bu is None:
                        x, P = mt.predict(x, P, mt.Phi_t, mt.Qd_t, None)
                    else:
                        x, P = mt.predict_bu(x, P, mt.Phi_t, mt.Qd_t, bu)
                xp_l.extend(x)
                Pp_l.extend(P)
                x, P, nu, S, K, b2, _, fus = _update_any(x, P, za[k], Ra[k], sm.H, sm.HT, sm.I,
                                                         thr, reject, None)
                x_l.extend(x)
                P_l.extend(P)
                nu_l.extend(nu.tolist())
                S_l.extend(S.ravel().tolist())
                K_l.extend(K.ravel().tolist())
                b2_l.append(b2)
                fus_l.append(fus)

    s, SS = sm.s, sm.SS
    nt = n * (n + 1) // 2

    def arr(values: list, *shape: int) -> np.ndarray:
        return np.fromiter(values, dtype=float, count=len(values)).reshape(N, *shape)

    if m == 1:  # one row per step: x- P- x+ P+ K nu S beta2 fused
        cut = np.cumsum([0, n, nt, n, nt, n, 1, 1, 1, 1])
        xp_a, Pp_a, x_a, P_a, K_a, nu_a, S_a, b2_a, fus_a = (
            rows[:, cut[i]:cut[i + 1]] for i in range(9))
        K_a, nu_a, S_a = K_a[:, :, None], nu_a, S_a[:, :, None]
        beta2, fused = b2_a[:, 0].copy(), fus_a[:, 0] != 0.0
    else:
        xp_a, Pp_a, x_a, P_a = arr(xp_l, n), arr(Pp_l, nt), arr(x_l, n), arr(P_l, nt)
        nu_a, S_a, K_a = arr(nu_l, m), arr(S_l, m, m), arr(K_l, n, m)
        beta2, fused = arr(b2_l), np.array(fus_l, dtype=bool)
    exceeded = beta2 > thr
    return ForwardResult(
        t=tt, dt=dt, z=za, R=Ra, H=record.H,
        x_prior=xp_a * s, P_prior=_tri_to_full(Pp_a, n) * SS,
        x=x_a * s, P=_tri_to_full(P_a, n) * SS,
        nu=np.ascontiguousarray(nu_a), S=np.ascontiguousarray(S_a), K=K_a * s[None, :, None],
        beta2=beta2, threshold=np.full(N, thr), exceeded=exceeded,
        fused=fused, alarm_state=alarm_states(exceeded, gate), u=ua, gate=gate)


def _control_terms(mats: list, idx: np.ndarray, ua: np.ndarray) -> list[tuple]:
    """Bd u of every step (scaled), as float tuples for the generated prediction."""
    Bd = np.stack([mt.Bd for mt in mats])[idx]
    return [tuple(row) for row in np.einsum("kip,kp->ki", Bd, ua).tolist()]


#: steps per call of the generated forward loop: its output list (36 Python floats per step for
#: the INS channel, ~1.2 kB) is turned into an array chunk by chunk, not for a whole 10-hour flight
_FORWARD_CHUNK = 16384


def _forward1(sm: ScaledModel, mats: list, idx: np.ndarray, ua: np.ndarray | None,
              x: tuple, P: tuple, zl: list, rl: list, thr: float, reject: bool) -> np.ndarray:
    """The one-row forward pass over a record: (N, :func:`forward_row_width`) floats per step.
    The update on the prior, then the generated ``run`` loop over the rest, chunk by chunk
    (``_run_source``; for jittered dt over per-step matrices, on the union of their sparsity
    patterns: a term with an exact-zero factor changes no bit)."""
    n, N = sm.n, len(zl)
    W = forward_row_width(n)
    rows = np.empty((N, W))
    h = sm.H[0].tolist()
    x1, P1, nu, s, K, b2, _, fus = sm.update1_for(sm.H)(x, P, h, rl[0], zl[0], thr, reject)
    rows[0] = [*x, *P, *x1, *P1, *K, nu, s, b2, 1.0 if fus else 0.0]
    x, P = x1, P1
    if N == 1:
        return rows
    steps = idx.tolist()
    used = [mats[i] for i in sorted(set(steps[1:]))]
    h_mask = tuple(bool(v) for v in sm.H[0] != 0)
    bus = None if ua is None else _control_terms(mats, idx, ua)
    constant = len(used) == 1
    if constant:
        mt = used[0]
        run = _compiled("run", *mt.pattern, ua is not None, h_mask, True)
        Phi, Qd = mt.Phi_t, mt.Qd_t
    else:
        phi_mask = tuple(tuple(any(mt.pattern[1][i][j] for mt in used) for j in range(n))
                         for i in range(n))
        q_mask = tuple(tuple(any(mt.pattern[2][i][j] for mt in used) for j in range(n))
                       for i in range(n))
        run = _compiled("run", n, phi_mask, q_mask, ua is not None, h_mask, False)
    for a in range(1, N, _FORWARD_CHUNK):
        b = min(N, a + _FORWARD_CHUNK)
        if not constant:
            Phi = [mats[i].Phi_t for i in steps[a:b]]
            Qd = [mats[i].Qd_t for i in steps[a:b]]
        flat: list = []
        x, P = run(x, P, Phi, Qd, None if bus is None else bus[a:b], h, rl[a:b], zl[a:b], thr,
                   reject, flat.extend)
        rows[a:b] = np.fromiter(flat, dtype=float, count=len(flat)).reshape(b - a, W)
    return rows
