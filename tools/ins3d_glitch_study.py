#!/usr/bin/env python3
"""A reference glitch and an IMU fault in the same flight, on the strapdown simulator: how often
both are reported, and what the glitch costs the fault (docs/ins3d.md, "A glitch and a fault in
the same flight").

    .venv/bin/python tools/ins3d_glitch_study.py [--flights 20] [--duration 900]
                                                 [--profile random] [--seed 0] [--out F]

The flights are the 3-D Monte Carlo's (``montecarlo3d.plan_study``: nominal flights and
accelerometer / gyro steps, seeded, random axis, sign and onset in 10-80 % of the flight). Each
flight is simulated twice with the same seeds: as planned, and with a GNSS velocity glitch
added -- a burst of spikes (the simulator's ``ref:outliers``: +-m on random messages, 0.1 per
second on average over 30 s, ~3 spikes) of 0.5, 1 or 2 m/s on the east, north or up velocity,
starting anywhere in 10-85 % of the flight (a stream of its own, from the flight's seed). The
model (``ins3d``, navigation grade, 3 rows) knows nothing of the simulator's glitch.

Counted per flight: the IMU fault named (``failure``, ``single``, the true sensor and axis),
the glitch reported (``post_flight.glitches`` or a ``glitch`` verdict on the glitch's row,
within 2 s of a spike), the spikes whose update was removed (within 0.15 s), a confident wrong
answer (``single`` naming another IMU sensor or axis, a reference jump, or reference outliers
on another row or away from the spikes) and ``ambiguous``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flight_fdi.core.errors import CoreError  # noqa: E402
from flight_fdi.eval import montecarlo3d as M  # noqa: E402

#: the glitch drawn per flight: spikes per second over the window, the window, sizes (m/s)
SPIKE_RATE, WINDOW_S, SIZES, START = 0.1, 30.0, (0.5, 1.0, 2.0), (0.1, 0.85)
#: a removed update within this of a spike is the spike (s); a reported glitch (its row the
#: glitch's) within NEAR_S of a spike is the glitch (a glitch verdict's first outlier can be a
#: neighbour of the first spike, pulled above the threshold by it)
MATCH_S, NEAR_S = 0.15, 2.0
ROW = {"x": "east", "y": "north", "z": "up"}


def glitch_spec(case: M.Case3D, duration: float) -> tuple[str, str, str]:
    """(the simulator's fault spec, a label, the reference row) of the case's glitch, from its
    own seed."""
    rng = np.random.default_rng([case.sim_seed, 7])
    t0 = round(float(rng.uniform(*START)) * duration, 1)
    mag, axis = float(rng.choice(SIZES)), str(rng.choice(["x", "y", "z"]))
    spec = (f"ref:outliers:t={t0:g},end={t0 + WINDOW_S:g},mag={mag:g},"
            f"freq={SPIKE_RATE:g},axis={axis}")
    return spec, f"{mag:g} m/s {ROW[axis]} from {t0:g} s", ROW[axis]


def simulate(case: M.Case3D, config: M.Study3DConfig, glitch: str | None):
    from flight_fdi.sim.faults import FaultSpec3D, parse_fault
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.gnss import GnssConfig
    from flight_fdi.sim.trajectory import TrajectoryConfig

    faults = tuple(f for f in (case.fault(),) if f is not None)
    if glitch:
        faults += (parse_fault(glitch, FaultSpec3D),)
    cfg = Sim3DConfig(trajectory=TrajectoryConfig(profile=config.profile,
                                                  duration_s=float(config.duration_s),
                                                  seed=case.traj_seed),
                      grade=config.grade, gnss=GnssConfig(latency_s=config.gnss_latency_s),
                      faults=faults, seed=case.sim_seed)
    return simulate3d(cfg)


def judge(post: dict, case: M.Case3D, spikes: np.ndarray, row: str | None = None) -> dict:
    """The flight's counts (module docstring); ``row``: the glitch's reference row."""
    truth = None if case.scenario == "nominal" else (M.SCENARIOS[case.scenario][2], case.axis)
    f, single = post.get("fault") or {}, post.get("isolation") == "single"
    found = [(g["axis"], t) for g in post.get("glitches") or [] for t in g["times_s"]]
    if f.get("kind") == "outliers":
        found += [(f["axis"], f["onset_s"])]
    times = [t for _, t in found]
    removed = np.array([t for g in post.get("glitches") or [] for t in g["times_s"]])
    at_spike = [a == row and bool(spikes.size) and float(np.min(np.abs(spikes - t))) <= NEAR_S
                for a, t in found]
    named = (f.get("sensor"), f.get("axis"))
    right = bool(truth) and post["verdict"] == "failure" and single and named == truth
    wrong = single and not right and (
        (f.get("sensor") in ("accelerometer", "gyro"))
        or (f.get("kind") == "jump") or (f.get("kind") == "outliers" and not all(at_spike)))
    return {"right": right, "wrong": bool(wrong), "ambiguous": post.get("isolation") ==
            "ambiguous", "glitch": bool(times) and all(at_spike), "spikes": int(spikes.size),
            "spikes_found": int(sum(removed.size > 0 and float(np.min(np.abs(removed - s)))
                                    <= MATCH_S for s in spikes)),
            "answer": f"{post['verdict']} {post.get('isolation')} {named[0]} {named[1]} "
                      f"{f.get('kind')}"}


def run(config: M.Study3DConfig) -> list[dict]:
    grade = config.grade
    rows = []
    for case in M.plan_study(config):
        spec, label, glitch_row = glitch_spec(case, config.duration_s)
        row = {"case": case.index, "scenario": case.scenario, "axis": case.axis,
               "level": case.level, "onset_s": case.onset_s, "glitch": label}
        for key, g in (("alone", None), ("with", spec)):
            fl = simulate(case, config, g)
            spikes = fl.gnss.t[fl.gnss.outlier.any(axis=1)]
            post, _ = M.ins3d_post_flight(fl, config, grade)
            row[key] = judge(post, case, spikes, glitch_row if g else None)
        rows.append(row)
        print(f"{case.index:3d} {case.scenario:10s} {case.axis} | alone: "
              f"{row['alone']['answer']} | with {label} ({row['with']['spikes']} spikes): "
              f"{row['with']['answer']} glitch={row['with']['glitch']}", file=sys.stderr)
    return rows


def table(rows: list[dict]) -> list[str]:
    out = ["| flights | n | IMU fault right: alone → with the glitch | confident wrong: "
           "alone → with | ambiguous: alone → with | glitch reported (flights with ≥ 1 spike) "
           "| spikes found of drawn |",
           "|---|---|---|---|---|---|---|"]
    for name in ("nominal", "accel_step", "gyro_step"):
        rs = [r for r in rows if r["scenario"] == name]
        if not rs:
            continue
        c = {k: [sum(r[w][k] for r in rs) for w in ("alone", "with")]
             for k in ("right", "wrong", "ambiguous")}
        hit = [r for r in rs if r["with"]["spikes"]]
        right = "-" if name == "nominal" else f"{c['right'][0]} → {c['right'][1]}"
        out.append(f"| {name} | {len(rs)} | {right} | {c['wrong'][0]} → {c['wrong'][1]} | "
                   f"{c['ambiguous'][0]} → {c['ambiguous'][1]} | "
                   f"{sum(r['with']['glitch'] for r in hit)} of {len(hit)} | "
                   f"{sum(r['with']['spikes_found'] for r in rs)} of "
                   f"{sum(r['with']['spikes'] for r in rs)} |")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--flights", type=int, default=20, help="per group (nominal, accel, gyro)")
    p.add_argument("--duration", type=float, default=900.0)
    p.add_argument("--profile", default="random")
    p.add_argument("--accel-mg", type=float, default=1.0)
    p.add_argument("--gyro-deg-h", type=float, default=0.2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path)
    a = p.parse_args(argv)
    try:
        config = M.Study3DConfig(nominal=a.flights, per_scenario=a.flights,
                                 scenarios=("accel_step", "gyro_step"),
                                 levels={"accel_step": (a.accel_mg,),
                                         "gyro_step": (a.gyro_deg_h,)},
                                 duration_s=a.duration, profile=a.profile, seed=a.seed,
                                 single_axis=False)
    except CoreError as exc:
        print(f"ins3d_glitch_study: {exc}", file=sys.stderr)
        return 2
    t0 = time.time()
    rows = run(config)
    lines = [f"Seed {a.seed}, {a.profile} {a.duration:g}-s flights, navigation grade, "
             f"accelerometer steps {a.accel_mg:g} mg, gyro steps {a.gyro_deg_h:g} deg/h; "
             f"{time.time() - t0:.0f} s.", ""] + table(rows)
    text = "\n".join(lines) + "\n"
    if a.out:
        a.out.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
