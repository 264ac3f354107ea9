"""``flight-fdi imu-simulate OUTPUT``: three co-mounted IMUs with faults into a rosbag2 bag.

The IMUs fly the maneuvering profile of flight_fdi.sim.imu (take-off, climb, coordinated turns),
each with its own turn-on bias, scale-factor error and white noise, and pulse (quantized) outputs.
Topics: /imu1/data, /imu2/data, /imu3/data (sensor_msgs/Imu) and /sim/fault (std_msgs/String,
the JSON description of the flight and its faults).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from flight_fdi.cli.voter_calibrate import add_imu_options, imu_config

EPILOG = """\
IMU fault specification (--imu-fault, repeatable):
  IMU:QUANTITY:TYPE:key=value[,key=value...]
  IMU: imu1 | imu2 | imu3;  QUANTITY: gyro_x gyro_y gyro_z accel_x accel_y accel_z
  output faults:    zero (stuck at zero), full_scale (mag=+1/-1: the sign), doubled
  parameter faults: step (bias), scale (scale factor), ramp, sine, square (+-mag),
                    square_onoff (0 / mag)
  keys: t (start, s; required), end (s), mag (magnitude, units as --fault: deg/h, deg/s, mg,
        ug, ppm, % ...), freq (Hz, sine and square)
  examples:
    --imu-fault imu3:gyro_z:square:t=20,mag=20deg/h,freq=1
    --imu-fault imu2:gyro_x:zero:t=10
    --imu-fault imu1:accel_z:scale:t=5,mag=1000ppm
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("imu-simulate", help="simulate three co-mounted IMUs with faults into a "
                       "rosbag2 bag", description=__doc__, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("output", help="bag directory to create")
    p.add_argument("--imu-fault", action="append", default=[], metavar="SPEC",
                   help="inject a fault (repeatable; format below)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="rosbag2 storage (default mcap)")
    p.add_argument("--compression", choices=("zstd", "none"), default="zstd",
                   help="compression (default zstd)")
    p.add_argument("--force", action="store_true", help="overwrite an existing bag")
    add_imu_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from flight_fdi.sim.imu import parse_imu_fault, simulate_imus, write_imu_bag

    faults = [parse_imu_fault(s) for s in args.imu_fault]
    config = imu_config(args, faults)
    start = time.perf_counter()
    flight = simulate_imus(config)
    counts = write_imu_bag(flight, args.output, storage=args.storage,
                           compression=args.compression, overwrite=args.force)
    size = sum(f.stat().st_size for f in Path(args.output).rglob("*") if f.is_file())
    print(f"wrote {args.output}: {config.duration_s:g} s at {config.rate_hz:g} Hz, seed "
          f"{config.seed}, {sum(v for k, v in counts.items() if k != '/sim/fault')} IMU messages, "
          f"{size / 1e6:.2f} MB, {time.perf_counter() - start:.1f} s")
    print("faults: " + ("; ".join(f.describe() for f in faults) or "none (nominal flight)"))
    return 0
