"""Compile every estimation kernel once, into numba's on-disk cache (``make setup`` runs
``python -m flight_fdi.core.warmup``), so that a user's first ``flight-fdi analyze`` or node
start only loads compiled code. Runs each public entry point on a short record of each built-in
model, which compiles the same type signatures the real calls use."""
from __future__ import annotations

import sys
import time

import numpy as np


def warm() -> None:
    from .analysis import AnalysisConfig, run_analysis
    from .diagnosis import diagnose
    from .kalman import ForwardResult, GateConfig, KalmanFilter, run_forward
    from .ldl import ldl, localize, udu
    from .models import attitude_axis, ins_channel
    from .smoother import run_backward

    rng = np.random.default_rng(0)
    N = 300
    t = np.cumsum(0.1 + rng.normal(0, 1e-3, N))
    ins = ins_channel()
    for gate in (GateConfig(), GateConfig(action="reject")):
        fwd = run_forward(ins, t, rng.normal(0, 0.1, N), gate=gate)
        bwd = run_backward(ins, fwd)
        diagnose(ins, fwd, bwd)
    # the smoother node's path: the forward pass rebuilt from a recording (its discretisation
    # of every recorded dt, ``discretize._discretize_all``, runs nowhere else)
    ForwardResult.from_record(ins, fwd.t, fwd.dt, fwd.z, fwd.R, fwd.H, fwd.fused, fwd.u,
                              fwd.x, fwd.P)
    two = _two_states()
    fwd = run_forward(two, t, rng.normal(0, 0.1, N))
    run_backward(two, fwd)
    warm_glr(two, fwd, hypotheses=("step:v", "ramp:v", "reference_jump", "reference_outlier"))
    ti = np.arange(5 * N) * 0.02
    run_analysis(ins, ti, rng.normal(0, 0.1, ti.size), t[t < ti[-1]],
                 np.zeros((t < ti[-1]).sum()), config=AnalysisConfig())
    att = attitude_axis()
    att2 = attitude_axis(sigma_rate=1e-3)
    u = rng.normal(0, 1, (N, 1))
    for model in (att, att2):
        fwd = run_forward(model, t, rng.normal(0, 1e-4, (N, model.m)), u=u)
        run_backward(model, fwd)
    for model in (ins, att, att2):
        kf = KalmanFilter(model)
        kf.update(np.zeros(model.m))
        kf.step(0.1, np.zeros(model.m), u=None if model.B is None else [0.0])
        kf.predict(0.1, None if model.B is None else [0.0])
        kf.update(np.zeros(1), np.eye(1), model.H[:1])
        model.discretize(0.1)
    KalmanFilter(ins).step1(0.1, 0.0, 0.01)
    warm_glr(ins, run_forward(ins, t, rng.normal(0, 0.1, N)))
    P = np.eye(4) + 0.1
    udu(P)
    ldl(P)
    localize(np.ones(4), dP=P)
    localize(np.ones(4), W=P)


def _two_states():
    """A 2-state model: its size is not specialised, so it compiles the generic backward sweep
    (``information.smooth_pass``, any n) and GLR kernels (``glr_kernel.kernel_for``) that a
    model file of another size runs."""
    from .models import LinearModel

    return LinearModel(name="warm_cv", state_names=("p", "v"), state_units=("m", "m/s"),
                       A=[[0.0, 1.0], [0.0, 0.0]], Qc=np.diag([0.0, 0.05]), H=[[1.0, 0.0]],
                       R=[[0.04]], P0=np.eye(2))


def preload(model, config=None) -> None:
    """Load the compiled kernels a flight analysis of ``model`` uses (numba's start-up and the
    cached machine code, ~0.4 s of a fresh process), by analysing a short synthetic record:
    what ``flight-fdi analyze --jobs 2`` does while its forked child reads the bag."""
    from .analysis import AnalysisConfig, run_analysis

    if model.m != 1:
        return
    t = np.arange(300) * 0.1
    res = run_analysis(model, t, np.zeros(t.size), t, np.zeros(t.size),
                       config=AnalysisConfig() if config is None else config)
    warm_glr(model, res.fwd)  # (GLR's second pass, which only a fault flight runs)


def warm_glr(model, fwd, hypotheses=None) -> None:
    """Every GLR kernel, the second pass's included (``isolate`` runs it only when one
    hypothesis explains a fault); ``hypotheses``: the default set unless given."""
    from .glr import GlrConfig, isolate
    from .glr_system import prepare, resolve, systems

    config = GlrConfig() if hypotheses is None else GlrConfig(hypotheses=hypotheses)
    isolate(model, fwd, config)
    flt = prepare(model, fwd)
    hyps = [resolve(model, h) for h in config.hypotheses]
    for system in {id(s): s for s in systems(model, hyps).values()}.values():
        system.num(flt.with_innovations(flt.w))
        system.signature(flt, 5, system.hyps[0].name)


def main() -> int:
    t0 = time.perf_counter()
    warm()
    print(f"[setup] estimation kernels compiled and cached ({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
