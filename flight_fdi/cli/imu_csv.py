"""``flight-fdi imu-csv OUTPUT CSV1 CSV2 CSV3``: IMU CSV logs -> a bag for the voter.

Each CSV (plain or .gz) is one IMU, with a header row naming at least ``time`` (s),
``Acc_X, Acc_Y, Acc_Z`` (m/s^2, specific force) and ``Gyr_X, Gyr_Y, Gyr_Z`` (deg/s) -- the layout of
Xsens DOT exports and of ../shared/data/mimu_quadrotor (other columns are ignored). The bag holds
sensor_msgs/Imu on /imu1/data, /imu2/data, /imu3/data (frame imu1..imu3, rates in rad/s,
covariances unknown: 0, orientation not provided: orientation_covariance[0] = -1); header stamp =
receive time = ``--epoch`` + time. A directory instead of three files takes its IMU_1, IMU_2,
IMU_3 .csv / .csv.gz (``--units`` picks others, e.g. 1,2,4).

Rows whose time does not increase are kept (the voter drops and counts them) and reported.
"""
from __future__ import annotations

import argparse
import gzip
import io
import json
import math
from pathlib import Path

import numpy as np

COLUMNS = ("time", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("imu-csv", help="three IMU CSV logs (time, Acc_*, Gyr_*) to a bag of "
                       "sensor_msgs/Imu for the voter", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("output", help="bag to write (directory)")
    p.add_argument("inputs", nargs="+", metavar="CSV",
                   help="three CSV files (IMU1, IMU2, IMU3) or one directory of IMU_k.csv[.gz]")
    p.add_argument("--units", default="1,2,3", metavar="K,K,K",
                   help="with a directory: which IMU_k files become IMU1..IMU3 (default 1,2,3)")
    p.add_argument("--epoch", type=float, default=1.7e9, metavar="S",
                   help="stamp of time 0 in seconds since 1970 (default 1.7e9)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def read_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(time (T,) s, values (T, 6) gyro x/y/z rad/s, accel x/y/z m/s^2); CliError on problems."""
    from flight_fdi.cli.errors import CliError

    try:
        raw = path.read_bytes()
        text = gzip.decompress(raw).decode() if raw[:2] == b"\x1f\x8b" else raw.decode()
    except FileNotFoundError:
        raise CliError(f"{path}: file not found") from None
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise CliError(f"{path}: cannot read ({exc})") from None
    header = [h.strip() for h in text.split("\n", 1)[0].split(",")]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise CliError(f"{path}: no column {', '.join(missing)} (header: {', '.join(header)})")
    cols = [header.index(c) for c in COLUMNS]
    try:
        data = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, usecols=cols, ndmin=2)
    except ValueError as exc:
        raise CliError(f"{path}: not a numeric CSV ({str(exc).splitlines()[0]})") from None
    if data.shape[0] < 2:
        raise CliError(f"{path}: fewer than 2 rows")
    if not np.all(np.isfinite(data[:, 0])):
        raise CliError(f"{path}: a time is not a number")
    values = np.column_stack([np.radians(data[:, 4:7]), data[:, 1:4]])
    return data[:, 0], values


def _inputs(args: argparse.Namespace) -> list[Path]:
    from flight_fdi.cli.errors import CliError

    if len(args.inputs) == 3:
        return [Path(p) for p in args.inputs]
    if len(args.inputs) == 1 and Path(args.inputs[0]).is_dir():
        d = Path(args.inputs[0])
        try:
            units = [int(u) for u in args.units.split(",")]
        except ValueError:
            raise CliError(f"--units: {args.units!r} is not three integers") from None
        if len(units) != 3:
            raise CliError(f"--units: give three units, got {args.units!r}")
        out = []
        for u in units:
            found = [d / f"IMU_{u}.csv", d / f"IMU_{u}.csv.gz"]
            hit = [f for f in found if f.exists()]
            if not hit:
                raise CliError(f"{d}: no IMU_{u}.csv or IMU_{u}.csv.gz")
            out.append(hit[0])
        return out
    raise CliError("give three CSV files (IMU1, IMU2, IMU3) or one directory")


def run(args: argparse.Namespace) -> int:
    from flight_fdi.bagio.writer import open_writer
    from flight_fdi.cli.errors import CliError
    from flight_fdi.sim.imu import IMU_MSG, IMU_TOPICS, encode_imu

    out = Path(args.output)
    if out.exists() and not args.force:
        raise CliError(f"{out} exists already (use --force to overwrite)")
    if not (math.isfinite(args.epoch) and 0 <= args.epoch < 2**31 - 10**6):
        raise CliError(f"--epoch must be seconds in [0, 2^31), got {args.epoch!r}")
    paths = _inputs(args)
    series, summary = [], {"output": str(out), "topics": {}}
    for k, (path, topic) in enumerate(zip(paths, IMU_TOPICS)):
        t, v = read_csv(path)
        stamp = np.round((args.epoch + t) * 1e9).astype(np.int64)
        payloads = encode_imu(stamp, v, f"imu{k + 1}", np.zeros(6))
        series.append((topic, IMU_MSG, stamp, payloads))
        summary["topics"][topic] = {"csv": str(path), "messages": int(t.size),
                                    "duration_s": round(float(t[-1] - t[0]), 3),
                                    "non_increasing_times": int(np.sum(np.diff(t) <= 0))}
    with open_writer(out, storage=args.storage, overwrite=args.force) as bag:
        bag.write_series(series)
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    for topic, s in summary["topics"].items():
        extra = (f"; {s['non_increasing_times']} non-increasing times (kept)"
                 if s["non_increasing_times"] else "")
        print(f"{topic}: {s['messages']} messages, {s['duration_s']:g} s from {s['csv']}{extra}")
    print(f"wrote {out}")
    return 0
