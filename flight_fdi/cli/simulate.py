"""``flight-fdi simulate``: simulate a flight with injected faults and write it as a rosbag2 bag."""
from __future__ import annotations

import argparse
import inspect
import time
from pathlib import Path

EPILOG = """\
fault specification (--fault, repeatable):
  TARGET:TYPE:key=value[,key=value...]
  targets and types:
    accel, gyro   step | ramp | sine | square | stuck | scale
    ref           jump | outliers | dropout
  keys: t (start, s; required), end (s; default: the end of the flight), mag (magnitude),
        freq (Hz for sine/square; outliers per second), axis (x|y; default --channel)
  magnitude: step/sine/square amplitude, ramp rate per second, stuck output value, scale-factor
        change (1 = doubled output); SI units by default, or a suffix:
        accel m/s^2, mg, ug;  gyro rad/s, deg/h, deg/s;  ref m/s;  scale ppm, %
  examples:
    --fault accel:step:t=500,mag=0.015          accelerometer bias step (1.5 mg) at 500 s
    --fault gyro:step:t=500,mag=10deg/h         gyro drift step of 10 deg/h at 500 s
    --fault gyro:square:t=20,mag=20deg/h,freq=1 square-wave gyro drift (seed 002)
    --fault accel:stuck:t=300,mag=0             accelerometer output stuck at zero
    --fault ref:outliers:t=100,end=900,mag=3,freq=0.05
    --fault ref:dropout:t=300,end=330           no reference messages for 30 s

topics written: /ins/velocity (geometry_msgs/TwistStamped, x and y channels),
  /reference/velocity (geometry_msgs/TwistWithCovarianceStamped, R on the covariance diagonal),
  /sim/truth (flight_fdi_msgs/FilterState, true error state per channel),
  /sim/fault (std_msgs/String, JSON description of the flight and its faults, transient local).
"""


def _epilog() -> str:
    from flight_fdi.cli.simulate3d import EPILOG_3D

    return EPILOG + "\n" + EPILOG_3D


def _model_param_names() -> list[str]:
    from flight_fdi.core.models import ins_channel

    return list(inspect.signature(ins_channel).parameters)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a flight (INS error model + faults) into a rosbag2 bag",
        description=("Simulate a flight with the single-channel INS error model of seed 000 on "
                     "two horizontal channels (default), or with the 3-D strapdown simulator "
                     "(--model ins3d), inject faults, and write a rosbag2 bag."),
        epilog=_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("output", help="bag directory to create")
    p.add_argument("--model", choices=("channel", "ins3d"), default="channel",
                   help="channel: the seed-000 INS error model (default); ins3d: the 3-D "
                        "strapdown simulator")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="flight duration in seconds (default 1000; ins3d 3600)")
    p.add_argument("--ins-rate", type=float, default=None, metavar="HZ",
                   help="INS velocity rate (default 50); ins3d: the mechanization rate "
                        "(default 100)")
    p.add_argument("--ref-rate", type=float, default=None, metavar="HZ",
                   help="reference velocity rate; must divide the INS rate (default 10)")
    p.add_argument("--truth-rate", type=float, default=1.0, metavar="HZ",
                   help="rate of the /sim/truth messages; must divide the INS rate (default 1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--channel", choices=("x", "y"), default=None,
                   help="axis the faults act on unless they name one (default x)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="inject a fault (repeatable; format below)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help=("override a parameter of the INS error model (repeatable): "
                         + ", ".join(_model_param_names())))
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="rosbag2 storage (default mcap, as ROS 2 Jazzy)")
    p.add_argument("--compression", choices=("zstd", "none"), default="zstd",
                   help="zstd: mcap chunk compression / sqlite3 per-message (default zstd)")
    p.add_argument("--epoch", type=int, default=None, metavar="S",
                   help="Unix time of the first message (default 1700000000)")
    p.add_argument("--force", action="store_true", help="overwrite an existing bag")
    from flight_fdi.cli.simulate3d import add_arguments

    add_arguments(p)
    p.set_defaults(func=run)


def _params(items: list[str]) -> dict[str, float]:
    from flight_fdi.cli.simulate3d import name_values

    return name_values(items, "--param", _model_param_names())


def _check_channel_options(args: argparse.Namespace) -> None:
    """The ins3d options are refused by the single-axis model (unless left at their defaults)."""
    from flight_fdi.sim.errors import SimError

    probe = argparse.ArgumentParser(add_help=False)
    from flight_fdi.cli.simulate3d import add_arguments

    add_arguments(probe)
    changed = [a.option_strings[0] for a in probe._actions
               if getattr(args, a.dest) != a.default]
    if changed:
        raise SimError(f"{', '.join(changed)} apply to --model ins3d only")


def run(args: argparse.Namespace) -> int:
    if args.model == "ins3d":
        from flight_fdi.cli.simulate3d import run3d

        return run3d(args)
    from flight_fdi.sim import SimConfig, parse_fault, simulate, write_bag
    from flight_fdi.sim.ins import EPOCH_S

    _check_channel_options(args)
    args.duration = 1000.0 if args.duration is None else args.duration
    args.ins_rate = 50.0 if args.ins_rate is None else args.ins_rate
    args.ref_rate = 10.0 if args.ref_rate is None else args.ref_rate
    args.channel = "x" if args.channel is None else args.channel
    faults = tuple(parse_fault(s) for s in args.fault)
    config = SimConfig(duration_s=args.duration, ins_rate_hz=args.ins_rate,
                       ref_rate_hz=args.ref_rate, truth_rate_hz=args.truth_rate, seed=args.seed,
                       channel=args.channel, faults=faults, model_params=_params(args.param),
                       epoch_s=EPOCH_S if args.epoch is None else args.epoch)
    start = time.perf_counter()
    flight = simulate(config)
    counts = write_bag(flight, args.output, storage=args.storage, compression=args.compression,
                       overwrite=args.force)
    elapsed = time.perf_counter() - start
    size = sum(f.stat().st_size for f in Path(args.output).rglob("*") if f.is_file())
    what = "; ".join(f.describe(config.channel) for f in faults) or "none (nominal flight)"
    print(f"wrote {args.output}: {config.duration_s:g} s flight, seed {config.seed}, "
          f"{counts.get('/ins/velocity', 0)} INS + {counts.get('/reference/velocity', 0)} "
          f"reference + {counts.get('/sim/truth', 0)} truth messages, "
          f"{size / 1e6:.2f} MB, {elapsed:.1f} s")
    print(f"faults: {what}")
    return 0

