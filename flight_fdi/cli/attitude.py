"""``flight-fdi attitude``: the spacecraft attitude axis of seed 003, offline.

  simulate OUT   three axes under on/off thruster control, optionally with a thruster leak,
                 written as a bag (/attitude/angle, /attitude/rate, /attitude/control,
                 /sim/truth, /sim/fault)
  analyze BAG    observability check, Kalman filter with the control input, and the actuator
                 monitor: the mean of the estimated disturbance torque over windows of zero
                 control against a threshold -> actuator fault -> switch to reserve
  study          Monte Carlo of the monitor: type I / II errors and detection delay

A configuration that is not observable (e.g. --measure rate: the angle never enters a
measurement) is refused with the rank test's message.
"""
from __future__ import annotations

import argparse
import json
import sys

from flight_fdi.cli.errors import CliError


def _monitor_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--window", type=float, default=5.0, metavar="S",
                   help="seconds of zero control per window (default 5)")
    p.add_argument("--threshold", type=float, default=1e-5, metavar="RAD_S2",
                   help="admissible |mean disturbance| per unit inertia (default 1e-5 rad/s^2)")
    p.add_argument("--zero-tol", type=float, default=0.0,
                   help="|u| at or below this counts as zero control (default 0)")
    p.add_argument("--settle", type=float, default=0.0, metavar="S",
                   help="seconds after a firing before a window may open (default 0)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("attitude", help="attitude axis (seed 003): simulate, analyse, study the "
                       "actuator fault monitor", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    s = p.add_subparsers(dest="attitude_command", metavar="ACTION")
    s.required = True

    sim = s.add_parser("simulate", help="simulate an attitude flight into a bag")
    sim.add_argument("output", help="bag directory to create")
    sim.add_argument("--duration", type=float, default=1200.0, metavar="S")
    sim.add_argument("--rate", type=float, default=10.0, metavar="HZ",
                     help="measurement and control rate (default 10)")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--measure", default="angle", choices=("angle", "angle+rate", "rate"))
    sim.add_argument("--fault", default=None, metavar="SPEC",
                     help="thruster leak, e.g. leak:t=600,mag=5e-5,axis=x (torque per unit "
                          "inertia in rad/s^2, also while commanded off)")
    sim.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    sim.add_argument("--force", action="store_true", help="overwrite an existing bag")
    sim.set_defaults(func=run_simulate)

    ana = s.add_parser("analyze", help="filter + actuator monitor on an attitude bag")
    ana.add_argument("bag")
    ana.add_argument("--axis", default="x", choices=("x", "y", "z"))
    _monitor_options(ana)
    ana.add_argument("--json", action="store_true", help="print one JSON object")
    ana.set_defaults(func=run_analyze)

    st = s.add_parser("study", help="Monte Carlo of the actuator monitor (type I / II errors)")
    st.add_argument("--nominal", type=int, default=50)
    st.add_argument("--faulty", type=int, default=50)
    st.add_argument("--duration", type=float, default=1200.0, metavar="S")
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--jobs", type=int, default=2)
    _monitor_options(st)
    st.add_argument("--json", action="store_true")
    st.add_argument("--no-progress", action="store_true")
    st.set_defaults(func=run_study)


def monitor_config(args: argparse.Namespace):
    from flight_fdi.core.actuator import ActuatorConfig

    return ActuatorConfig(window_s=args.window, threshold=args.threshold,
                          zero_tol=args.zero_tol, settle_s=args.settle)


def run_simulate(args: argparse.Namespace) -> int:
    from flight_fdi.sim.attitude import (AttitudeSimConfig, parse_actuator_fault,
                                         simulate_attitude, write_attitude_bag)

    fault = parse_actuator_fault(args.fault) if args.fault else None
    config = AttitudeSimConfig(duration_s=args.duration, rate_hz=args.rate, seed=args.seed,
                               measure=args.measure, fault=fault)
    flight = simulate_attitude(config)
    counts = write_attitude_bag(flight, args.output, storage=args.storage, overwrite=args.force)
    print(f"wrote {args.output}: " + ", ".join(f"{t} {n}" for t, n in sorted(counts.items())))
    return 0


def analyze_attitude_bag(bag: str, axis: str, config) -> dict:
    """Read one axis of an attitude bag, run filter and monitor; a JSON-able summary."""
    from flight_fdi.core.actuator import attitude_model, run_attitude
    from flight_fdi.sim.attitude import read_attitude_bag

    data = read_attitude_bag(bag, axis)
    params = dict(((data.description or {}).get("model") or {}).get("params") or {})
    known = ("m_c", "sigma_md_walk", "sigma_angle", "sigma_rate", "sigma_angle0", "sigma_rate0",
             "sigma_md0")
    params = {k: float(v) for k, v in params.items() if k in known and v}
    model = attitude_model(data.measure, **params)
    fwd, mon = run_attitude(model, data.t, data.z, data.u, config=config, axis=axis)
    out = {"bag": str(bag), "model": {"name": model.name, "measure": data.measure,
                                      "params": dict(model.params)},
           "samples": int(len(fwd.t)), "duration_s": float(fwd.t[-1] - fwd.t[0]),
           "in_flight": {"exceed_fraction": float(fwd.exceeded.mean()),
                         "alarms": len(fwd.alarms())},
           "monitor": mon.summary()}
    fault = (data.description or {}).get("fault")
    if fault:
        out["injected_fault"] = fault
    return out


def run_analyze(args: argparse.Namespace) -> int:
    res = analyze_attitude_bag(args.bag, args.axis, monitor_config(args))
    if args.json:
        json.dump(res, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    mon = res["monitor"]
    print(f"bag {res['bag']}  axis {mon['axis']}  {res['duration_s']:.1f} s  "
          f"{res['samples']} samples  measuring {res['model']['measure']}")
    print(f"zero-control windows: {mon['windows']} ({mon['windows_evaluated']} evaluated), "
          f"largest |mean disturbance| {mon['max_abs_mean'] or 0:.3g} rad/s^2, threshold "
          f"{mon['config']['threshold']:.3g}")
    if mon["events"]:
        e = mon["events"][0]
        print(f"ACTUATOR FAULT at {e['t']:.1f} s on axis {e['axis']}: mean disturbance "
              f"{e['mean']:.3g} rad/s^2 over {e['window_start_t']:.1f} .. "
              f"{e['window_end_t']:.1f} s exceeds {e['threshold']:.3g} -> switch to reserve")
    else:
        print("no actuator fault")
    return 0


def run_study(args: argparse.Namespace) -> int:
    from flight_fdi.eval.attitude import AttitudeStudyConfig, run_attitude_study

    if args.jobs < 1:
        raise CliError(f"--jobs must be >= 1, got {args.jobs}")
    config = AttitudeStudyConfig(nominal=args.nominal, faulty=args.faulty,
                                 duration_s=args.duration, seed=args.seed,
                                 monitor=monitor_config(args))
    res = run_attitude_study(config, jobs=args.jobs, progress=not args.no_progress)
    m = res["metrics"]
    if args.json:
        json.dump({k: v for k, v in res.items() if k != "flights"}, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    e = m["errors"]

    def pct(x):
        return "-" if x is None else f"{100 * x:.1f}%"

    print(f"type I (false alarm on nominal): {pct(e['type_I'])} ({e['false_alarms']}/"
          f"{e['nominal']}); type II (missed leak): {pct(e['type_II'])} "
          f"({e['missed']}/{e['faulty']})")
    d = m["delay_s"]
    if d["n"]:
        print(f"detection delay: median {d['median']:.1f} s, 5-95% {d['p05']:.1f} .. "
              f"{d['p95']:.1f} s")
    print("| leak rad/s^2 | n | detected | median delay s |\n|---|---|---|---|")
    for r in m["by_level"]:
        md = "-" if r["delay_median_s"] is None else f"{r['delay_median_s']:.1f}"
        print(f"| {r['level']:.3g} | {r['n']} | {pct(r['detected'])} | {md} |")
    print(f"({e['nominal'] + e['faulty']} flights in {res['elapsed_s']:.1f} s)")
    return 0
