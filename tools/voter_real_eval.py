#!/usr/bin/env python3
"""Judge the triple-IMU voter on the real recordings (docs/voter_real.md), leave-one-day-out.

    .venv/bin/python tools/voter_real_eval.py [DATA_DIR] [--alpha 0.002] [--margin 3] [--json]
        [--baseline learn|grow] [--no-linear] [--offset-blocks B] [--no-sequential]
        [--seq-drift GYRO,ACCEL] [--seq-margin F] [--nominal-only] [--cases LABEL,...]

The defaults are those of voter-calibrate --from-bags (offset: median of 5 block means of the
learning phase; CUSUM sequential detector on the accelerometers, drift 0.025 m/s^2, thresholds
3 x the largest nominal statistic of the calibration days).

DATA_DIR (default ../shared/data/mimu_quadrotor) holds <group>/path_N/IMU_1..3.csv.gz. The
recordings are split into three flight days, told apart by the units' time offsets (straight
lines; vertical 1-7; vertical 8-14). For each day the thresholds are calibrated on the two other
days (flight_fdi.core.voter_real, the code of voter-calibrate --from-bags) and the voter engine
(flight_fdi.core.voter_core, the code of flight-fdi vote and voter_node) judges the day's
recordings: nominal, and with faults injected into IMU2 or IMU3 from ONSET s (recordings at least
ONSET + 5 s long): gyro z stuck at zero, gyro z bias steps 50 ... 2000 deg/h, accel x bias steps
0.05 ... 0.5 m/s^2, and the seed's square-wave gyro z bias (switching between 0 and A,
A = 5..100 deg/h, 1/5/20 Hz).
Detected = the faulty IMU is isolated on the faulty quantity at or after the onset with no
isolation before it; delay from the onset.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flight_fdi.cli.imu_csv import read_csv  # noqa: E402
from flight_fdi.cli.voter_calibrate import SEQ_DRIFT, SEQ_MARGIN, parse_drift  # noqa: E402
from flight_fdi.core.voter_core import DEFAULT_CONFIRM_S, VoterCore  # noqa: E402
from flight_fdi.core.voter_real import calibrate_recordings  # noqa: E402
from flight_fdi.core.voting import QUANTITIES  # noqa: E402

DPH = math.pi / 180 / 3600
RATE = 120.0
DAYS = {"straight": lambda g, n: g == "straight", "vertical 1-7": lambda g, n: g == "vertical"
        and n <= 7, "vertical 8-14": lambda g, n: g == "vertical" and n >= 8}


def load(root: Path) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    out = {}
    for d in sorted(root.glob("*/path_*"), key=lambda p: (p.parent.name, int(p.name[5:]))):
        g, n = d.parent.name, int(d.name[5:])
        day = next(k for k, f in DAYS.items() if f(g, n))
        t, _ = read_csv(d / "IMU_1.csv.gz")
        P = np.stack([read_csv(d / f"IMU_{k}.csv.gz")[1] for k in (1, 2, 3)], axis=-1)
        out[f"{g}/{d.name}"] = (day, np.round((1.7e9 + t) * 1e9).astype(np.int64), P)
    return out


def inject(P: np.ndarray, t: np.ndarray, kind: str, imu: int, onset: float, amp=0.0, f=0.0):
    P = P.copy()
    on = t >= onset
    k = imu - 1
    if kind == "stuck":
        P[on, 2, k] = 0.0
    elif kind == "gyro_step":
        P[on, 2, k] += amp * DPH
    elif kind == "accel_step":
        P[on, 3, k] += amp
    elif kind == "square":
        phase = np.floor(2 * f * (t - onset)) % 2 == 0
        P[on & phase, 2, k] += amp * DPH
    return P


def run_voter(table, ns, P, confirm, alarms=False):
    core = VoterCore(table, confirm=confirm)
    parts = [core.push(ns, P), core.finish()]
    status = np.concatenate([d.status for d in parts])
    events = [e for d in parts for e in d.events if e[3]]
    if not alarms:
        return status, events
    return status, events, cusum_alarms(core, parts)


def cusum_alarms(core, parts) -> int:
    """Pair-level CUSUM alarms (entries of a (quantity, pair) statistic above its threshold)."""
    if core.cusum is None:
        return 0
    g = np.concatenate([d.cusum for d in parts])
    out = np.abs(g.reshape(g.shape[0], -1)) > core.cusum.h
    return int(np.sum(out[0]) + np.sum(out[1:] & ~out[:-1]))


def judge(events, onset, imu, qname):
    before = [e for e in events if e[0] < onset]
    after = [e for e in events if e[0] >= onset]
    if before or not after:
        return False, None
    first = after[0]
    ok = first[3] == imu and QUANTITIES[first[1]] == qname
    return ok, first[0] - onset


def evaluate(data, alpha, margin, onset, confirm_s, cases=(), nominal_only=False, **calib):
    confirm = max(1, int(math.ceil(confirm_s * RATE)))
    res = {"nominal": [], "faults": {}}
    for day in DAYS:
        train = [k for k, v in data.items() if v[0] != day]
        table, _ = calibrate_recordings([data[k][1:] for k in train], alpha, RATE,
                                        margin=margin, names=train, **calib)
        for name in (k for k, v in data.items() if v[0] == day):
            _, ns, P = data[name]
            t = (ns - ns[0]) * 1e-9
            status, events, alarms = run_voter(table, ns, P, confirm, alarms=True)
            res["nominal"].append({"recording": name, "day": day, "decisions": int(len(status)),
                                   "below_sum3": float(np.mean(status > 0)) if len(status) else 0,
                                   "isolations": len(events), "cusum_alarms": alarms})
            if nominal_only or t[-1] < onset + 5.0:
                continue
            todo = [("gyro z stuck at zero", "stuck", 0, 0, "gyro_z"),
                     ("gyro z bias step 50 deg/h", "gyro_step", 50, 0, "gyro_z"),
                     ("accel x bias step 0.05 m/s^2", "accel_step", 0.05, 0, "accel_x"),
                     ("gyro z bias step 100 deg/h", "gyro_step", 100, 0, "gyro_z"),
                     ("gyro z bias step 200 deg/h", "gyro_step", 200, 0, "gyro_z"),
                     ("gyro z bias step 500 deg/h", "gyro_step", 500, 0, "gyro_z"),
                     ("gyro z bias step 2000 deg/h", "gyro_step", 2000, 0, "gyro_z"),
                     ("accel x bias step 0.2 m/s^2", "accel_step", 0.2, 0, "accel_x"),
                     ("accel x bias step 0.5 m/s^2", "accel_step", 0.5, 0, "accel_x")]
            todo += [(f"gyro z square {a:g} deg/h {f:g} Hz", "square", a, f, "gyro_z")
                      for a in (5, 10, 20, 50, 100) for f in (1, 5, 20)]
            for label, kind, amp, f, q in todo:
                if cases and not any(c in label for c in cases):
                    continue
                for imu in (2, 3):
                    _, ev = run_voter(table, ns, inject(P, t, kind, imu, onset, amp, f), confirm)
                    ok, dly = judge(ev, onset, imu, q)
                    res["faults"].setdefault(label, []).append({"recording": name, "imu": imu,
                                                                "detected": ok, "delay_s": dly})
    return res


def markdown(res) -> str:
    nom = res["nominal"]
    lines = ["| recording | day | decisions | below sum 3 | CUSUM pair alarms | isolations |",
             "|---|---|---:|---:|---:|---:|"]
    for r in nom:
        lines.append(f"| {r['recording']} | {r['day']} | {r['decisions']} | "
                     f"{100 * r['below_sum3']:.2f}% | {r['cusum_alarms']} | {r['isolations']} |")
    fa = sum(r["isolations"] > 0 for r in nom)
    worst = max(r["below_sum3"] for r in nom)
    allb = sum(r["below_sum3"] * r["decisions"] for r in nom) / sum(r["decisions"] for r in nom)
    lines += ["", f"Nominal: {fa} of {len(nom)} recordings with a false isolation; decisions "
              f"below sum 3: {100 * allb:.2f}% overall, worst recording {100 * worst:.2f}%; "
              f"{sum(r['cusum_alarms'] for r in nom)} CUSUM pair alarms in "
              f"{sum(r['decisions'] for r in nom) / RATE / 3600:.3f} h of decisions.", "",
              "| fault (IMU2 and IMU3, from the onset) | runs | detected, right IMU "
              "| median delay (s) |",
              "|---|---:|---:|---:|"]
    for label, rows in res["faults"].items():
        det = [r for r in rows if r["detected"]]
        med = f"{np.median([r['delay_s'] for r in det]):.2f}" if det else "-"
        lines.append(f"| {label} | {len(rows)} | {100 * len(det) / len(rows):.0f}% | {med} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2]
                                                   / "shared" / "data" / "mimu_quadrotor"))
    ap.add_argument("--alpha", type=float, default=0.002)
    ap.add_argument("--margin", type=float, default=3.0)
    ap.add_argument("--onset", type=float, default=10.0)
    ap.add_argument("--confirm-s", type=float, default=DEFAULT_CONFIRM_S)
    ap.add_argument("--baseline", choices=("learn", "grow"), default="learn")
    ap.add_argument("--no-linear", action="store_true",
                    help="calibrate without the per-pair linear model (core/voter_linear.py)")
    ap.add_argument("--offset-blocks", type=int, default=5, metavar="B",
                    help="offset = median of B block means of the learning window (1: mean)")
    ap.add_argument("--no-sequential", action="store_true",
                    help="without the CUSUM sequential detector (core/voter_sequential.py)")
    ap.add_argument("--seq-drift", default=SEQ_DRIFT, metavar="GYRO_DPH,ACCEL",
                    help=f"CUSUM drift nu: gyro in deg/h, accel in m/s^2, off: none on that "
                    f"sensor (default {SEQ_DRIFT})")
    ap.add_argument("--seq-margin", type=float, default=SEQ_MARGIN)
    ap.add_argument("--nominal-only", action="store_true", help="no fault runs")
    ap.add_argument("--cases", default="", help="comma-separated substrings of the fault "
                    "labels to run (default all)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    root = Path(a.data)
    if not root.is_dir():
        print(f"voter_real_eval: {root} is not a directory", file=sys.stderr)
        return 1
    res = evaluate(load(root), a.alpha, a.margin, a.onset, a.confirm_s,
                   cases=[c for c in a.cases.split(",") if c], baseline=a.baseline,
                   linear=not a.no_linear, offset_blocks=a.offset_blocks,
                   nominal_only=a.nominal_only, sequential=None if a.no_sequential
                   or a.baseline == "grow" else parse_drift(a.seq_drift),
                   sequential_margin=a.seq_margin)
    print(json.dumps(res, indent=1) if a.json else markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
