#!/usr/bin/env python3
"""Benchmark of the estimation core against FilterPy and pykalman (a script, not a test).

Measured in one run on the same data (the INS channel, 10 Hz, seeded nominal flight):

* forward filter per step: ``run_forward`` (and the streaming ``KalmanFilter.step``) vs FilterPy
  ``KalmanFilter.predict() + update()`` -- target >= 3x;
* post-flight: ``run_backward`` + ``diagnose`` (backward information filter, two-filter smoother,
  J, UDU^T terms, Fisher) vs FilterPy ``batch_filter`` + ``rts_smoother`` -- target >= 5x -- and vs
  pykalman ``KalmanFilter.smooth``.

Each timing is the best of ``--repeat`` interleaved runs.
Usage: ``python bench/bench_core.py [--steps N] [--repeat R]``.
"""
from __future__ import annotations

import argparse
import gc
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.core.diagnosis import diagnose  # noqa: E402
from flight_fdi.core.kalman import KalmanFilter, run_forward  # noqa: E402
from flight_fdi.core.models import ins_channel  # noqa: E402
from flight_fdi.core.smoother import run_backward  # noqa: E402


def best(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def simulate(model, t, rng):
    n = model.n
    Phi, Qd, _ = model.discretize(t[1] - t[0])
    lam, V = np.linalg.eigh(Qd / np.outer(model.scale, model.scale))
    G = model.scale[:, None] * (V * np.sqrt(np.clip(lam, 0, None)))
    x = rng.multivariate_normal(np.zeros(n), model.P0)
    X = np.empty((t.size, n))
    for k in range(t.size):
        if k:
            x = Phi @ x + G @ rng.standard_normal(n)
        X[k] = x
    return X


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    N, rep = args.steps, args.repeat

    from filterpy.kalman import KalmanFilter as FilterPyKF
    from pykalman import KalmanFilter as PyKalmanKF

    model = ins_channel()
    dt = 0.1
    t = np.arange(N) * dt
    rng = np.random.default_rng(0)
    z = simulate(model, t, rng)[:, 0] + rng.normal(0, 0.1, N)
    Phi, Qd, _ = model.discretize(dt)
    H, R, P0 = np.array(model.H), np.array(model.R), np.array(model.P0)
    run_forward(model, t[:10], z[:10])  # warm the caches (discretization, generated code)

    def filterpy_new():
        kf = FilterPyKF(4, 1)
        kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = np.zeros((4, 1)), P0.copy(), Phi, Qd, H, R
        return kf

    def filterpy_loop():
        kf = filterpy_new()
        kf.update(z[0])
        for zk in z[1:]:
            kf.predict()
            kf.update(zk)
        return kf

    def mine_streaming():
        kf = KalmanFilter(model)
        kf.update(z[0])
        for zk in z[1:]:
            kf.step(dt, zk)
        return kf

    def filterpy_smoother():
        kf = filterpy_new()
        Fs = [np.eye(4)] + [Phi] * (N - 1)
        Qs = [np.zeros((4, 4))] + [Qd] * (N - 1)
        mu, cov, _, _ = kf.batch_filter(z, Fs=Fs, Qs=Qs)
        return kf.rts_smoother(mu, cov, Fs=Fs, Qs=Qs)

    def pykalman_smoother():
        pk = PyKalmanKF(transition_matrices=Phi, observation_matrices=H,
                        transition_covariance=Qd, observation_covariance=R,
                        initial_state_mean=np.zeros(4), initial_state_covariance=P0)
        return pk.smooth(z.reshape(-1, 1))

    # interleaved repetitions, best of each: the machine's load changes between runs
    timings: dict[str, float] = {}
    results: dict[str, object] = {}
    jobs = {
        "fp": filterpy_loop, "fwd": lambda: run_forward(model, t, z), "stream": mine_streaming,
    }
    for _ in range(rep):
        for name, fn in jobs.items():
            dt_, results[name] = best(fn, 1)
            timings[name] = min(timings.get(name, np.inf), dt_)
        gc.disable()
        dt_, _ = best(filterpy_loop, 1)
        gc.enable()
        timings["fp_nogc"] = min(timings.get("fp_nogc", np.inf), dt_)
    fwd = results["fwd"]
    jobs = {
        "bwd": lambda: run_backward(model, fwd), "fps": filterpy_smoother,
    }
    for _ in range(rep):
        for name, fn in jobs.items():
            dt_, results[name] = best(fn, 1)
            timings[name] = min(timings.get(name, np.inf), dt_)
        bwd = results["bwd"]
        dt_, _ = best(lambda: diagnose(model, fwd, bwd), 1)
        timings["seed"] = min(timings.get("seed", np.inf), dt_)
    t_pk, (xs_pk, _) = best(pykalman_smoother, max(1, rep - 1))
    t_fp, t_fwd, t_stream, t_fp_nogc = (timings[k] for k in ("fp", "fwd", "stream", "fp_nogc"))
    t_bwd, t_seed, t_fps = (timings[k] for k in ("bwd", "seed", "fps"))
    xs_fp = results["fps"][0]
    xs_fp = np.asarray(xs_fp).reshape(N, 4)
    t_pk, (xs_pk, _) = best(pykalman_smoother, max(1, rep - 1))

    s = model.scale
    us = 1e6 / N
    print(f"INS channel, {N} steps at {1 / dt:g} Hz, best of {rep}")
    print(f"  agreement: smoothed x vs FilterPy RTS max |diff|/scale "
          f"{np.max(np.abs(bwd.x_s - xs_fp) / s):.2e}, vs pykalman "
          f"{np.max(np.abs(bwd.x_s - xs_pk) / s):.2e}")
    print("forward filter, per step:")
    print(f"  flight_fdi run_forward            {t_fwd * us:7.2f} us")
    print(f"  flight_fdi KalmanFilter.step      {t_stream * us:7.2f} us")
    print(f"  FilterPy predict()+update()       {t_fp * us:7.2f} us   "
          f"(with the garbage collector paused: {t_fp_nogc * us:.2f} us)")
    print(f"  ratio FilterPy / run_forward      {t_fp / t_fwd:7.2f} x   (target >= 3; "
          f"{t_fp_nogc / t_fwd:.2f} x against FilterPy without GC)")
    print(f"  ratio FilterPy / streaming        {t_fp / t_stream:7.2f} x")
    print("post-flight, per step:")
    print(f"  run_backward (info filter + two-filter combination + J)  {t_bwd * us:7.2f} us")
    print(f"  diagnose (UDU^T terms, Fisher, verdict)                  {t_seed * us:7.2f} us")
    print(f"  FilterPy batch_filter + rts_smoother                     {t_fps * us:7.2f} us")
    print(f"  pykalman KalmanFilter.smooth                             {t_pk * us:7.2f} us")
    mine = t_bwd + t_seed
    print(f"  ratio FilterPy filter+RTS / (backward + seed statistics)   {t_fps / mine:7.2f} x "
          f"(target >= 5)")
    print(f"  ratio pykalman smooth / (backward + seed statistics)       {t_pk / mine:7.2f} x")
    print(f"  ratio FilterPy filter+RTS / (forward + backward + seed)    "
          f"{t_fps / (t_fwd + mine):7.2f} x")
    print(f"  ratio pykalman smooth / (forward + backward + seed)        "
          f"{t_pk / (t_fwd + mine):7.2f} x")


if __name__ == "__main__":
    main()
