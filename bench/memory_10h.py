"""Peak memory of ``flight-fdi analyze`` on a 10-hour flight.

    .venv/bin/python bench/memory_10h.py [--duration 36000] [--ins-rate 50] [--ref-rate 10]
                                         [--bag DIR] [--keep] [--limit-mb 1024] [--json]

1. ``flight-fdi simulate DIR --duration 36000`` (10 hours; INS 50 Hz, reference 10 Hz: 1.8
   million INS and 360 000 reference messages; an accelerometer bias step of 1.5 mg after 5
   hours, so that the isolation has work to do) into a temporary directory, unless ``--bag``
   names an existing bag.
2. ``flight-fdi analyze DIR --json`` as a user runs it (the installed command of this venv), in a
   child process; its peak resident set size is ``ru_maxrss`` of ``RUSAGE_CHILDREN`` measured by
   an intermediate process that starts nothing else (so the simulation's own peak is not
   mixed in).

Prints both peaks, the analysis's wall time and the verdict (analyze peak < ``--limit-mb``);
exit 0 when it passes. The bag (about 0.2 GB with zstd) is deleted unless ``--keep``.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

VENV_BIN = Path(sys.executable).parent

#: measures one command in a fresh process: prints "<peak kB> <exit status> <wall s>"
_MEASURE = """
import resource, subprocess, sys, time
t = time.perf_counter()
code = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode
wall = time.perf_counter() - t
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, code, wall)
"""


def measure(cmd: list[str]) -> tuple[float, int, float]:
    """(peak RSS [MB], exit status, wall time [s]) of ``cmd`` run as a child process."""
    out = subprocess.run([sys.executable, "-c", _MEASURE, *cmd], capture_output=True, text=True,
                         check=True).stdout.split()
    return int(out[0]) / 1024.0, int(out[1]), float(out[2])


def flight_fdi() -> str:
    exe = VENV_BIN / "flight-fdi"
    return str(exe) if exe.exists() else "flight-fdi"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=36000.0, help="flight seconds (10 h)")
    ap.add_argument("--ins-rate", type=float, default=50.0)
    ap.add_argument("--ref-rate", type=float, default=10.0)
    ap.add_argument("--bag", help="analyse this existing bag instead of simulating one")
    ap.add_argument("--keep", action="store_true", help="keep the simulated bag")
    ap.add_argument("--limit-mb", type=float, default=1024.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    result: dict = {"limit_mb": args.limit_mb}
    tmp = None
    if args.bag:
        bag = Path(args.bag)
    else:
        tmp = Path(tempfile.mkdtemp(prefix="fdi_10h_"))
        bag = tmp / "flight_10h"
        onset = args.duration / 2
        cmd = [flight_fdi(), "simulate", str(bag), "--duration", f"{args.duration:g}",
               "--ins-rate", f"{args.ins_rate:g}", "--ref-rate", f"{args.ref_rate:g}",
               "--fault", f"accel:step:t={onset:g},mag=0.015"]
        print("simulating:", " ".join(cmd[1:]), flush=True)
        peak, code, wall = measure(cmd)
        if code != 0:
            print(f"simulate failed (exit {code})")
            return 1
        result["simulate"] = {"peak_rss_mb": round(peak, 1), "wall_s": round(wall, 1)}
        print(f"simulate: {wall:.0f} s, peak RSS {peak:.0f} MB", flush=True)
    try:
        size = sum(f.stat().st_size for f in bag.iterdir()) / 2**20
        result["bag"] = {"path": str(bag), "size_mb": round(size, 1),
                         "duration_s": args.duration, "ins_rate_hz": args.ins_rate,
                         "ref_rate_hz": args.ref_rate}
        cmd = [flight_fdi(), "analyze", str(bag), "--json"]
        print("measuring:", " ".join(cmd[1:]), flush=True)
        peak, code, wall = measure(cmd)
        result["analyze"] = {"peak_rss_mb": round(peak, 1), "wall_s": round(wall, 1),
                             "exit_status": code}
        ok = code == 0 and peak < args.limit_mb
        result["passed"] = ok
        print(f"analyze: exit {code}, {wall:.1f} s, peak RSS {peak:.0f} MB "
              f"(limit {args.limit_mb:.0f} MB) -> {'PASS' if ok else 'FAIL'}")
        if args.json:
            print(json.dumps(result, indent=1))
        return 0 if ok else 1
    finally:
        if tmp is not None and not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp is not None:
            print(f"bag kept: {bag}")


if __name__ == "__main__":
    t0 = time.perf_counter()
    status = main()
    print(f"({time.perf_counter() - t0:.0f} s in all)")
    sys.exit(status)
