#!/usr/bin/env python3
"""The 3-D post-flight isolator (ins3d) on the real Xsens DOT recordings: the tables of
docs/ins3d_real.md (markdown on stdout or --out), seeded.

    .venv/bin/python tools/ins3d_real_eval.py [--data DIR] [--seed 1] [--settings abcdefghij]
                                              [--out F]

For each setting (SETTINGS: process noise, accelerometer prior, reference correction, the
decision's model-error allowance): the units'
turn-on biases and their leave-one-out residuals, the nominal analyses (every recording x unit),
then bias steps injected into the unit's samples (accelerometer 0.1/0.3/1.0 m/s^2, gyro
300/1000/3000 deg/h, per body axis, random sign and onset in [3 s, T - 5 s], seeded per run).
"""
from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from collections import Counter
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flight_fdi.cli.errors import CliError  # noqa: E402
from flight_fdi.core.errors import CoreError  # noqa: E402
from flight_fdi.core.ins3d.grades import DEG_H  # noqa: E402
from flight_fdi.eval import real3d as R  # noqa: E402
from flight_fdi.eval.real3d_error import model_error_angle  # noqa: E402

HEIGHT_SIGMA = float(np.hypot(0.05, 0.4))     # m: the height row's white and Markov parts
#: (label, Settings options, with the fault tables): process noise (gyro ARW deg/sqrt(h),
#: VRW m/s/sqrt(s)) and the reference's INS shape correction (Contract.ref_ins_shape)
SETTINGS = {
    "a": ("ARW 10 °/√h, VRW 0.03 m/s/√s, accelerometer bias 0.3 m/s², reference without the "
          "INS shape (the first version)",
          {"arw_deg_rt_h": 10.0, "vrw": 0.03, "accel_bias": 0.3,
           "contract": R.Contract(ref_ins_shape=False)}, False),
    "b": ("ARW 10 °/√h, VRW 0.03 m/s/√s, accelerometer bias 0.3 m/s²",
          {"arw_deg_rt_h": 10.0, "vrw": 0.03, "accel_bias": 0.3}, True),
    "c": ("ARW 3 °/√h, VRW 0.02 m/s/√s, accelerometer bias 0.3 m/s²",
          {"arw_deg_rt_h": 3.0, "vrw": 0.02, "accel_bias": 0.3}, True),
    "d": ("ARW 3 °/√h, VRW 0.02 m/s/√s, accelerometer bias 0.5 m/s², independent initial "
          "states (**default**)", {}, True),
    "e": ("ARW 60 °/√h, VRW 0.05 m/s/√s, accelerometer bias 0.5 m/s²",
          {"arw_deg_rt_h": 60.0, "vrw": 0.05}, True),
    "f": ("(d) with the model-error allowance of sessions 11-14 (signature error 0.33 rad, "
          "measured while the fault runs' reference carried the faulty INS's shape)",
          {"signature_error": 0.33}, True),
    "g": ("(d) with the initial covariance of a levelled INS (the tilt cancels the horizontal "
          "accelerometer bias; the default before)", {"aligned_prior": True}, True),
    "h": ("(d) as before session 15: the fault runs' reference built with the faulty INS's "
          "shape, and the 0.33-rad allowance", {"nominal_reference": False,
                                                "signature_error": 0.33}, True),
    "i": ("(d) with the barometric height as a third reference row: white σ 0.05 m and a "
          "Markov error of σ 0.4 m, τ 5 s; the initial vertical velocity σ 1 m/s",
          {"contract": R.Contract(height_sigma=HEIGHT_SIGMA), "v0_sigma_up": 1.0,
           "ref_markov": (1e-3, 0.4, 5.0)}, True),
    "j": ("(i) with a looser barometer: Markov σ 0.8 m, τ 10 s (the sensitivity to that choice)",
          {"contract": R.Contract(height_sigma=float(np.hypot(0.05, 0.8))), "v0_sigma_up": 1.0,
           "ref_markov": (1e-3, 0.8, 10.0)}, True),
}
#: the recordings the model-error allowance was calibrated on (Settings.signature_error) and
#: the day held out from it
FIT_DAYS = ("straight", "vertical_a")
HELD_OUT = "vertical_b"
SIZES = {"accelerometer": (0.1, 0.3, 1.0), "gyro": (300.0, 1000.0, 3000.0)}
UNIT = {"accelerometer": "m/s^2", "gyro": "deg/h"}


