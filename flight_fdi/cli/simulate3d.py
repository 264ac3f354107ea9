"""``flight-fdi simulate --model ins3d``: the 3-D strapdown flight simulator's options and run."""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

EPILOG_3D = """\
--model ins3d (the 3-D strapdown simulator, docs/sim3d.md):
  faults: accel|gyro step|ramp|sine|square|stuck|scale on body axis x (forward), y (left),
        z (up); ref jump|outliers on ENU axis x (East), y (North), z (Up), ref dropout, and
        ref latency (mag in s or ms: the reference reports the velocity of mag seconds earlier)
  examples:
    flight-fdi simulate out/nominal --model ins3d --profile cruise_turns --grade navigation
    flight-fdi simulate out/ay --model ins3d --fault accel:step:t=600,mag=1mg,axis=y
    flight-fdi simulate out/lat --model ins3d --fault ref:latency:t=900,end=1200,mag=80ms
  topics: /ins/velocity (TwistStamped, ENU), /ins/imu (Imu: attitude, body rate, specific
  force), /ins/fix (NavSatFix), /reference/velocity (TwistWithCovarianceStamped, ENU),
  /reference/fix (NavSatFix), /sim/truth (FilterState 'truth3d'), /sim/fault (JSON); with
  --baro-topic T a height reference on T (FluidPressure by default: --baro-type)
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from flight_fdi.sim.imu3d import GRADES
    from flight_fdi.sim.ins3d import ALIGNMENTS, VERTICAL_MODES
    from flight_fdi.sim.trajectory import PROFILES

    g = p.add_argument_group("--model ins3d (3-D strapdown simulator)")
    g.add_argument("--profile", choices=PROFILES, default="cruise_turns",
                   help="trajectory (default cruise_turns: cruise with turns, climbs, speed "
                        "changes)")
    g.add_argument("--grade", default="navigation", metavar="GRADE|FILE.yaml",
                   help=f"IMU errors: a preset ({', '.join(GRADES)}; default navigation) or a "
                        "YAML grade file (docs/ins3d.md, 'IMU grade from a file'): its values")
    g.add_argument("--lat", type=float, default=45.0, metavar="DEG",
                   help="start latitude, |lat| <= 70 (default 45)")
    g.add_argument("--lon", type=float, default=7.0, metavar="DEG", help="start longitude")
    g.add_argument("--alt", type=float, default=3000.0, metavar="M",
                   help="start height above the WGS-84 ellipsoid (default 3000)")
    g.add_argument("--speed", type=float, default=None, metavar="M/S",
                   help="start speed, 50-250 (default: 200; survey_grid 80; random 150)")
    g.add_argument("--heading", type=float, default=0.0, metavar="DEG",
                   help="start heading from North, clockwise (default 0)")
    g.add_argument("--vertical", choices=VERTICAL_MODES, default="baro",
                   help="vertical channel: baro-aided loop (default), reference-damped (GNSS "
                        "height), or free")
    g.add_argument("--tau-vertical", type=float, default=100.0, metavar="S",
                   help="time constant of the vertical loop (default 100)")
    g.add_argument("--alignment", choices=ALIGNMENTS, default="consistent",
                   help="initial attitude error from the sensor errors (default) or none")
    g.add_argument("--quantize", action="store_true",
                   help="quantize the IMU increments (the grade's quanta)")
    g.add_argument("--velocity-rate", type=float, default=20.0, metavar="HZ",
                   help="/ins/velocity rate; divides --ins-rate (default 20)")
    g.add_argument("--imu-rate", type=float, default=20.0, metavar="HZ",
                   help="/ins/imu rate (mean rates over each interval); divides --ins-rate "
                        "(default 20)")
    g.add_argument("--fix-rate", type=float, default=5.0, metavar="HZ",
                   help="/ins/fix rate; divides --ins-rate (default 5)")
    g.add_argument("--gnss", action="append", default=[], metavar="NAME=VALUE",
                   help="GNSS reference parameter (repeatable): " + ", ".join(
                       f.name for f in _gnss_fields()))
    g.add_argument("--baro-topic", default=None, metavar="TOPIC",
                   help="also write a height reference on TOPIC (e.g. /reference/baro): a "
                        "second barometer, independent of the INS's (analyse it with analyze "
                        "--height-topic TOPIC; docs/sim3d.md)")
    g.add_argument("--baro-type", choices=tuple(BARO_TYPES), default=None,
                   help="the height topic's message: pressure (sensor_msgs/FluidPressure, the "
                        "ISA pressure; default), navsatfix (sensor_msgs/NavSatFix altitude) or "
                        "point (geometry_msgs/PointStamped z)")
    g.add_argument("--baro-rate", type=float, default=None, metavar="HZ",
                   help="the height topic's rate; divides --ins-rate (default 10)")
    g.add_argument("--baro", action="append", default=[], metavar="NAME=VALUE",
                   help="the height reference's errors (repeatable): bias, instability, tau_s, "
                        "white (m, s) and drift_mps (default 10 m turn-on offset, 0.3 m "
                        "Gauss-Markov over 20 s, 0.1 m white, 1 m/h drift)")


#: ``--baro-type``: the height topic's message type
BARO_TYPES = {"pressure": "sensor_msgs/msg/FluidPressure", "navsatfix": "sensor_msgs/msg/NavSatFix",
              "point": "geometry_msgs/msg/PointStamped"}


def _height_reference(args: argparse.Namespace):
    """The simulated height reference of ``--baro-topic`` and ``--baro`` (None without a
    topic; SimError for ``--baro*`` options without one or a bad value)."""
    from flight_fdi.sim.errors import SimError
    from flight_fdi.sim.gnss import HEIGHT_REFERENCE

    if args.baro_topic is None:
        given = [f for f, v in (("--baro-type", args.baro_type), ("--baro-rate", args.baro_rate),
                                ("--baro", args.baro)) if v]
        if given:
            raise SimError(f"{', '.join(given)} need{'s' if len(given) == 1 else ''} "
                           "--baro-topic")
        return None
    names = [f.name for f in dataclasses.fields(HEIGHT_REFERENCE)]
    return dataclasses.replace(HEIGHT_REFERENCE, **name_values(args.baro, "--baro", names))


def _gnss_fields():
    from flight_fdi.sim.gnss import GnssConfig

    return [f for f in dataclasses.fields(GnssConfig) if f.name != "rate_hz"]


def name_values(items: list[str], option: str, names: list[str]) -> dict[str, float]:
    """``NAME=VALUE`` items of a repeatable option as floats (SimError naming the bad one)."""
    from flight_fdi.sim.errors import SimError

    out: dict[str, float] = {}
    for item in items:
        name, sep, value = (s.strip() for s in item.partition("="))
        if not sep:
            raise SimError(f"{option} {item!r}: expected NAME=VALUE")
        if name not in names:
            raise SimError(f"{option} {item!r}: unknown parameter {name!r}; parameters are "
                           + ", ".join(names))
        try:
            out[name] = float(value)
        except ValueError:
            raise SimError(f"{option} {item!r}: {value!r} is not a number") from None
    return out


def _gnss(items: list[str], rate_hz: float):
    from flight_fdi.sim.gnss import GnssConfig

    values = name_values(items, "--gnss", [f.name for f in _gnss_fields()])
    return GnssConfig(rate_hz=rate_hz, **values)


def sim_grade(value: str):
    """``--grade``: the ImuGrade of a preset name or of a YAML grade file
    (``core.ins3d.grade_file.resolve_grade``); SimError (one line) otherwise."""
    from flight_fdi.core.errors import CoreError
    from flight_fdi.core.ins3d.grade_file import resolve_grade
    from flight_fdi.sim.errors import SimError

    try:
        return resolve_grade(value)
    except CoreError as exc:
        raise SimError(f"--grade: {exc}") from None


def run3d(args: argparse.Namespace) -> int:
    from flight_fdi.sim.bag3d import EPOCH_S, write_bag3d
    from flight_fdi.sim.errors import SimError
    from flight_fdi.sim.faults import FaultSpec3D, parse_fault
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    if args.channel is not None or args.param:
        raise SimError("--channel and --param belong to the single-axis model; --model ins3d "
                       "takes body-axis faults (axis=x|y|z) and --grade / --gnss")
    if args.speed is not None and not 50.0 <= args.speed <= 250.0:
        raise SimError(f"--speed must be within 50..250 m/s, got {args.speed:g}")
    if args.ref_rate is not None and not 1.0 <= args.ref_rate <= 10.0:
        raise SimError(f"--ref-rate must be within 1..10 Hz for ins3d, got {args.ref_rate:g}")
    rate = 100.0 if args.ins_rate is None else args.ins_rate
    if rate < 100.0:
        raise SimError(f"--ins-rate must be >= 100 Hz for ins3d, got {rate:g}")
    traj = TrajectoryConfig(profile=args.profile,
                            duration_s=3600.0 if args.duration is None else args.duration,
                            rate_hz=rate, lat_deg=args.lat, lon_deg=args.lon, alt_m=args.alt,
                            speed_mps=args.speed, heading_deg=args.heading, seed=args.seed)
    cfg = Sim3DConfig(trajectory=traj, grade=sim_grade(args.grade), quantize=args.quantize,
                      gnss=_gnss(args.gnss, 10.0 if args.ref_rate is None else args.ref_rate),
                      vertical=args.vertical, tau_vertical_s=args.tau_vertical,
                      alignment=args.alignment, seed=args.seed,
                      faults=tuple(parse_fault(s, FaultSpec3D) for s in args.fault),
                      height_reference=_height_reference(args))
    start = time.perf_counter()
    flight = simulate3d(cfg)
    counts = write_bag3d(flight, args.output, velocity_rate_hz=args.velocity_rate,
                         imu_rate_hz=args.imu_rate, fix_rate_hz=args.fix_rate,
                         truth_rate_hz=args.truth_rate,
                         epoch_s=EPOCH_S if args.epoch is None else args.epoch,
                         storage=args.storage, compression=args.compression,
                         overwrite=args.force, height_topic=args.baro_topic,
                         height_type=BARO_TYPES[args.baro_type or "pressure"],
                         height_rate_hz=10.0 if args.baro_rate is None else args.baro_rate)
    elapsed = time.perf_counter() - start
    size = sum(f.stat().st_size for f in Path(args.output).rglob("*") if f.is_file())
    dv = abs(flight.velocity_error()).max(axis=0)
    print(f"wrote {args.output}: ins3d {traj.profile}, {traj.duration_s:g} s at {rate:g} Hz, "
          f"{cfg.imu_grade.name} IMU, seed {cfg.seed}, "
          + ", ".join(f"{n} {t}" for t, n in counts.items()) + f"; {size / 1e6:.2f} MB, "
          f"{elapsed:.1f} s")
    print(f"INS velocity error max |E, N, U| = {dv[0]:.3g}, {dv[1]:.3g}, {dv[2]:.3g} m/s")
    print("faults: " + ("; ".join(f.describe("x") for f in cfg.faults) or "none (nominal flight)"))
    return 0
