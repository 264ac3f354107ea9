#!/usr/bin/env python3
"""Benchmark: the 3-D analysis (``analyze_ins3d``) against FilterPy running the same 15-state LTV
filter + RTS smoother on the same flight, in the same run (a script, not a test; issue 15 item 6).

The flight: ``cruise_turns``, navigation grade, INS at 100 Hz (/ins/imu, /ins/velocity: the
propagation steps), GNSS velocity at 10 Hz (east and north rows). The model:
``Ins3dModel.from_grade(rows=2, vertical="damped")`` with the reference Markov states and the
latency state: 12 + 2 + 1 = 15 states, as ``analyze_ins3d`` uses it.

The baseline (``filterpy.kalman.KalmanFilter``, Joseph-form update, and its ``rts_smoother``) runs
the model as the issue defines it -- discretised per INS step at the actual dt: Phi_k, Q_k of
every 100-Hz step (``model.fill_F`` + ``model.discretize``; computed *before* its timer starts, the
baseline is charged for the filter and the smoother only), the same 10-Hz updates with the same
H_j (velocity rows, Markov columns, the latency column a_n), R_j and initial covariance. The
project's analysis takes the same 100-Hz input and merges the steps between updates
(``data.coarsen``), so it propagates ten times less often; the agreement is checked and printed
(innovations in units of their sd, smoothed states in units of the RTS sd). A second baseline
runs FilterPy on the merged steps themselves (the same arithmetic the project does: innovations
equal to 1e-6), the like-for-like ratio.

Both ratios: FilterPy's filter + RTS over the project's whole analysis (forward filter, backward
sweep, two-filter chi^2 with the seed method, GLR over every onset and hypothesis, isolation,
ambiguity time, the ``post_flight`` section; the observability Gramian, a report item, left
out), runs interleaved, best of ``--repeat``; the project with its default threads (two on this
machine: the discretisation runs ahead of the forward filter, the fault blocks beside the
combination) and on one thread (``FLIGHT_FDI_THREADS=1``: wall = CPU, what a loaded machine
gives). Stamps: regular, and jittered by U(-1, +1) ms per /ins/imu stamp (``--jitter-ms``):
Phi_k then changes with every step's dt. For information, the same on the analysis's default
19-state model (vertical loop with the baro aiding, three rows; ``--no-19`` skips it). The
2-hour target
(<= 5 s for the whole analysis, GLR included) is bench/bench_ins3d.py (``--two-hours`` here runs
the project's analysis of the whole 2-hour flight once as well). The machine is shared: wall
times vary with the load; the ratio, measured in the same run, is the result.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time
from dataclasses import replace

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from flight_fdi.bagio.ins3d_input import from_flight  # noqa: E402
from flight_fdi.core.ins3d.analysis import analyze_ins3d  # noqa: E402
from flight_fdi.core.ins3d.data import RefRows  # noqa: E402
from flight_fdi.core.ins3d.filter import scaled_H, white_variance  # noqa: E402
from flight_fdi.core.ins3d.model import Ins3dModel  # noqa: E402
from flight_fdi.core.ins3d.dynamics import discretize, fill_F  # noqa: E402
from flight_fdi.core.threads import ENV  # noqa: E402
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d  # noqa: E402
from flight_fdi.sim.trajectory import TrajectoryConfig  # noqa: E402

TARGET_RATIO = 20.0
TARGET_2H_S = 5.0


def flight_input(duration_s: float, jitter_ms: float, seed: int = 1):
    """The analysis input of a simulated flight at 100 Hz; stamps jittered by U(-j, j) ms."""
    fl = simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(duration_s=duration_s), seed=seed))
    inp = from_flight(fl, imu_rate_hz=100.0, velocity_rate_hz=100.0)
    if jitter_ms > 0:
        rng = np.random.default_rng(seed)
        s = inp.steps
        t = s.t + rng.uniform(-jitter_ms, jitter_ms, s.t.size) * 1e-3
        inp.steps = replace(s, t=t, dt=np.diff(t))
    return inp


#: the 15-state model of the issue (damped vertical channel, east and north rows) and the
#: analysis's default (vertical loop with the baro aiding, three rows: 19 states)
MODELS = {"15": {"rows": 2, "vertical": "damped"}, "19": {"rows": 3, "vertical": "loop"}}


def project(inp, grade: str = "navigation", model: str = "15", threads: int | None = None
            ) -> tuple[float, float, object]:
    """(wall s, CPU s, analysis) of the project's 3-D analysis of the input: forward filter,
    backward sweep, two-filter chi^2 with the seed method, GLR isolation, the post_flight
    section (the observability Gramian, a report item, is left out). ``threads``: the
    analysis's threads (``FLIGHT_FDI_THREADS``; default: the cores it may use)."""
    old = os.environ.get(ENV)
    if threads is not None:
        os.environ[ENV] = str(threads)
    try:
        t0, c0 = time.perf_counter(), time.process_time()
        an = analyze_ins3d(inp.steps, inp.refs, grade=grade, with_observability=False,
                           **MODELS[model])
        an.post_flight_dict()
        return time.perf_counter() - t0, time.process_time() - c0, an
    finally:
        if threads is not None:
            if old is None:
                del os.environ[ENV]
            else:
                os.environ[ENV] = old


