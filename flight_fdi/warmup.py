"""Compile every numba kernel of the product once, into numba's on-disk cache (``make setup`` runs
``python -m flight_fdi.warmup``), so that a user's first ``flight-fdi analyze`` (either model),
``simulate`` or node start only loads compiled code.

``core.warmup`` covers the single-axis estimation kernels; this module adds what needs more than the
core to exercise: the 3-D simulator (a short flight with turns) and the 3-D model's batch analysis
(forward filter, backward sweep, GLR, both row counts, the nonlinear check's exact removal, the
relinearisation about a large attitude error) and
its per-message streaming step, on that
flight. The kernels compile for argument types, not values, so a short flight compiles the same
signatures a 3-hour one uses. Last, the triple-IMU voter's kernels (``flight-fdi vote``, the
voter node) and every strapdown scheme of the simulator (``sim.strapdown.warm_up``)."""
from __future__ import annotations

import sys
import time

import numpy as np


def warm_ins3d() -> None:
    from .bagio.ins3d_input import from_flight
    from .core.ins3d.analysis import analyze_ins3d
    from .core.ins3d.filter import run_forward
    from .core.ins3d.model import Ins3dModel
    from .core.ins3d.nonlinear import corrected
    from .core.ins3d.relinearize import relinearized
    from .core.ins3d.stream import Ins3dStream
    from .sim.faults import FaultSpec3D, parse_fault
    from .sim.ins3d import Sim3DConfig, simulate3d
    from .sim.trajectory import TrajectoryConfig

    # a gyro step before the first turn: isolation, its rival's signature and the ambiguity's end
    fault = parse_fault("gyro:step:t=200,mag=3deg/h,axis=x", FaultSpec3D)
    flight = simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(duration_s=420.0), seed=1,
                                    faults=(fault,)))
    inp = from_flight(flight)
    for rows in (2, 3):
        analyze_ins3d(inp.steps, inp.refs, rows=rows).post_flight_dict()
        # the forward filter with its discretisation running ahead on a second thread (what
        # analyze_ins3d does without the observability Gramian: the Monte Carlo engine)
        run_forward(Ins3dModel.from_grade("navigation", rows=rows), inp.steps, inp.refs,
                    threads=2)
        stream = Ins3dStream(Ins3dModel.from_grade("navigation", rows=rows, latency=True,
                                                   ref_markov=(0.02, 0.03, 30.0)))
        stream.predict(inp.steps, 0)
        stream.update(inp.refs.z[0], inp.refs.r[0], inp.refs.a[0])
    # the nonlinear check's exact removal (a large gyro fault, core/ins3d/nonlinear.py)
    corrected(Ins3dModel.from_grade("navigation"), inp.steps, inp.refs, "gyro", "x", "step", 10,
              1e-3)
    # the relinearisation about a large attitude error (core/ins3d/relinearize.py)
    relinearized(Ins3dModel.from_grade("mems"), inp.steps, inp.refs,
                 np.full((inp.refs.t.size, 6), 0.1))


def warm_voter() -> None:
    """The voter's kernels (core/voter_kernel.py) on 40 s of three identical noisy IMUs: the
    bundled threshold table's model (the prefilter's moving means, the sequential detector) and
    the step detector of a "grow" baseline, as ``flight-fdi vote`` and voter_node run them."""
    from .cli.vote import DEFAULT_TABLE
    from .core.voter_core import VoterCore, VoterModel
    from .core.voting import load_table

    table = load_table(DEFAULT_TABLE)
    n = int(40 * table.rate_hz)
    stamps = (np.arange(n) * (1e9 / table.rate_hz)).astype(np.int64)
    P = np.repeat(np.random.default_rng(0).normal(0.0, 1e-4, (n, 6, 1)), 3, axis=2)
    grow = VoterModel.from_dict({"learn_s": 5.0, "baseline": "grow"})
    for model in (None, grow):
        core = VoterCore(table, model=model)
        core.push(stamps[: n // 2], P[: n // 2])
        core.push(stamps[n // 2:], P[n // 2:])
        core.finish()


def warm_direct() -> None:
    """Signatures only a direct call from Python compiles (the kernels are otherwise inlined into
    their callers): the test suite's checks of the compiled Van Loan discretisation against scipy
    (test/core/test_discretize.py), of the 3-D model's noise-free propagation and of the
    information filter's combination step, Earth's radii and gravity on arrays, and the
    information sweep's terms with a read-only reference -- so that ``make test`` after ``make
    setup`` compiles nothing either (test_discretize.py alone compiled for ~7 s)."""
    from numba import types as nt

    from .core import discretize, earth, information, ldl
    from .core.ins3d import dynamics

    f8, b1, i8 = nt.float64, nt.boolean, nt.int64

    def a(nd: int, dtype=f8, readonly: bool = False):
        return nt.Array(dtype, nd, "C", readonly=readonly)

    discretize.van_loan.compile((a(3), a(3), a(3), f8, f8, a(2), a(2), a(2), a(3)))
    discretize.expm_series.compile((a(3), f8, f8, a(2), a(2)))
    discretize._scaling.compile((f8, f8))
    discretize._terms.compile((f8,))
    earth.gravity.compile((a(1), a(1)))
    earth.radii.compile((a(1),))
    dynamics._propagate.compile((a(1), a(3), a(2), a(2), a(1), a(1), a(1), a(1), a(2), a(2), b1,
                                 a(2)))
    information.combine_step.compile((a(2), a(1), a(1), a(2), f8, a(2), a(1), a(1), a(2), a(1),
                                      a(1), a(1, nt.boolean), a(1), a(1), a(1), a(1, i8), a(1),
                                      a(2), a(3)))
    ldl._terms_stack.compile((a(3), a(2), a(2, readonly=True), f8, a(3), a(2), a(2, b1), a(2),
                              a(2), a(2), a(2, i8), a(2)))


def main() -> int:
    from .core.warmup import warm
    from .sim.strapdown import warm_up

    t0 = time.perf_counter()
    warm()
    t1 = time.perf_counter()
    warm_ins3d()
    t2 = time.perf_counter()
    warm_voter()
    warm_up()
    warm_direct()
    print(f"[setup] kernels compiled and cached: single-axis {t1 - t0:.1f} s, "
          f"3-D model and simulator {t2 - t1:.1f} s, "
          f"voter, strapdown schemes and direct calls {time.perf_counter() - t2:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
