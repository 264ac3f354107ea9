"""``flight-fdi voter-calibrate OUTPUT``: threshold table of the triple-IMU voter (seed 002).

Monte Carlo over N nominal flights of three co-mounted IMUs with pulse outputs
(flight_fdi.sim.imu): at each time step the window means of the pair differences x1 = P1 - P2,
x2 = P2 - P3, x3 = P1 - P3 of every quantity (gyro x/y/z, accel x/y/z) are tested for normality
(Kolmogorov-Smirnov); normal -> mu +- z sigma (maximum likelihood), otherwise the alpha/2 and
1 - alpha/2 quantiles; the bound curves are cut into segments at their largest rates of change,
each segment taking its max / min. The table is written as JSON (schema in
flight_fdi/core/voting.py and docs/seed002_experiment.md) and loaded by voter_node.

With ``--from-bags BAG...`` the same procedure runs on recorded nominal flights of three real
IMUs instead (flight_fdi.core.voter_real): time offsets and mounting are estimated, each pair's
offset is learnt in the first ``--learn`` seconds of every flight and the bounds hold the
deviation from it (docs/voter_real.md). ``--grade`` picks the simulated IMUs' error presets.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path


#: IMU grades of the simulator: navigation = the documented defaults of ImuErrorModel (seed
#: 002's experiment); tactical and mems = the turn-on bias, white noise, scale factor and pulse
#: of flight_fdi.sim.imu3d's grades (their bias instability has no counterpart in this model)
GRADES = ("navigation", "tactical", "mems")
#: the sequential detector's defaults (chosen leave-one-day-out, docs/voter_real.md)
SEQ_DRIFT = "off,0.025"
SEQ_MARGIN = 3.0


def grade_params(name: str) -> dict[str, float]:
    """ImuErrorModel parameters of a grade (--param overrides them)."""
    if name == "navigation":
        return {}
    from flight_fdi.sim.imu import ARCSEC
    from flight_fdi.sim.imu3d import DEG_H, DEG_RTH, GRADES as GRADES_3D, UG

    g = GRADES_3D[name]
    return {"gyro_bias_dph": g.gyro_bias / DEG_H, "gyro_scale_ppm": g.gyro_scale * 1e6,
            "gyro_arw_dph_rthz": g.arw / DEG_RTH, "gyro_pulse_arcsec": g.gyro_quantum / ARCSEC,
            "accel_bias_ug": g.accel_bias / UG, "accel_scale_ppm": g.accel_scale * 1e6,
            "accel_vrw_ug_rthz": g.vrw / UG, "accel_pulse_mps": g.accel_quantum}


def add_imu_options(p: argparse.ArgumentParser, duration: float = 60.0) -> None:
    """Options of the IMU simulation shared by the voter commands."""
    p.add_argument("--grade", choices=GRADES, default="navigation",
                   help="IMU error presets (default navigation; --param overrides single values)")
    p.add_argument("--duration", type=float, default=duration, metavar="S",
                   help=f"flight duration in seconds (default {duration:g})")
    p.add_argument("--rate", type=float, default=200.0, metavar="HZ",
                   help="IMU sample rate (default 200)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="override an IMU error parameter (repeatable): "
                        + ", ".join(_param_names()))


def _param_names() -> list[str]:
    from flight_fdi.sim.imu import ImuErrorModel

    return list(ImuErrorModel.__dataclass_fields__)


def imu_config(args: argparse.Namespace, faults=()):
    """ImuSimConfig from the shared options."""
    from flight_fdi.sim.errors import SimError
    from flight_fdi.sim.imu import ImuErrorModel, ImuSimConfig

    params: dict[str, float] = grade_params(getattr(args, "grade", "navigation"))
    for item in args.param:
        if "=" not in item:
            raise SimError(f"--param {item!r}: expected NAME=VALUE")
        name, value = (s.strip() for s in item.split("=", 1))
        try:
            params[name] = float(value)
        except ValueError:
            raise SimError(f"--param {item!r}: {value!r} is not a number") from None
    return ImuSimConfig(duration_s=args.duration, rate_hz=args.rate, seed=args.seed,
                        faults=tuple(faults), errors=ImuErrorModel.from_dict(params))


def add_calibration_options(p: argparse.ArgumentParser, flights: int = 1000) -> None:
    p.add_argument("--window", type=int, default=1000, metavar="N",
                   help="samples of the window mean (default 1000, as the seed)")
    p.add_argument("--ks-alpha", type=float, default=0.05,
                   help="significance of the Kolmogorov-Smirnov normality test (default 0.05)")
    p.add_argument("--method", choices=("auto", "normal", "quantile"), default="auto",
                   help="bounds: auto (KS decides), or force normal / quantile (default auto)")
    p.add_argument("--segments", type=int, default=12, metavar="K",
                   help="at most K threshold segments per curve (default 12)")
    p.add_argument("--min-segment", type=float, default=1.0, metavar="S",
                   help="shortest threshold segment in seconds (default 1)")
    p.add_argument("--smooth", type=float, default=1.0, metavar="S",
                   help="moving average over S seconds before the rates of change are ranked "
                        "(0: none; default 1)")
    p.add_argument("--no-window-cut", action="store_true",
                   help="do not force a segment boundary at the end of the first window "
                        "(the seed's segmentation by rates of change alone)")
    p.add_argument("--eval-every", type=int, default=10, metavar="K",
                   help="evaluate the distribution every K samples (default 10)")
    p.add_argument("--batch", type=int, default=100, metavar="B",
                   help="flights simulated together (memory vs speed, default 100)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _check_int(value: int, name: str, low: int = 1) -> None:
    from flight_fdi.cli.errors import CliError

    if value < low:
        raise CliError(f"{name} must be >= {low}, got {value}")


def simulate_means(config, n_flights: int, args: argparse.Namespace, quantities,
                   first_run: int = 0, desc: str = "calibration flights"):
    """The calibration Monte Carlo with a tqdm bar on stderr: (t, means)."""
    from tqdm import tqdm

    from flight_fdi.sim.imu import nominal_window_means

    with tqdm(total=n_flights, desc=desc, unit="flight", disable=args.no_progress,
              file=sys.stderr, leave=False) as bar:
        return nominal_window_means(config, n_flights, args.window, quantities,
                                    eval_every=args.eval_every, batch_size=args.batch,
                                    first_run=first_run, progress=bar.update)


def calibration_meta(config, n_flights: int, first_run: int = 0) -> dict:
    from dataclasses import asdict

    return {"simulator": "flight_fdi.sim.imu", "seed": int(config.seed),
            "first_run": int(first_run), "flights": int(n_flights),
            "duration_s": float(config.duration_s), "rate_hz": float(config.rate_hz),
            "errors": asdict(config.errors), "profile": asdict(config.flight_profile())}


def calibrate_from_means(t, means, args: argparse.Namespace, alpha: float, config, quantities,
                         first_run: int = 0):
    from flight_fdi.core.voting_calib import calibrate

    return calibrate(means, t, alpha, args.window, config.rate_hz, quantities,
                     ks_alpha=args.ks_alpha, n_segments=args.segments,
                     min_segment_s=args.min_segment, smooth_s=args.smooth,
                     cut_at_window=not args.no_window_cut,
                     method=args.method,
                     duration_s=config.duration_s,
                     calibration=calibration_meta(config, means.shape[0], first_run))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("voter-calibrate", help="Monte Carlo threshold table for the triple-IMU "
                       "voter", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("output", help="threshold table file to write (JSON)")
    p.add_argument("--from-bags", nargs="+", metavar="BAG", default=None,
                   help="calibrate on these recorded nominal flights of three real IMUs "
                        "(/imu1/data ... /imu3/data) instead of the simulator")
    p.add_argument("--learn", type=float, default=5.0, metavar="S",
                   help="recordings: seconds at the start of a flight that learn the offsets "
                        "and time offsets (default 5)")
    p.add_argument("--prefilter", type=int, default=12, metavar="K",
                   help="recordings: moving average of K samples before the window mean "
                        "(default 12)")
    p.add_argument("--margin", type=float, default=3.0, metavar="F",
                   help="recordings: bounds x F for flights of other days (default 3, chosen "
                        "by leave-one-day-out, docs/voter_real.md)")
    p.add_argument("--track", type=float, default=0.0, metavar="S",
                   help="recordings: time constant of the slow offset tracking (0: offsets "
                        "frozen after the learning; default 0)")
    p.add_argument("--baseline", choices=("learn", "grow"), default="learn",
                   help="recordings: offset model -- learn: the first --learn seconds; grow: "
                        "the step detector's baseline, every earlier healthy sample "
                        "(docs/voter_real.md; default learn)")
    p.add_argument("--offset-blocks", type=int, default=5, metavar="B",
                   help="recordings: the learnt offset is the median of B block means of the "
                        "learning phase (1: its mean; default 5, docs/voter_real.md)")
    p.add_argument("--no-sequential", action="store_true",
                   help="recordings: without the CUSUM sequential detector on the pair "
                        "residuals (default: with it, on the fixed offset model -- not with "
                        "--baseline grow or --track; thresholds from the same recordings)")
    p.add_argument("--seq-drift", default=SEQ_DRIFT, metavar="GYRO,ACCEL",
                   help="recordings: CUSUM drift nu, gyro in deg/h and accel in m/s^2, 'off': "
                        f"no CUSUM on that sensor (default {SEQ_DRIFT})")
    p.add_argument("--seq-margin", type=float, default=SEQ_MARGIN, metavar="F",
                   help="recordings: CUSUM thresholds = F x the largest nominal statistic "
                        f"(default {SEQ_MARGIN:g})")
    p.add_argument("--no-linear", action="store_true",
                   help="recordings: no per-pair linear model (lever arm, scale; fitted and "
                        "kept per quantity where it lowers the held-out residual)")
    p.add_argument("--flights", type=int, default=1000, metavar="N",
                   help="Monte Carlo flights (default 1000, as the seed)")
    p.add_argument("--alpha", type=float, default=0.05,
                   help="bounds of confidence 1 - alpha (default 0.05)")
    p.add_argument("--quantities", default="all", metavar="LIST",
                   help="comma-separated quantities (gyro_x ... accel_z; default all)")
    p.add_argument("--curves", metavar="FILE.npz", default=None,
                   help="also write the per-step bound curves (t, lower, upper, is_normal, "
                        "ks_pvalue) for plots")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    add_imu_options(p)
    add_calibration_options(p)
    p.set_defaults(func=run)


def parse_drift(text: str) -> dict[str, float]:
    """--seq-drift GYRO_DPH,ACCEL -> {quantity: drift in SI units} ('off': left out)."""
    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.voting import QUANTITIES

    parts = [v.strip().lower() for v in text.split(",")]
    try:
        if len(parts) != 2:
            raise ValueError
        gyro, accel = (None if v == "off" else float(v) for v in parts)
    except ValueError:
        raise CliError(f"--seq-drift must be GYRO_DEG_H,ACCEL (numbers or off), got {text!r}"
                       ) from None
    if any(v is not None and not (math.isfinite(v) and v >= 0) for v in (gyro, accel)):
        raise CliError(f"--seq-drift must be >= 0, got {text!r}")
    if gyro is None and accel is None:
        raise CliError("--seq-drift: both off; use --no-sequential")
    dph = math.pi / 180 / 3600
    out = {q: gyro * dph for q in QUANTITIES if q.startswith("gyro") and gyro is not None}
    out.update({q: accel for q in QUANTITIES if q.startswith("accel") and accel is not None})
    return out


def parse_quantities(text: str) -> tuple[str, ...]:
    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.voting import QUANTITIES

    if text.strip().lower() == "all":
        return QUANTITIES
    qs = tuple(q.strip().lower() for q in text.split(",") if q.strip())
    bad = [q for q in qs if q not in QUANTITIES]
    if bad or not qs:
        raise CliError(f"--quantities: unknown {', '.join(bad) or 'empty list'}; quantities are "
                       f"{', '.join(QUANTITIES)} (or all)")
    if len(set(qs)) != len(qs):
        raise CliError("--quantities: a quantity is listed twice")
    return tuple(q for q in QUANTITIES if q in qs)


def summary(table, elapsed_s: float, path: str) -> dict:
    from flight_fdi.core.voting import PAIRS

    entries = {}
    for q in table.quantities:
        entries[q] = {}
        for pair in PAIRS:
            ts, lo, up = table.entries[q][pair]
            st = table.stats.get(q, {}).get(pair, {})
            entries[q][pair] = {"segments": int(len(ts)),
                                "normal_fraction": st.get("normal_fraction"),
                                "lower_min": float(lo.min()), "upper_max": float(up.max()),
                                "upper_after_first_window": float(
                                    up[ts >= table.window / table.rate_hz].max())
                                if (ts >= table.window / table.rate_hz).any() else None}
    return {"output": path, "flights": table.calibration.get("flights"),
            "alpha": table.alpha, "window": table.window, "rate_hz": table.rate_hz,
            "elapsed_s": round(elapsed_s, 2), "entries": entries}


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.voting import PAIRS, save_table

    out = Path(args.output)
    if out.exists() and not args.force:
        raise CliError(f"{out} exists already (use --force to overwrite)")
    if not out.parent.is_dir():
        raise CliError(f"cannot write {out}: directory {out.parent} does not exist")
    for name in ("flights", "window", "segments", "eval_every", "batch"):
        _check_int(getattr(args, name), "--" + name.replace("_", "-"))
    if not (math.isfinite(args.alpha) and 0 < args.alpha < 1):
        raise CliError(f"--alpha must be in (0, 1), got {args.alpha!r}")
    for name in ("min_segment", "smooth"):
        v = getattr(args, name)
        if not math.isfinite(v) or v < 0:
            raise CliError(f"--{name.replace('_', '-')} must be >= 0, got {v!r}")
    quantities = parse_quantities(args.quantities)
    if args.from_bags:
        return run_bags(args, out, quantities)
    config = imu_config(args)
    start = time.perf_counter()
    t, means = simulate_means(config, args.flights, args, quantities)
    cal = calibrate_from_means(t, means, args, args.alpha, config, quantities)
    save_table(cal.table, out)
    if args.curves:
        try:
            np.savez_compressed(args.curves, t=cal.t, lower=cal.lower, upper=cal.upper,
                                is_normal=cal.is_normal, ks_pvalue=cal.ks_pvalue,
                                quantities=np.array(quantities), pairs=np.array(PAIRS))
        except OSError as exc:
            raise CliError(f"cannot write {args.curves}: {exc.strerror or exc}") from None
    info = summary(cal.table, time.perf_counter() - start, str(out))
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    print(f"wrote {out}: {args.flights} flights of {config.duration_s:g} s at "
          f"{config.rate_hz:g} Hz, window {args.window}, alpha {args.alpha:g}, "
          f"{info['elapsed_s']:.1f} s")
    print(f"{'quantity':<8} {'pair':<4} {'segs':>4} {'normal':>7} {'lower min':>12} "
          f"{'upper max':>12} {'upper after 1st window':>23}")
    for q, pairs in info["entries"].items():
        unit = 1.0 if q.startswith("accel") else math.pi / 180 / 3600
        uname = "m/s^2" if q.startswith("accel") else "deg/h"
        for pair, e in pairs.items():
            after = e["upper_after_first_window"]
            print(f"{q:<8} {pair:<4} {e['segments']:>4} {e['normal_fraction']:>7.2f} "
                  f"{e['lower_min'] / unit:>12.4g} {e['upper_max'] / unit:>12.4g} "
                  f"{'-' if after is None else format(after / unit, '.4g'):>17} {uname}")
    return 0


def run_bags(args: argparse.Namespace, out: Path, quantities) -> int:
    """``--from-bags``: the calibration on recordings (flight_fdi.core.voter_real)."""
    import numpy as np

    from flight_fdi.bagio.imu_reader import read_imu_triples
    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.voter_real import calibrate_recordings
    from flight_fdi.core.voting import save_table

    _check_int(args.offset_blocks, "--offset-blocks")
    if not args.seq_margin >= 1:
        raise CliError(f"--seq-margin must be >= 1, got {args.seq_margin!r}")
    # the CUSUM runs against the fixed offset of the learning phase only
    fixed = args.baseline == "learn" and args.track == 0
    drift = None if args.no_sequential or not fixed else parse_drift(args.seq_drift)
    for name in ("learn", "margin", "track"):
        v = getattr(args, name)
        if not math.isfinite(v) or v < 0:
            raise CliError(f"--{name} must be >= 0, got {v!r}")
    _check_int(args.prefilter, "--prefilter")
    start = time.perf_counter()
    recs, rates = [], []
    for bag in args.from_bags:
        d = read_imu_triples(bag)
        recs.append((d.stamp_ns, d.P))
        rates.append(1e9 / float(np.median(np.diff(d.stamp_ns))))
    rate = float(np.median(rates))
    if max(abs(r / rate - 1) for r in rates) > 0.02:
        raise CliError("the recordings have different sample rates: "
                       + ", ".join(f"{r:.1f} Hz" for r in rates))
    rate = round(rate, 3)
    window = args.window if args.window != 1000 else int(round(5.0 * rate))
    table, meta = calibrate_recordings(
        recs, args.alpha, rate, window=window, prefilter=args.prefilter, learn_s=args.learn,
        track_tau_s=args.track, margin=max(1.0, args.margin), ks_alpha=args.ks_alpha,
        method=args.method, n_segments=args.segments, quantities=quantities,
        names=[str(b) for b in args.from_bags], baseline=args.baseline,
        linear=not args.no_linear, offset_blocks=args.offset_blocks, sequential=drift,
        sequential_margin=args.seq_margin)
    save_table(table, out)
    info = summary(table, time.perf_counter() - start, str(out))
    info.update({"recordings": len(recs), "time_offsets_s": meta["time_offsets_s"],
                 "mounting": meta["mounting"], "sequential": meta["sequential"]})
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    print(f"wrote {out}: {len(recs)} recordings at {rate:g} Hz, window {window}, learn "
          f"{args.learn:g} s, alpha {args.alpha:g}, margin {args.margin:g}, "
          f"{info['elapsed_s']:.1f} s")
    for name, tau in meta["time_offsets_s"].items():
        print(f"  {name}: time offsets IMU2 {1e3 * tau[1]:.1f} ms, IMU3 {1e3 * tau[2]:.1f} ms")
    for key, m in meta["mounting"].items():
        print(f"  mounting {key}: rotation {m['rotation_deg']} deg, scale {m['scale_pct']} %")
    for q in table.quantities:
        unit, uname = (1.0, "m/s^2") if q.startswith("accel") else (math.pi / 180 / 3600,
                                                                   "deg/h")
        ups = [float(table.entries[q][p][2].max()) / unit for p in ("x1", "x2", "x3")]
        print(f"  {q:<8} largest upper bound x1/x2/x3: "
              + " / ".join(f"{u:.4g}" for u in ups) + f" {uname}")
    seq = meta["sequential"]
    for q, h in (seq or {}).get("threshold", {}).items():
        unit, uname = (1.0, "m/s^2") if q.startswith("accel") else (math.pi / 180 / 3600,
                                                                   "deg/h")
        print(f"  {q:<8} CUSUM drift {seq['drift'][q] / unit:.4g} {uname}, thresholds x1/x2/x3 "
              + " / ".join(f"{v / unit:.4g}" for v in h) + f" {uname} s")
    return 0
