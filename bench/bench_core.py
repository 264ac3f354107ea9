#!/usr/bin/env python3
"""Benchmark of the estimation kernels against FilterPy and pykalman (a script, not a test).

Measured in one run on the same data (the INS channel at 10 Hz, a seeded nominal flight), on
regular stamps and on stamps with 1 ms Gaussian jitter (every dt distinct):

* forward filter per step: ``run_forward`` (and the streaming ``KalmanFilter.step1`` a node
  calls) vs FilterPy ``KalmanFilter.predict() + update()`` -- target >= 30x;
* post-flight: ``run_backward`` + ``diagnose`` (backward information filter, two-filter
  combination, J, UDU^T terms, Fisher) vs FilterPy ``batch_filter`` + ``rts_smoother`` -- target
  >= 30x -- and vs pykalman ``KalmanFilter.smooth``.

The baselines get their Phi and Qd per step precomputed (outside their timing); the kernels
discretize inside theirs. Each timing is the best CPU time of ``--repeat`` interleaved runs.
Usage: ``python bench/bench_core.py [--steps N] [--repeat R]``.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.core.diagnosis import diagnose  # noqa: E402
from flight_fdi.core.kalman import KalmanFilter, run_forward  # noqa: E402
from flight_fdi.core.models import ins_channel  # noqa: E402
from flight_fdi.core.smoother import run_backward  # noqa: E402

TARGET = 30.0


def seconds(fn):
    """CPU time of fn() (process time: on the shared machine, less sensitive than wall time to
    the other processes; one thread throughout, so the two agree on a quiet machine)."""
    t0 = time.process_time()
    out = fn()
    return time.process_time() - t0, out


def simulate(model, t, rng):
    """States of the model itself at the stamps t (exact discretization per dt)."""
    n = model.n
    x = rng.multivariate_normal(np.zeros(n), model.P0)
    X = np.empty((t.size, n))
    for k in range(t.size):
        if k:
            Phi, Qd, _ = model.discretize(t[k] - t[k - 1])
            lam, V = np.linalg.eigh(Qd / np.outer(model.scale, model.scale))
            G = model.scale[:, None] * (V * np.sqrt(np.clip(lam, 0, None)))
            x = Phi @ x + G @ rng.standard_normal(n)
        X[k] = x
    return X


def jobs_for(model, t, z):
    """The timed functions of one kind of stamps, and what the baselines need precomputed."""
    from filterpy.kalman import KalmanFilter as FilterPyKF
    from pykalman import KalmanFilter as PyKalmanKF

    N = t.size
    dt = np.diff(t, prepend=t[0])
    disc = [model.discretize(d) for d in dt]
    Fs = [np.eye(4)] + [d[0] for d in disc[1:]]
    Qs = [np.zeros((4, 4))] + [d[1] for d in disc[1:]]
    H, R, P0 = np.array(model.H), np.array(model.R), np.array(model.P0)

    def filterpy_new():
        kf = FilterPyKF(4, 1)
        kf.x, kf.P, kf.H, kf.R = np.zeros((4, 1)), P0.copy(), H, R
        return kf

    def filterpy_loop():
        kf = filterpy_new()
        kf.update(z[0])
        for k in range(1, N):
            kf.F, kf.Q = Fs[k], Qs[k]
            kf.predict()
            kf.update(z[k])
        return kf

    def streaming():
        kf = KalmanFilter(model)
        for k in range(N):
            kf.step1(dt[k], z[k], 0.01)
        return kf

    def filterpy_smoother():
        kf = filterpy_new()
        mu, cov, _, _ = kf.batch_filter(z, Fs=Fs, Qs=Qs)
        return kf.rts_smoother(mu, cov, Fs=Fs, Qs=Qs)

    def pykalman_smoother():
        pk = PyKalmanKF(transition_matrices=np.array(Fs[1:]), observation_matrices=H,
                        transition_covariance=np.array(Qs[1:]), observation_covariance=R,
                        initial_state_mean=np.zeros(4), initial_state_covariance=P0)
        return pk.smooth(z.reshape(-1, 1))

    return {"fp": filterpy_loop, "fwd": lambda: run_forward(model, t, z), "stream": streaming,
            "fps": filterpy_smoother, "pk": pykalman_smoother}


def measure(model, t, z, rep):
    jobs = jobs_for(model, t, z)
    timings: dict[str, float] = {}
    results: dict[str, object] = {}
    for _ in range(rep):  # interleaved repetitions, best of each: the machine's load changes
        for name in ("fp", "fwd", "stream", "fps"):
            dt_, results[name] = seconds(jobs[name])
            timings[name] = min(timings.get(name, np.inf), dt_)
        fwd = results["fwd"]
        dt_, results["bwd"] = seconds(lambda: run_backward(model, fwd))
        timings["bwd"] = min(timings.get("bwd", np.inf), dt_)
        bwd = results["bwd"]
        dt_, _ = seconds(lambda: diagnose(model, fwd, bwd))
        timings["seed"] = min(timings.get("seed", np.inf), dt_)
    timings["pk"], results["pk"] = min(seconds(jobs["pk"]) for _ in range(max(1, rep // 2)))
    return timings, results


def report(label, model, N, timings, results):
    s = model.scale
    bwd = results["bwd"]
    xs_fp = np.asarray(results["fps"][0]).reshape(N, 4)
    xs_pk = results["pk"][0]
    us = 1e6 / N
    t_fp, t_fwd, t_stream = timings["fp"], timings["fwd"], timings["stream"]
    mine = timings["bwd"] + timings["seed"]
    print(f"{label}:")
    print(f"  agreement: smoothed x vs FilterPy RTS max |diff|/scale "
          f"{np.max(np.abs(bwd.x_s - xs_fp) / s):.2e}, vs pykalman "
          f"{np.max(np.abs(bwd.x_s - xs_pk) / s):.2e}")
    print(f"  forward, per step: run_forward {t_fwd * us:6.2f} us, KalmanFilter.step1 "
          f"{t_stream * us:6.2f} us, FilterPy predict()+update() {t_fp * us:6.2f} us")
    print(f"    ratio FilterPy / run_forward        {t_fp / t_fwd:7.1f} x   (target >= {TARGET:g}: "
          f"{'met' if t_fp / t_fwd >= TARGET else 'NOT met'})")
    print(f"    ratio FilterPy / KalmanFilter.step1 {t_fp / t_stream:7.1f} x")
    print(f"  post-flight, per step: run_backward {timings['bwd'] * us:6.2f} us + diagnose "
          f"{timings['seed'] * us:6.2f} us; FilterPy batch_filter+rts_smoother "
          f"{timings['fps'] * us:6.2f} us; pykalman smooth {timings['pk'] * us:6.2f} us")
    ratio = timings["fps"] / mine
    print(f"    ratio FilterPy filter+RTS / (backward + seed statistics) {ratio:7.1f} x   "
          f"(target >= {TARGET:g}: {'met' if ratio >= TARGET else 'NOT met'})")
    print(f"    ratio pykalman smooth / (backward + seed statistics)     "
          f"{timings['pk'] / mine:7.1f} x")
    return t_fwd, mine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    N, rep = args.steps, args.repeat
    model = ins_channel()
    rng = np.random.default_rng(0)
    regular = np.arange(N) * 0.1
    jittered = regular + rng.normal(0.0, 1e-3, N)
    print(f"INS channel, {N} steps at 10 Hz, best of {rep}; load average before: "
          f"{os.getloadavg()[0]:.1f}")
    run_forward(model, regular[:10], np.zeros(10))  # (compiled at set-up; loads the cache)
    out = {}
    for label, t in (("regular stamps", regular), ("1 ms Gaussian jitter", jittered)):
        z = simulate(model, t, rng)[:, 0] + rng.normal(0, 0.1, N)
        timings, results = measure(model, t, z, rep)
        out[label] = report(label, model, N, timings, results)
    (f_r, b_r), (f_j, b_j) = out.values()
    print(f"jittered / regular: forward {f_j / f_r:.2f}, backward + seed {b_j / b_r:.2f} "
          f"(load average after: {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
