"""The post-flight part of the ins3d analysis: the backward sweep over the forward pass, the
seed method (chi^2 J with effective dof, UDU^T / LDL^T localisation, Fisher test: the single-axis
``core.diagnosis.diagnose`` on the sweep's terms), the GLR curves and the isolation
(``glr3d``), and the ``post_flight`` result in the form of ``result-v1.schema.json``.
"""
from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from ..diagnosis import DiagnosisConfig, SeedDiagnosis, diagnose
from ..errors import CoreError
from ..ldl import localization
from ..threads import usable_threads
from .backward import ACC_A, ACC_R, GYR_A, GYR_R, REF, backward_sweep
from .combination import combine_kept
from .data import NavSteps, RefRows
from .filter import Ins3dForward, run_forward, white_variance
from .glr3d import (AMBIGUITY_MARGIN, GlrCurve, Isolation, curves, hypotheses, joint,
                    resolved_time, settle)
from .grade_file import signature_error_of
from .model import IBA, IBG, Ins3dModel
from .signature import signature_series


@dataclass
class Ins3dBackward:
    """The backward sweep per reference update (sorted), physical units."""

    t: np.ndarray            # (M,) update times
    x_s: np.ndarray          # (M, n) smoothed state at the update's boundary
    sd_s: np.ndarray         # (M, n) its sd
    terms: np.ndarray        # (M, n) cumulative element terms J(i/k)
    dof: np.ndarray          # (M, n) their effective degrees of freedom
    normalized: np.ndarray   # (M, n)
    v_tilde: np.ndarray      # (M, n)
    d: np.ndarray            # (M, n)
    eta: np.ndarray          # (M, pB) fault information vector (scaled fault columns)
    I3: np.ndarray           # (M, 3, 6, 6) its information, group blocks
    oe: np.ndarray           # (M, rows) outlier information vector
    oI: np.ndarray           # (M, rows, rows)
    sB: np.ndarray           # (pB,) scales of the fault columns (SI per scaled unit)
    first: np.ndarray        # (U,) first update of every boundary with updates (the onsets)
    joint: dict[str, np.ndarray] | None = None   # glr3d.joint over the onsets

    def at_onsets(self, a: np.ndarray) -> np.ndarray:
        """The rows of a per-update array at the onsets (``first``); the array itself when
        every boundary carries one update (no copy)."""
        return a if self.first.size == self.t.size else a[self.first]


def fault_scales(model: Ins3dModel, duration: float) -> np.ndarray:
    """SI per scaled unit of every fault column: the grade's bias sigma for a step, that over
    the flight's duration for a ramp, 0.1 m/s for a reference offset."""
    s = np.sqrt(model.p0())
    sB = np.empty(REF + model.rows)
    sB[ACC_A:ACC_A + 3] = s[IBA:IBA + 3]
    sB[ACC_R:ACC_R + 3] = s[IBA:IBA + 3] / duration
    sB[GYR_A:GYR_A + 3] = s[IBG:IBG + 3]
    sB[GYR_R:GYR_R + 3] = s[IBG:IBG + 3] / duration
    sB[REF:] = 0.1
    return sB


def fused_forward(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd):
    """The forward pass the post-flight part runs on: ``fwd``, or when it rejected updates
    (gate action ``reject``) the same pass fusing every update (the post-flight part judges all
    the data)."""
    if fwd.fused is not None and not np.all(fwd.fused):
        fwd = run_forward(model, steps, refs, x0=fwd.x0, P0=fwd.P0, keep_prior=True)
    return fwd


def kernel_args(model: Ins3dModel, steps: NavSteps, refs: RefRows) -> tuple:
    """The compiled post-flight kernels' flight arguments (navigation steps, model parameters,
    fault scales, reference rows), built once per flight; also for ``eval.onset_bound``."""
    return (steps.C, steps.f_n, steps.v, steps.lat, steps.h, steps.dt,
            np.ascontiguousarray(steps.t[:-1] - steps.t[0]), model.kernel_params(), model.qc(),
            np.sqrt(model.p0()), fault_scales(model, float(steps.t[-1] - steps.t[0])),
            refs.step)