def model_matrices(model: Ins3dModel, steps, k_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Phi_k, Q_k of steps 0 .. k_max-1 (as the project's forward kernel builds them)."""
    n = model.n
    F = np.empty((n, n))
    Phi = np.empty((k_max, n, n))
    Q = np.empty((k_max, n, n))
    for k in range(k_max):
        fill_F(F, steps.C[k], steps.f_n[k], steps.v[k], steps.lat[k], steps.h[k],
               model.kernel_params())
        discretize(F, steps.dt[k], model.qc(), Phi[k], Q[k])
    return Phi, Q


def filterpy_run(model: Ins3dModel, steps, refs, P0: np.ndarray):
    """(wall s and CPU s of FilterPy's filter + RTS, wall s of building Phi_k, Q_k, innovations
    (M, rows), smoothed states (K+1, n), their sd (K+1, n)) over all steps (``refs`` sorted by
    step)."""
    from filterpy.kalman import KalmanFilter

    k_max = len(steps)
    t_phi = time.perf_counter()
    Phi, Q = model_matrices(model, steps, k_max)
    t_phi = time.perf_counter() - t_phi
    ref_step, z, a = refs.step, refs.z, refs.a
    r = white_variance(model, refs.r)
    rows, n = model.rows, model.n
    ones = np.ones(n)
    H = [scaled_H(ones, a[j], *model.row_args())
         for j in range(ref_step.size)]
    R = [np.diag(r[j, :rows]) for j in range(ref_step.size)]
    Fs = np.concatenate([Phi, np.eye(n)[None]])       # Fs[k] propagates k -> k+1
    Qs = np.concatenate([Q, np.zeros((1, n, n))])
    t0, c0 = time.perf_counter(), time.process_time()
    kf = KalmanFilter(dim_x=n, dim_z=rows)
    kf.x = np.zeros(n)
    kf.P = P0.copy()
    Xs = np.empty((k_max + 1, n))
    Ps = np.empty((k_max + 1, n, n))
    nu = np.empty((ref_step.size, rows))
    j = 0
    for k in range(k_max + 1):
        if k > 0:
            kf.predict(F=Phi[k - 1], Q=Q[k - 1])
        while j < ref_step.size and ref_step[j] == k:
            kf.update(z[j, :rows], R=R[j], H=H[j])
            nu[j] = kf.y
            j += 1
        Xs[k] = kf.x
        Ps[k] = kf.P
    xs, Pss, _, _ = kf.rts_smoother(Xs, Ps, Fs=Fs, Qs=Qs)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return wall, cpu, t_phi, nu, xs, np.sqrt(np.diagonal(Pss, axis1=1, axis2=2))


def sorted_refs(refs):
    order = np.argsort(refs.step, kind="stable")
    return RefRows(refs.t[order], refs.z[order], refs.r[order], refs.step[order], refs.a[order])


def compare(label: str, span_s: float, jitter_ms: float, grade: str, repeat: int,
            model: str = "15") -> dict:
    inp = flight_input(span_s, jitter_ms)
    fine_refs = sorted_refs(inp.refs)
    ours, one, fine, merged = [], [], [], []
    for _ in range(repeat):                           # interleaved: the same load for all
        ours += [project(inp, grade, model) for _ in range(3)]   # (short runs: more of them)
        one += [project(inp, grade, model, threads=1) for _ in range(3)]
        an = ours[-1][2]
        P0 = an.model.p0_aligned(an.steps.C[0], an.steps.f_n[0], float(an.steps.lat[0]))
        fine.append(filterpy_run(an.model, inp.steps, fine_refs, P0))
        merged.append(filterpy_run(an.model, an.steps, an.refs, P0))
    wall_ours, cpu_ours = min(r[0] for r in ours), min(r[1] for r in ours)
    wall_one, cpu_one = min(r[0] for r in one), min(r[1] for r in one)
    wall_fine, wall_merged = min(r[0] for r in fine), min(r[0] for r in merged)
    cpu_fine, cpu_merged = min(r[1] for r in fine), min(r[1] for r in merged)
    model_, steps, refs = an.model, an.steps, an.refs
    sd_nu = np.sqrt(np.diagonal(an.forward.S, axis1=1, axis2=2))
    _, _, phi_fine, nu_f, xs_f, sd_f = fine[0]
    _, _, phi_merged, nu_m, _, _ = merged[0]
    d_nu_fine = float(np.max(np.abs(nu_f - an.forward.nu) / sd_nu))
    d_xs_fine = float(np.max(np.abs(xs_f[fine_refs.step] - an.backward.x_s)
                             / sd_f[fine_refs.step]))
    d_nu_merged = float(np.max(np.abs(nu_m - an.forward.nu)) / np.max(np.abs(an.forward.nu)))
    print(f"{label}: {span_s:.0f} s, {len(inp.steps)} INS steps at 100 Hz, {refs.t.size} GNSS "
          f"updates, {model_.n} states; best of {repeat} (project: of {3 * repeat}), "
          f"interleaved; load average {os.getloadavg()[0]:.1f}")
    print(f"  project analyze_ins3d (merges onto {len(steps)} steps): {wall_ours:.3f} s wall, "
          f"{cpu_ours:.3f} s CPU ({1e6 * wall_ours / len(inp.steps):.2f} us per INS step); "
          f"on one thread: {wall_one:.3f} s wall, {cpu_one:.3f} s CPU")
    print(f"  FilterPy filter + RTS on the {len(inp.steps)} INS steps: {wall_fine:.3f} s wall, "
          f"{cpu_fine:.3f} s CPU ({1e6 * wall_fine / len(inp.steps):.1f} us/step; Phi_k, Q_k "
          f"built beforehand in {phi_fine:.2f} s); project vs it: innovations within "
          f"{d_nu_fine:.1e} sd, smoothed states within {d_xs_fine:.1e} sd")
    print(f"  FilterPy filter + RTS on the {len(steps)} merged steps: {wall_merged:.3f} s wall, "
          f"{cpu_merged:.3f} s CPU; innovations vs the project's forward filter: max rel. "
          f"difference {d_nu_merged:.1e}")
    ratio, ratio_m = wall_fine / wall_ours, wall_merged / wall_ours
    verdict = ("PASS" if ratio >= TARGET_RATIO else "FAIL") if model == "15" else \
        "information: the issue's target is for the 15-state model"
    print(f"  ratio FilterPy / project, wall: {ratio:.1f}x on the INS steps (target >= "
          f"{TARGET_RATIO:g}x -> {verdict}), {ratio_m:.1f}x on the merged steps (like for "
          f"like); CPU: {cpu_fine / cpu_ours:.1f}x, {cpu_merged / cpu_ours:.1f}x; project on "
          f"one thread: wall {wall_fine / wall_one:.1f}x, CPU {cpu_fine / cpu_one:.1f}x")
    return {"ratio": ratio, "ratio_merged": ratio_m, "same_filter": d_nu_merged < 1e-6,
            "ratio_cpu": cpu_fine / cpu_ours, "ratio_one_thread": wall_fine / wall_one}


def two_hours(grade: str) -> None:
    """The project's analysis of the whole 2-hour flight (720 000 INS steps), once."""
    inp = flight_input(7200.0, 0.0)
    wall, _, _ = project(inp, grade)
    print(f"2-hour flight (720 000 INS steps at 100 Hz, 72 000 GNSS updates): {wall:.2f} s "
          f"-> {'PASS' if wall <= TARGET_2H_S else 'FAIL'} (target <= {TARGET_2H_S:g} s; "
          f"bench/bench_ins3d.py has the stages)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--span", type=float, default=300.0, metavar="S",
                    help="flight seconds both run on for the ratio (default 300)")
    ap.add_argument("--jitter-ms", type=float, default=1.0)
    ap.add_argument("--two-hours", action="store_true",
                    help="also analyse the whole 2-hour flight once")
    ap.add_argument("--grade", default="navigation")
    ap.add_argument("--repeat", type=int, default=3, help="best of N runs (default 3)")
    ap.add_argument("--no-19", dest="model19", action="store_false",
                    help="skip the information run on the default 19-state model")
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"load average at the start {os.getloadavg()[0]:.1f} (2 cores)")
    warm = flight_input(60.0, 0.0)
    for model in MODELS:
        an = project(warm, args.grade, model)[2]
        project(warm, args.grade, model, threads=1)
        filterpy_run(an.model, an.steps, an.refs, np.diag(an.model.p0()))
    print(f"numba kernels ready in {time.perf_counter() - t0:.1f} s (cache load or compile)")
    compare("regular stamps", args.span, 0.0, args.grade, args.repeat)
    compare(f"stamps jittered by +-{args.jitter_ms:g} ms", args.span, args.jitter_ms, args.grade,
            args.repeat)
    if args.model19:
        compare("the default 19-state model (vertical loop, 3 rows), regular stamps",
                args.span, 0.0, args.grade, args.repeat, model="19")
    if args.two_hours:
        two_hours(args.grade)
    print(f"load average {os.getloadavg()[0]:.1f} (2 cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
