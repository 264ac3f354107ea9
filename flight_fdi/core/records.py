"""What the forward filter is given and what it gives, over a whole record:
:class:`MeasurementRecord` (checked inputs) and :class:`ForwardResult` (every intermediate
quantity, physical units)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .checks import check_prior, check_R_batch, check_times, check_u_batch
from .errors import CoreError
from .gate import ALARM_CLEARED, ALARM_RAISED, GateConfig, alarm_states
from .models import LinearModel
from .scaled import scaled_model


#: a float64 block at least this large (4 MiB) is backed by huge pages (numpy advises the kernel
#: to, above 4 MiB): one page fault per 2 MiB instead of per 4 KiB when the kernels first write
#: their outputs
_HUGE_BLOCK = 1 << 19
#: below this many values the outputs are allocated as they are
_SMALL = 1 << 16


def output_arrays(shapes: dict) -> dict:
    """{name: empty float64 array of that shape}, views of one block: a kernel's per-step
    outputs over a long record would otherwise cost a page fault every 4 KiB on first write (a
    fifth of the forward filter's time on a 20 000-step record)."""
    sizes = [int(np.prod(shape)) for shape in shapes.values()]
    total = sum(sizes)
    if total < _SMALL:
        return {name: np.empty(shape) for name, shape in shapes.items()}
    block = np.empty(max(total, _HUGE_BLOCK))
    out, start = {}, 0
    for (name, shape), size in zip(shapes.items(), sizes):
        out[name] = block[start:start + size].reshape(shape)
        start += size
    return out


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
        Ra = check_R_batch(np.asarray(R, dtype=float).reshape(N, m, m), N, m)
        fa = np.asarray(fused, dtype=bool).reshape(-1)
        if fa.shape != (N,):
            raise CoreError(f"from_record: fused must have {N} entries")
        ua = check_u_batch(model, u, N)
        x0v, P0m = check_prior(model, x0, P0)
        # priors, in scaled coordinates
        xs, Ps = sm.to_scaled(xa, Pa)
        x0s, P0s = sm.to_scaled(x0v, P0m)
        Phi, Qd, Bd = sm.discretize_all(dtt)
        xps = np.empty_like(xs)
        Pps = np.empty_like(Ps)
        xps[0], Pps[0] = x0s, P0s
        if N > 1:
            xps[1:] = np.einsum("kij,kj->ki", Phi[1:], xs[:-1])
            Pps[1:] = Phi[1:] @ Ps[:-1] @ np.swapaxes(Phi[1:], 1, 2) + Qd[1:]
            if ua is not None:
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



@dataclass
class MeasurementRecord:
    """What the forward filter is given, checked (:func:`measurement_record`): the inputs of
    :func:`~flight_fdi.core.kalman.run_forward` (``record=``)."""

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
        Ra = check_R_batch(Ra, N, m)
    ua = check_u_batch(model, u, N)
    dt = np.empty(N)
    dt[0] = 0.0
    dt[1:] = np.diff(tt)
    return MeasurementRecord(t=tt, dt=dt, z=za, R=Ra, H=np.broadcast_to(model.H, (N, m, n)).copy(),
                             fused=np.ones(N, dtype=bool), u=ua)