def run_backward(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
                 rank_tol: float, threads: int | None = None, chunk: int | None = None
                 ) -> Ins3dBackward:
    """The backward sweep (``refs`` sorted by step, ``fwd`` run with keep_prior=True) and the
    3-dof statistics of its fault blocks (``glr3d.joint``). With ``threads`` = 2 (default:
    when the process may run on two or more cores) the sweep keeps (lambda, Lambda) of the
    next ``chunk`` boundaries with updates (default: 0.5 MB of them) and a second thread makes
    the combination from them while the sweep goes on (``combination.combine_kept``; the same
    numbers as one thread).
    When the forward pass rejected updates (gate action ``reject``), the sweep runs on a
    forward pass that fuses every update (``backward.py``: the post-flight part judges all the
    data)."""
    if fwd.Ps_prior is None:
        raise CoreError("ins3d backward: the forward pass must keep its priors (keep_prior)")
    fwd = fused_forward(model, steps, refs, fwd)
    n, rows, m = model.n, model.rows, refs.t.size
    sweep, combine, out, eta, I3 = _sweep_args(model, steps, refs, fwd, rank_tol, fwd.nu)
    sB = sweep[9]
    first = np.flatnonzero(np.r_[True, refs.step[1:] != refs.step[:-1]]) if m else \
        np.zeros(0, dtype=np.int64)
    if threads is None:
        threads = usable_threads()
    if threads > 1:
        if chunk is None:
            chunk = max(64, (1 << 19) // (8 * n * (n + 1)))
        stats = {k: np.empty(first.size) for k in joint(eta[:0], I3[:0], rows)}

        def joint_at(onsets: np.ndarray) -> None:       # rows of the onsets a chunk passed
            at = np.searchsorted(first, onsets)
            for k, v in joint(eta[onsets], I3[onsets], rows).items():
                stats[k][at] = v

        bad = _sweep_beside_combination(sweep, combine, len(steps), m, chunk, joint_at)
    else:
        bad = backward_sweep(*sweep, len(steps), m, 3, *_kept(0, n))[3]
        on = slice(None) if first.size == m else first      # (no copy when all are)
        stats = joint(eta[on], I3[on], rows)
    _positive_definite(steps, bad)
    return Ins3dBackward(refs.t, *out[:7], eta, I3, *out[7:], sB, first, stats)


def smoothed_states(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
                    rank_tol: float) -> np.ndarray:
    """The smoothed state x_s (M, n) of ``run_backward`` alone: the sweep without the fault
    information and its statistics (``backward_sweep`` part 1, one thread) -- what a
    relinearisation needs (``nonlinear.relinearized_cost``), bit-identical to
    ``run_backward(...).x_s``."""
    if fwd.Ps_prior is None:
        raise CoreError("ins3d backward: the forward pass must keep its priors (keep_prior)")
    fwd = fused_forward(model, steps, refs, fwd)
    sweep, _, out, _, _ = _sweep_args(model, steps, refs, fwd, rank_tol, fwd.nu)
    bad = backward_sweep(*sweep, len(steps), refs.t.size, 1, *_kept(0, model.n))[3]
    _positive_definite(steps, bad)
    return out[0]


def _sweep_args(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
                rank_tol: float, nu: np.ndarray) -> tuple:
    """The backward sweep's arguments (``backward_sweep``: up to ``state``) on the innovations
    ``nu`` (M, rows), the combination's (``combine_kept``) and the output buffers (the
    combination's ``out``, eta, I3)."""
    n, rows, m = model.n, model.rows, refs.t.size
    args = kernel_args(model, steps, refs)
    sB = args[10]
    out = (*(np.empty((m, n)) for _ in range(3)), np.empty((m, n), dtype=np.int64),
           *(np.empty((m, n)) for _ in range(3)), np.empty((m, rows)), np.empty((m, rows, rows)))
    eta, I3 = np.empty((m, sB.size)), np.zeros((m, 3, 6, 6))
    z, r, a = np.ascontiguousarray(refs.z), white_variance(model, refs.r), \
        np.ascontiguousarray(refs.a)
    sweep = (*args[:8], *args[9:], z, r, a, *model.row_args(), fwd.xs_prior, fwd.Ps_prior,
             fwd.Ks, fwd.S_inv, np.ascontiguousarray(nu), rank_tol, out, eta, I3,
             (np.zeros(n), np.zeros((n, n)), np.zeros(sB.size), np.zeros((n, sB.size)),
              np.zeros((sB.size, sB.size))))
    combine = (args[9], a, *model.row_args(), z, r, fwd.xs_prior, fwd.Ps_prior, rank_tol, out)
    return sweep, combine, out, eta, I3


def fault_information(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
                      nu: np.ndarray) -> np.ndarray:
    """The backward sweep's fault information vector eta (M, pB) with the innovations replaced
    by ``nu`` (M, rows): eta is linear in the innovations, so with ``nu`` = the signature rho_g
    of another fault g (``signature``) tau' eta at an onset is the cross information
    sum_j rho_h' S^-1 rho_g of hypothesis h (direction tau, that onset) with g -- for every
    onset and hypothesis in one sweep (``fwd``: the pass the curves judged, ``fused_forward``;
    the fault blocks only)."""
    sweep, _, _, eta, _ = _sweep_args(model, steps, refs, fwd, 0.0, nu)
    bad = backward_sweep(*sweep, len(steps), refs.t.size, 2, *_kept(0, model.n))[3]
    _positive_definite(steps, bad)
    return eta


def _positive_definite(steps: NavSteps, bad: int) -> None:
    """The sweep's failure (``bad``: the boundary where P_f is not positive definite, -1:
    none) as one CoreError line."""
    if bad >= 0:
        raise CoreError(f"ins3d backward: the forward covariance is not positive definite at "
                        f"t = {steps.t[bad]:.3f} s")


def _kept(size: int, n: int) -> tuple:
    """Buffers of ``size`` boundaries for the sweep's kept (lambda, Lambda)."""
    return (np.empty(size, dtype=np.int64), np.empty((size, 2), dtype=np.int64),
            np.empty((size, n)), np.empty((size, n, n)))


def _sweep_beside_combination(sweep: tuple, combine: tuple, K: int, m: int, chunk: int,
                              then: Callable[[np.ndarray], None]) -> int:
    """The sweep (fault blocks) on this thread, ``chunk`` boundaries at a time, and on a
    second thread the combination of the previous chunk, then ``then`` of the first updates of
    its boundaries (two buffers; the kernels release the GIL). Returns the boundary where P_f
    is not positive definite, or -1."""
    n = combine[0].size
    buf = [_kept(chunk, n), _kept(chunk, n)]

    def combination(count: int, kb: np.ndarray, jb: np.ndarray, *kept: np.ndarray) -> int:
        bad = combine_kept(count, kb, jb, *kept, *combine)
        then(jb[count - 1::-1, 0] if count else jb[:0, 0])
        return bad

    k, j1, c, bad = K, m, 0, -1
    with ThreadPoolExecutor(max_workers=1) as pool:
        done = None
        while k >= 0:
            k, j1, count, _ = backward_sweep(*sweep, k, j1, 6, *buf[c % 2])
            if done is not None:                # the other buffer is free again
                bad = max(bad, done.result())
            done = pool.submit(combination, count, *buf[c % 2])
            c += 1
        bad = max(bad, done.result())
    return bad


def seed_method(model: Ins3dModel, bwd: Ins3dBackward, config: DiagnosisConfig
                ) -> SeedDiagnosis:
    """The single-axis seed method (``diagnose``) on the sweep's element terms, one sample per
    boundary with updates."""
    at = bwd.at_onsets
    loc = localization(at(bwd.v_tilde), at(bwd.d), at(bwd.terms), at(bwd.dof),
                       at(bwd.normalized))
    t = at(bwd.t)
    return diagnose(SimpleNamespace(n=model.n, state_names=list(model.names)),
                    SimpleNamespace(t=t), SimpleNamespace(t=t, rank_tol=config.rank_tol,
                                                          localization=loc), config)


def glr_curves(model: Ins3dModel, steps: NavSteps, bwd: Ins3dBackward,
               eta: np.ndarray | None = None, I3: np.ndarray | None = None
               ) -> dict[str, GlrCurve]:
    """The GLR curves of every hypothesis over the onsets; ``eta``, ``I3`` (at the onsets):
    other information than the sweep's (``turn_on``: conditional on faults taken as present)."""
    at = bwd.at_onsets
    return curves(hypotheses(model.rows, model.height_row), at(bwd.t), float(steps.t[0]),
                  float(steps.t[-1] - steps.t[0]), at(bwd.eta) if eta is None else eta,
                  at(bwd.I3) if I3 is None else I3, bwd.sB, bwd.t, bwd.oe, bwd.oI)


def direction(model: Ins3dModel, cv: GlrCurve, t_start: float, duration: float) -> np.ndarray:
    """tau (pB,) of a hypothesis at its best onset (a ramp: e_r - (theta~ / T) e_a)."""
    tau = np.zeros(REF + model.rows)
    h = cv.hypothesis
    tau[h.column] = 1.0
    if h.kind == "ramp":
        tau[h.column - 3] = -(cv.t[cv.best] - t_start) / duration
    return tau


def signature(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
              cv: GlrCurve) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hypothesis at its best onset through the forward filter (``signature_series``): the
    cumulative e and d with the data up to every update (M,) and its signature rho (M, rows),
    m/s per scaled unit of its direction."""
    args = kernel_args(model, steps, refs)
    k0 = int(np.searchsorted(steps.t, cv.t[cv.best] - 1e-9))
    m = refs.t.size
    e, d, rho = np.zeros(m), np.zeros(m), np.zeros((m, model.rows))
    tau = direction(model, cv, float(steps.t[0]), float(steps.t[-1] - steps.t[0]))
    signature_series(*args, np.ascontiguousarray(refs.a), *model.row_args(), fwd.Ks, fwd.S_inv,
                     fwd.nu, k0, tau, e, d, rho)
    return e, d, rho


def _glr(e: np.ndarray, d: np.ndarray) -> np.ndarray:
    return np.where(d > 0, e * e / np.where(d > 0, d, 1.0), 0.0)


def data_up_to(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
               cv: GlrCurve) -> np.ndarray:
    """GLR(t) of a hypothesis at its best onset with the data up to every update (M,)."""
    return _glr(*signature(model, steps, refs, fwd, cv)[:2])


def resolve(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
            cv: dict[str, GlrCurve], iso: Isolation, signature_error: float | None = None,
            given=None) -> None:
    """For an IMU/jump isolation with a rival: the two fitted together (their signatures
    through the forward filter; ``glr3d.settle`` with the model's relative
    ``signature_error``, default the grade's: ``grade_file.signature_error_of``, may make a
    single one ``ambiguous``), then ``iso.gap`` (the decision's: net of ``iso.offset``, NaN
    before the best's onset) and, for a single one, ``iso.ambiguity_resolved_s``.
    ``given`` (``turn_on.Given``): the pair fitted together with faults taken as present (the
    turn-on biases; ``cv`` then holds the curves conditional on them), the same test on the
    statistics with those faults profiled out, at every update (the gap)."""
    if iso.isolation == "none" or iso.rival is None or cv[iso.best].hypothesis.kind == \
            "outliers":
        return
    if signature_error is None:
        signature_error = signature_error_of(model.grade)
    fwd = fused_forward(model, steps, refs, fwd)        # the pass the GLR curves judged
    with ThreadPoolExecutor(max_workers=1) as pool:     # the kernels release the GIL
        rival = pool.submit(signature, model, steps, refs, fwd, cv[iso.rival])
        e_b, d_b, rho_b = signature(model, steps, refs, fwd, cv[iso.best])
        e_r, d_r, rho_r = rival.result()
    if given is None:
        x = float(np.einsum("mi,mij,mj->", rho_b, fwd.S_inv, rho_r))
        e, D = np.array([e_b[-1], e_r[-1]]), np.array([[d_b[-1], x], [x, d_r[-1]]])
        gap = _glr(e_b, d_b) - _glr(e_r, d_r)
    else:
        x = np.cumsum(np.einsum("mi,mij,mj->m", rho_b, fwd.S_inv, rho_r))
        es, Ds = given.condition(np.stack([e_b, e_r], axis=1),
                                 np.stack([np.stack([d_b, x], 1), np.stack([x, d_r], 1)], 1),
                                 np.stack([rho_b, rho_r]))
        e, D = es[-1], Ds[-1]
        gap = _glr(es[:, 0], Ds[:, 0, 0]) - _glr(es[:, 1], Ds[:, 1, 1])
    settle(iso, e, D, signature_error, AMBIGUITY_MARGIN)
    # the decision's gap (net of the thresholds' offset, as isolate), from the best's onset on:
    # before it the best explains nothing and the offset alone would "tell them apart"
    b = cv[iso.best]
    iso.gap = np.where(refs.t >= b.t[b.best], gap - iso.offset, np.nan)
    if iso.isolation == "single":
        iso.ambiguity_resolved_s = resolved_time(refs.t, iso.gap, AMBIGUITY_MARGIN)


__all__ = ["Ins3dBackward", "data_up_to", "direction", "fault_information", "fault_scales",
           "fused_forward", "glr_curves", "kernel_args", "resolve", "run_backward", "seed_method",
           "signature", "smoothed_states"]