def _si(sensor: str, size: float) -> float:
    return size * DEG_H if sensor == "gyro" else size


def bias_table(cal: R.Calibration) -> list[str]:
    rg, ra = cal.residuals()
    g = np.array([v[0] for v in cal.biases.values()]) / DEG_H
    a = np.array([v[1] for v in cal.biases.values()])
    rows = ["| quantity | x | y | z |", "|---|---|---|---|"]
    for label, arr, fmt in (("gyro turn-on bias, range over units and recordings (deg/h)",
                             g, "{:.0f} … {:.0f}"),
                            ("accelerometer bias, range (m/s²)", a, "{:.2f} … {:.2f}")):
        rows.append(f"| {label} | " + " | ".join(fmt.format(arr[:, i].min(), arr[:, i].max())
                                                  for i in range(3)) + " |")
    rows.append("| gyro residual after leave-one-out calibration, rms (deg/h) | "
                + " | ".join(f"{np.sqrt(np.mean(rg[:, i] ** 2)) / DEG_H:.0f}"
                             for i in range(3)) + " |")
    rows.append("| accelerometer residual, rms (m/s²) | "
                + " | ".join(f"{np.sqrt(np.mean(ra[:, i] ** 2)):.3f}" for i in range(3)) + " |")
    return rows


def nominal(data: Path, cal, names, units, st: R.Settings, dump=None
            ) -> tuple[list[str], dict]:
    per_day: dict[str, list[dict]] = {}
    detail, outcome = [], {}
    for name in names:
        outs = []
        for u in units:
            bg, ba = cal.for_recording(name, u)
            out = R.record(R.analyze(R.read_recording(data, name, u), bg, ba, st))
            out["outcome"] = outcome[(name, u)] = R.judge(out, None,
                                                          R.REFERENCE_GLITCHES.get(name, ()))
            if dump is not None:
                dump.write(json.dumps({"name": name, "unit": u, "fault": None,
                                       "outcome": out["outcome"], "record": out}) + "\n")
            outs.append(out)
            per_day.setdefault(R.day_of(name), []).append(out)
        named = Counter(f"{o['verdict']}" + (f" {o['sensor']} {o['axis']}" if o["sensor"] else "")
                        for o in outs)
        detail.append(f"| {name} | {np.mean([o['beta2'] for o in outs]):.2f} | "
                      + f"{max(o['max_step'] for o in outs):.1f} | "
                      + f"{max(o['max_jump'] for o in outs):.1f} | "
                      + f"{max(o['max_outliers'] for o in outs):.1f} | "
                      + ", ".join(f"{k} ×{v}" for k, v in sorted(named.items())) + " |")
    rows = ["| day | runs | verdict not no_fault | seed method (χ² J) failure / glitch | "
            "false IMU isolation | reference named | the recording's own RTK glitch named | "
            "ambiguous | none | "
            "β² mean (2 rows) median [max] | largest step GLR median [max] | ramp | jump | "
            "outliers |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    allo = [o for v in per_day.values() for o in v]
    for day, outs in list(per_day.items()) + [("all", allo)]:
        c = Counter(o["outcome"] for o in outs)

        def med_max(key):
            v = np.array([o[key] for o in outs])
            return f"{np.median(v):.1f} [{v.max():.1f}]"
        seed = Counter(o["seed_verdict"] for o in outs)
        declared = sum(o["verdict"] not in ("no_fault", "insufficient_data") for o in outs)
        rows.append(f"| {day} | {len(outs)} | {declared} | {seed['failure']} / "
                    f"{seed['glitch']} | {c['false']} | {c['reference']} | "
                    f"{c['glitch']} | {c['ambiguous']} | {c['none']} | {med_max('beta2')} | "
                    f"{med_max('max_step')} | {med_max('max_ramp')} | {med_max('max_jump')} | "
                    f"{med_max('max_outliers')} |")
    rows += ["", validity_line(allo)]
    head = ["| recording | β² mean | largest step GLR | jump | outliers | outcomes (4 units) |",
            "|---|---|---|---|---|---|"]
    thr = allo[0]["thresholds"]
    return rows + ["", f"Thresholds (the tactical preset's, the custom grade is not "
                   f"calibrated): {thr}.", ""] + head + detail, outcome


def faults(data: Path, cal, names, units, st: R.Settings, seed: int, nominal_outcome: dict,
           dump=None) -> list[str]:
    rows = ["| fault | size | runs | right sensor+axis | confident wrong | of which the nominal "
            "run was clean | ambiguous | of which the right one is a candidate | none | "
            "the recording's own RTK glitch only (fault missed) | "
            "median onset error (s) | median magnitude error | "
            "most frequent wrong or ambiguous answer | held out (vertical 8-14): right / "
            "confident wrong of 28 |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    smallest, angles, totals, records = {}, {}, Counter(), []
    for sensor, sizes in SIZES.items():
        for axis in R.AXES:
            for size in sizes:
                c, oe, me, other = Counter(), [], [], Counter()
                for name, unit, f, out, o in R.fault_runs(data, cal, names, units, sensor, axis,
                                                          _si(sensor, size), seed, st):
                    c[o] += 1
                    records.append(out)
                    if dump is not None:
                        dump.write(json.dumps({"name": name, "unit": unit, "fault": asdict(f),
                                               "outcome": o, "record": out}) + "\n")
                    held = R.day_of(name) == HELD_OUT
                    c["held_" + o] += held
                    totals[("held" if held else "fit", o)] += 1
                    a = model_error_angle(out, f)
                    if a is not None:
                        angles.setdefault(R.day_of(name), []).append(a)
                    c["wrong_clean"] += o == "wrong" and nominal_outcome[(name, unit)] == "none"
                    c["amb_right"] += o == "ambiguous" and any(
                        x.startswith(f"{sensor} {axis} ") for x in out["candidates"])
                    if o == "ambiguous":
                        other["ambiguous: " + " / ".join(sorted(out["candidates"]))] += 1
                    elif o == "wrong":
                        other[f"{out['sensor']} {out['axis']} {out['kind']}"] += 1
                    if o == "right":
                        oe.append(abs(out["onset_s"] - f.onset_s))
                        me.append(out["magnitude"] / f.magnitude - 1.0)
                n = sum(c[k] for k in ("right", "wrong", "ambiguous", "none", "glitch"))
                if c["right"] > n / 2 and (sensor, axis) not in smallest:
                    smallest[(sensor, axis)] = size
                rows.append(f"| {sensor} {axis} step | {size:g} {UNIT[sensor]} | {n} | "
                            f"{100 * c['right'] / n:.0f} % | {100 * c['wrong'] / n:.0f} % | "
                            f"{100 * c['wrong_clean'] / n:.0f} % | "
                            f"{100 * c['ambiguous'] / n:.0f} % | "
                            f"{100 * c['amb_right'] / n:.0f} % | {100 * c['none'] / n:.0f} % | "
                            f"{c['glitch']} | "
                            + (f"{np.median(oe):.1f} | {100 * np.median(me):+.0f} % | "
                               if oe else "- | - | ")
                            + (f"{other.most_common(1)[0][0]} ×{other.most_common(1)[0][1]} |"
                               if other else "- |")
                            + f" {c['held_right']} / {c['held_wrong']} |")
    rows += ["", "Smallest size isolated to the right sensor and axis on most (> 50 %) runs: "
             + "; ".join(f"{s} {a}: " + (f"{smallest[(s, a)]:g} {UNIT[s]}"
                                         if (s, a) in smallest else "none of the sizes")
                         for s in SIZES for a in R.AXES) + "."]
    rows += ["", "All fault runs: " + "; ".join(
        f"{lab} {sum(v for (g, _), v in totals.items() if g == key)} runs: right "
        f"{totals[(key, 'right')]}, confident wrong {totals[(key, 'wrong')]}, ambiguous "
        f"{totals[(key, 'ambiguous')]}, the recording's own RTK glitch only "
        f"{totals[(key, 'glitch')]}" for key, lab in (("fit", "fit days (straight, "
                                                           "vertical 1-7)"),
                                                          ("held", "held out (vertical 8-14)")))
             + "."]
    return rows + ["", validity_line(records), ""] + angle_table(angles)


def validity_line(records: list[dict]) -> str:
    """How many runs were relinearised (``record``'s ``relinearised``: a pass about the
    smoothed attitude error kept) and how many left the model valid (``model_valid``), with
    the largest smoothed attitude error."""
    n = len(records)
    att = [r["attitude_error_max_deg"] for r in records
           if r.get("attitude_error_max_deg") is not None]
    return (f"Relinearised: {sum(bool(r['relinearised']) for r in records)} of {n} runs "
            f"({sum(r['relinearisation_passes'] for r in records)} passes kept); model valid "
            f"(smoothed attitude error within the small-angle limit): "
            f"{sum(r['model_valid'] is True for r in records)} of {n}"
            + (f", largest attitude error {max(att):.2f} deg." if att else "."))


def angle_table(angles: dict[str, list[float]]) -> list[str]:
    """The model's signature error seen in the fault runs (``model_error_angle``) per day and
    on the fit days pooled: what ``Settings.signature_error`` is calibrated from."""
    rows = ["Model error: the angle (rad) by which the true hypothesis's signature misses the "
            "data beyond noise, in the runs where it is the best or the runner-up "
            "(`real3d_error.model_error_angle`):", "",
            "| days | runs | median | q90 | q95 | max |", "|---|---|---|---|---|---|"]
    fit = [a for d in FIT_DAYS for a in angles.get(d, [])]
    for label, v in [(d, angles.get(d, [])) for d in (*FIT_DAYS, HELD_OUT)] + [
            ("fit days pooled", fit)]:
        if v:
            q = np.quantile(v, [0.5, 0.9, 0.95, 1.0])
            rows.append(f"| {label} | {len(v)} | " + " | ".join(f"{x:.3f}" for x in q) + " |")
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=R.default_data_dir())
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--units", default="1,2,3,4")
    p.add_argument("--settings", default="abcdefghij",
                   help="which SETTINGS (letters a-j, default all)")
    p.add_argument("--no-faults", action="store_true")
    p.add_argument("--out", type=Path)
    p.add_argument("--records", type=Path,
                   help="also write every run's record (JSON lines: recording, unit, fault, "
                        "outcome, record) to this file")
    args = p.parse_args(argv)
    if not args.data.is_dir():
        print(f"ins3d_real_eval: no data directory {args.data}", file=sys.stderr)
        return 2
    bad = [k for k in args.settings if k not in SETTINGS]
    try:
        units = [int(u) for u in args.units.split(",")]
    except ValueError:
        bad.append(args.units)
    if bad or not args.settings:
        print(f"ins3d_real_eval: unknown --settings / --units {bad} (settings: "
              f"{''.join(SETTINGS)}, units e.g. 1,2,3,4)", file=sys.stderr)
        return 2
    names = R.names_in(args.data)
    if not names:
        print(f"ins3d_real_eval: no recording of the set under {args.data}", file=sys.stderr)
        return 2
    t0 = time.time()
    try:
        cal = R.calibrate(args.data, names, units)
    except (CoreError, CliError) as exc:       # EvalError; the CSV reader's CliError
        print(f"ins3d_real_eval: {exc}", file=sys.stderr)
        return 2
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=Path(__file__).parent).stdout.strip()
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() \
        else ["?"]
    lines = [f"Settings: {len(names)} recordings × units {units} of {args.data.name}, seed "
             f"{args.seed}, commit {commit}, {platform.node()}, load {' '.join(load)} at start.",
             "", "### Units (the calibration removed before mechanization)", ""]
    lines += bias_table(cal)
    dump = args.records.open("w", encoding="utf-8") if args.records else None
    for key in args.settings:
        label, opts, with_faults = SETTINGS[key]
        st = R.Settings(**opts)
        rows_text = "3 rows (the third the height)" if st.height else f"{st.rows} rows"
        lines += ["", f"### ({key}) {label}", "",
                  f"Grade: residual gyro bias {st.gyro_bias_deg_h:g} deg/h, accelerometer bias "
                  f"{st.accel_bias:g} m/s²; {rows_text}, vertical {st.vertical}; reference "
                  f"±{st.contract.ref_half * R.GT_DT:g} s central differences every "
                  f"{st.contract.ref_every * R.GT_DT:g} s, INS shape "
                  f"{'on' if st.contract.ref_ins_shape else 'off'}; the decision's model-error "
                  f"allowance (signature error) "
                  + (f"{st.signature_error:g} rad" if st.signature_error is not None else
                     "none (the grade's misalignment)") + ".", "", "#### Nominal", ""]
        rows, outcome = nominal(args.data, cal, names, units, st, dump)
        lines += rows
        if with_faults and not args.no_faults:
            lines += ["", "#### Injected bias steps", ""]
            lines += faults(args.data, cal, names, units, st, args.seed, outcome, dump)
    if dump is not None:
        dump.close()
    lines += ["", f"Wall time {time.time() - t0:.0f} s."]
    text = "\n".join(lines) + "\n"
    if args.out:
        args.out.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
