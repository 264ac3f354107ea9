#!/usr/bin/env python3
"""Benchmark: reading a 3-D contract bag (a script, not a test).

For each bag (default: the bundled bags/ins3d_*, 1800 s each: /ins/imu and /ins/velocity at
20 Hz, /ins/fix at 5 Hz, /reference/velocity at 10 Hz = 99 000 contract messages), in the same
run: the contract topics decoded as whole series by the one CDR codec
(``bagio.ins3d_series.read_series``, what ``read_ins3d`` uses) against rosbags' per-message
decode (``read_series_messages``, what ``read_ins3d`` did before), both to the same arrays (bit
for bit, checked here too), and the whole ``read_ins3d`` (decode + steps + reference rows +
description). Best of ``--repeat`` runs of each, wall and CPU time; the ratio is per-message /
series (CPU).

``--recording DIR`` (a run folder's ``recording``, e.g. of ``flight-fdi run --model ins3d
bags/ins3d_gyro_x_step --out OUT``): also the ins3d recording read (``read_recording3d``: the
FilterStates as columns) against the raw read of its two topics alone (``read_topics_raw``),
CPU ratio recording read / raw read.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.bagio.ins3d_input import TOPICS, read_ins3d  # noqa: E402
from flight_fdi.bagio.ins3d_series import read_series, read_series_messages  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


def best(fn, repeat: int) -> tuple[float, float, object]:
    """(best wall s, best CPU s, the last result) of ``repeat`` calls."""
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus), out


def same(a: dict, b: dict) -> bool:
    return all(x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
               for role in a for x, y in zip(a[role], b[role]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bags", nargs="*", type=pathlib.Path,
                    default=sorted((ROOT / "bags").glob("ins3d_*")))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--recording", type=pathlib.Path, action="append", default=[])
    args = ap.parse_args(argv)
    print(f"{'bag':<22}{'messages':>9}  {'series s':>14}  {'per-message s':>14}  "
          f"{'ratio':>6}  {'read_ins3d s':>13}  same")
    for bag in args.bags:
        fw, fc, fast = best(lambda: read_series(bag, TOPICS), args.repeat)
        sw, sc, slow = best(lambda: read_series_messages(bag, TOPICS), args.repeat)
        rw, rc, _ = best(lambda: read_ins3d(bag), args.repeat)
        n = sum(v[0].size for v in fast.values())
        print(f"{bag.name:<22}{n:>9}  {fw:6.3f} ({fc:5.3f})  {sw:6.3f} ({sc:5.3f})  "
              f"{sc / fc:6.1f}  {rw:5.3f} ({rc:5.3f})  {same(fast, slow)}")
    print("(wall (CPU) s, best of", args.repeat, "runs; ratio: per-message CPU / series CPU)")
    for rec in args.recording:
        recordings(rec, args.repeat)
    return 0


def recordings(rec: pathlib.Path, repeat: int) -> None:
    """The ins3d recording read against the raw read of its topics (one line)."""
    from flight_fdi.bagio.reader import read_topics_raw
    from flight_fdi.bagio.recording3d import read_recording3d

    topics = ["/fdi/model", "/fdi/state"]
    read_recording3d(rec)  # imports warmed
    bw, bc, raw = best(lambda: read_topics_raw(rec, topics), repeat)
    rw, rc, _ = best(lambda: read_recording3d(rec), repeat)
    n = sum(len(raw[t].payloads) for t in topics)
    print(f"recording {rec}: {n} messages, raw read {bw:.3f} ({bc:.3f}) s, read_recording3d "
          f"{rw:.3f} ({rc:.3f}) s, ratio {rc / bc:.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
