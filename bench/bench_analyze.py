#!/usr/bin/env python3
"""Benchmark: the whole ``flight-fdi analyze`` of a 3-hour flight against just reading its bag
(a script, not a test).

INS at 50 Hz and reference at 10 Hz for 3 h: 540 000 + 108 000 messages (plus truth). The flight
is simulated once into ``--bag`` (default /tmp/flight_fdi_bench_3h) and reused; a copy whose
header stamps carry 1 ms of Gaussian jitter (every dt distinct) is written beside it. For both,
in the same run: the time of each stage, of just reading the bag (``read_flight``, a fresh
process), and of the whole command (a fresh process), as CPU time (the ratios) and wall time.
Targets: analyze <= 1.5x the read alone; jittered within 1.1x of regular. ``--jobs 2`` (the forked two-process analysis) is measured
against ``--jobs 1`` when the installed CLI still has the option.
"""
from __future__ import annotations

import argparse
import math
import os
import pathlib
import resource
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.bagio import read_flight  # noqa: E402
from flight_fdi.core.align import align_to_reference  # noqa: E402
from flight_fdi.core.analysis import AnalysisConfig, analyze_forward  # noqa: E402
from flight_fdi.core.diagnosis import diagnose  # noqa: E402
from flight_fdi.core.glr import isolate  # noqa: E402
from flight_fdi.core.kalman import run_forward  # noqa: E402
from flight_fdi.core.models import ins_channel  # noqa: E402
from flight_fdi.core.smoother import run_backward  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
CLI = ROOT / ".venv" / "bin" / "flight-fdi"
PY = ROOT / ".venv" / "bin" / "python"
STAMPED = ("/ins/velocity", "/reference/velocity")


def timed(label, fn, *a, **k):
    t0 = time.perf_counter()
    out = fn(*a, **k)
    dt = time.perf_counter() - t0
    print(f"    {label:<40}{dt:7.2f} s")
    return out, dt


def jittered_copy(src: pathlib.Path, dst: pathlib.Path, sigma_s: float, seed: int = 1) -> None:
    """``src`` with N(0, sigma) added to the header stamp of every INS and reference message
    (the stamp is the first field of the CDR payload: int32 sec, uint32 nanosec)."""
    from rosbags.highlevel import AnyReader

    from flight_fdi.bagio.writer import open_writer

    rng = np.random.default_rng(seed)
    with AnyReader([src]) as reader, open_writer(dst) as writer:
        for conn, t_ns, raw in reader.messages():
            data = bytearray(raw)
            if conn.topic in STAMPED:
                sec = int.from_bytes(data[4:8], "little", signed=True)
                ns = int.from_bytes(data[8:12], "little")
                stamp = sec * 1_000_000_000 + ns + int(round(rng.normal(0.0, sigma_s * 1e9)))
                data[4:8] = (stamp // 1_000_000_000).to_bytes(4, "little", signed=True)
                data[8:12] = (stamp % 1_000_000_000).to_bytes(4, "little")
            writer.write_raw(conn.topic, conn.msgtype, bytes(data), t_ns)


def fresh(cmd: list[str]) -> tuple[float, float]:
    """(wall, CPU) seconds of a fresh process (CPU: user + system of it and its children)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


#: a fresh ``flight-fdi analyze`` (the command line's own exit path) writing wall-clock marks
#: (time.perf_counter: CLOCK_MONOTONIC, one clock for every process) and each process's CPU
#: time to the file argv[3]; the wrapped functions are looked up where the CLI looks them up.
#: argv[4] undoes start-up and exit measures of session 8 one by one (``ABLATIONS``)
TIMELINE = r"""
import os, sys, time
P, T, FD, PARENT = time.perf_counter, time.process_time, None, os.getpid()
FD = os.open(sys.argv[3], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
def mark(label):
    who = "parent" if os.getpid() == PARENT else "child"
    os.write(FD, f"{who}\t{label}\t{P():.6f}\t{T():.6f}\n".encode())
mark("python ready")
def wrap(obj, name, before=None, after=None):
    fn = getattr(obj, name)
    def marked(*a, **k):
        if before: mark(before)
        try:
            return fn(*a, **k)
        finally:
            if after: mark(after)
    setattr(obj, name, marked)
import flight_fdi.cli.main as cli
mark("cli imported")
import flight_fdi.bagio as bagio
import flight_fdi.cli.analyze as analyze
import flight_fdi.core.forked as forked
mark("bagio imported")
read = bagio.read_flight
def marked_read(*a, **k):
    mark("read start")
    out = read(*a, **k)
    mark("read done")
    if os.getpid() != PARENT:  # the forked child: pickles, writes to the pipe, os._exit
        leave = os._exit
        def marked_exit(code):
            mark("result sent")
            leave(code)
        os._exit = marked_exit
    return out
bagio.read_flight = marked_read
wrap(forked.ForkedCall, "__init__", "fork")
imp = analyze.import_numba
UNDO = set(sys.argv[4].split(",")) - {""}
def marked_import():
    if "blas alone" in UNDO:
        import scipy.linalg
    imp()
    mark("numba imported")
    import numba.core.registry
    import flight_fdi.core.analysis as analysis, flight_fdi.core.warmup as warmup
    mark("core imported")
    ctx = numba.core.registry.cpu_target.target_context
    refresh = ctx.refresh
    def first_refresh():  # numba's target start-up, at the first kernel call
        ctx.refresh = refresh
        mark("numba target start")
        refresh()
        mark("numba target ready")
    ctx.refresh = first_refresh
    wrap(warmup, "preload", after="kernels loaded (preload)")
    wrap(analysis, "run_analysis", "analysis start", "analysis done")
analyze.import_numba = marked_import
wrap(forked, "_receive", "result wanted", "result received")
wrap(forked.ForkedCall, "__exit__", None, "child reaped")
wrap(analyze, "run", after="output written")
if "gc off" in UNDO:
    run = analyze.run
    def run_with_gc(args):
        import gc
        gc.enable()
        return run(args)
    analyze.run = run_with_gc
if "exit now" in UNDO:
    cli.exit_now = lambda code: None
sys.argv = ["flight-fdi", "analyze", sys.argv[1], "--json", "--jobs", sys.argv[2]]
sys.exit(cli.main())
"""


#: the start-up and exit measures of session 8 that ``--ablation`` undoes one at a time:
#: ``exit now`` (the interpreter's teardown runs), ``gc off`` (the cyclic GC runs),
#: ``blas alone`` (scipy.linalg imported, as numba's start-up did)
ABLATIONS = ("exit now", "gc off", "blas alone")


def timeline(bag: pathlib.Path, jobs: int, repeat: int,
             undo: tuple[str, ...] = ()) -> list[tuple[str, str, float, float]]:
    """The marks of the fastest of ``repeat`` fresh ``analyze --jobs N`` (by the end of the
    process as its launcher sees it): (process, label, wall s since the launch, CPU s of that
    process at the mark), the last one the launcher's "process ended" with the CPU time of the
    process and its child; ``undo``: measures of ``ABLATIONS`` to leave out."""
    import tempfile

    best: list = []
    for _ in range(repeat):
        with tempfile.NamedTemporaryFile("r", suffix=".marks") as f:
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run([str(PY), "-c", TIMELINE, str(bag), str(jobs), f.name,
                            ",".join(undo)], check=True, stdout=subprocess.DEVNULL)
            end = time.perf_counter() - t0
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            marks = [(who, label, float(w) - t0, float(c)) for who, label, w, c in
                     (ln.rstrip("\n").split("\t") for ln in f)]
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        marks.append(("launcher", "process ended", end, cpu))
        if not best or end < best[-1][2]:
            best = marks
    return best


def print_timeline(bag: pathlib.Path, jobs: int, repeat: int) -> None:
    marks = timeline(bag, jobs, repeat)
    print(f"  timeline of analyze --jobs {jobs} on {bag.name} (fastest of {repeat}; wall s since "
          f"the launch, CPU s of that process; load average {os.getloadavg()[0]:.1f}):")
    prev = 0.0
    for who, label, wall, cpu in marks:
        print(f"    {who:<9}{label:<28}{wall:7.3f} (+{wall - prev:.3f}){cpu:9.3f} CPU"
              + (" (whole run)" if who == "launcher" else ""))
        prev = wall


def critical_path(bag: pathlib.Path, repeat: int) -> dict:
    """Best CPU seconds of each side of ``--jobs 2`` over ``repeat`` fresh processes (from the
    timeline's marks): the parent until it needs the bag (``parent_before``), the forked read
    up to its result sent (``child``), the parent's wait for and reading of the result
    (``handover``, CPU), the analysis and output after it (``parent_after``; its wall time,
    ``after_wall``, is less on an idle machine: GLR runs beside the backward pass). On an idle
    two-core machine the wall time is about max(parent_before, child) + parent_after (+ the
    hand-over's wall time), against their sum in one process."""
    best: dict[str, float] = {}
    for _ in range(repeat):
        marks = timeline(bag, 2, 1)
        m = {(who, label): cpu for who, label, _, cpu in marks}
        w = {(who, label): wall for who, label, wall, _ in marks}
        best["after_wall"] = min(best.get("after_wall", np.inf), w[("parent", "output written")]
                                 - w[("parent", "result received")])
        cpu = {"prefork": m[("parent", "fork")],
               "parent_before": m[("parent", "result wanted")],
               "child": m[("child", "result sent")],
               "handover": m[("parent", "result received")] - m[("parent", "result wanted")],
               "parent_after": m[("parent", "output written")] - m[("parent", "result received")]}
        for k, v in cpu.items():
            best[k] = min(best.get(k, np.inf), v)
    return best


def stages(bag: pathlib.Path) -> None:
    model = ins_channel()
    config = AnalysisConfig()
    flight, _ = timed("read_flight", read_flight, bag, "x", with_truth=False)
    (valid, v_at), _ = timed("align", align_to_reference, flight.ins_rel_s, flight.v_ins,
                             flight.ref_rel_s, config.max_gap_s)
    z = (v_at - flight.v_ref)[valid][:, None]
    fwd, _ = timed(f"forward filter ({z.shape[0]} steps)", run_forward, model,
                   flight.ref_rel_s[valid], z, gate=config.gate)
    bwd, _ = timed("backward pass", run_backward, model, fwd)
    timed("seed statistics", diagnose, model, fwd, bwd)
    timed("GLR isolation", isolate, model, fwd)
    res, _ = timed("analyze_forward (all post-flight)", analyze_forward, model, fwd, config,
                   str(bag), "x", 0.0)
    s = res.summary["post_flight"]
    print(f"    verdict: {s['verdict']} {s['element']} onset {s['onset_s']}")


def print_ablation(bag: pathlib.Path, repeat: int) -> None:
    """``analyze --jobs 2`` and ``--jobs 1`` as they are and with each measure of ``ABLATIONS``
    undone, interleaved fresh processes, best of ``repeat``: wall, CPU (process and child), and
    the parent's CPU until it needs the bag (--jobs 2)."""
    variants = [()] + [(a,) for a in ABLATIONS] + [ABLATIONS]
    best: dict = {}
    for _ in range(repeat):
        for jobs in (2, 1):
            for undo in variants:
                m = {(who, label): (w, c) for who, label, w, c in timeline(bag, jobs, 1, undo)}
                got = (m[("launcher", "process ended")][0], m[("launcher", "process ended")][1],
                       m.get(("parent", "result wanted"), (0.0, math.nan))[1])
                old = best.get((jobs, undo), (np.inf,) * 3)
                best[(jobs, undo)] = tuple(min(a, b) for a, b in zip(old, got))
    print(f"  ablation on {bag.name} (best of {repeat}; load average {os.getloadavg()[0]:.1f}):")
    for (jobs, undo), (wall, cpu, start) in best.items():
        what = "as is" if not undo else "all undone" if len(undo) > 1 else f"without {undo[0]}"
        base = best[(jobs, ())]
        print(f"    --jobs {jobs} {what:<22} {wall:6.3f} s wall ({wall - base[0]:+.3f}), "
              f"{cpu:6.3f} s CPU ({cpu - base[1]:+.3f})"
              + (f"; parent before the bag {start:.3f} s CPU" if jobs == 2 else ""))


def print_critical_path(bag: pathlib.Path, repeat: int, read_cpu: float, read_wall: float) -> None:
    cp = critical_path(bag, repeat)
    pre, after_wall = cp["prefork"], cp.pop("after_wall")
    one = cp["parent_before"] + cp["child"] + cp["parent_after"]
    two = max(cp["parent_before"], pre + cp["child"]) + cp["handover"] + cp["parent_after"]
    print(f"  --jobs 2 critical path on {bag.name} (CPU s, best of {repeat}): parent before the "
          f"bag {cp['parent_before']:.3f} (of which before the fork {pre:.3f}), forked read "
          f"{cp['child']:.3f}, hand-over {cp['handover']:.3f}, parent after {cp['parent_after']:.3f} "
          f"(its wall {after_wall:.3f}, threads)"
          f": on an idle 2-core machine ~{two:.2f} s = {two / read_cpu:.2f}x the read's CPU, "
          f"{two / read_wall:.2f}x its wall (~{one:.2f} s in one process)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bag", default="/tmp/flight_fdi_bench_3h")
    ap.add_argument("--duration", type=float, default=10800.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ablation", action="store_true",
                    help="only fresh analyze processes with each start-up/exit measure undone")
    ap.add_argument("--timeline", action="store_true",
                    help="only the wall-clock timelines of fresh analyze processes (--jobs 2 and "
                         "1, both bags) and the --jobs 2 critical paths, against the read")
    args = ap.parse_args()
    bag = pathlib.Path(args.bag)
    jbag = bag.with_name(bag.name + "_jitter1ms")
    if not bag.exists():
        print(f"simulating a {args.duration:.0f}-s flight into {bag} ...")
        subprocess.run([str(CLI), "simulate", str(bag), "--duration", str(args.duration),
                        "--seed", "3", "--fault", "accel:step:t=5000,mag=0.01"], check=True)
    if not jbag.exists():
        print(f"writing {jbag} (1 ms Gaussian stamp jitter) ...")
        jittered_copy(bag, jbag, 1e-3)
    read_cmd = [str(PY), "-c", "import sys; from flight_fdi.bagio import read_flight; "
                "read_flight(sys.argv[1], 'x', with_truth=False)"]
    if args.ablation:
        print_ablation(bag, args.repeat)
        return 0
    if not args.timeline:
        for b in (bag, jbag):
            print(f"stages on {b.name}:")
            stages(b)
    print(f"fresh processes, best of {args.repeat} (load average {os.getloadavg()[0]:.1f}):")
    best: dict[tuple, tuple[float, float]] = {}
    for _ in range(args.repeat):  # interleaved: the machine's load changes between runs
        for b in (bag, jbag):
            runs = {"read": read_cmd + [str(b)]}
            if not args.timeline:
                analyze = [str(CLI), "analyze", str(b), "--json"]
                runs |= {"--jobs 1": analyze + ["--jobs", "1"], "--jobs 2": analyze + ["--jobs", "2"]}
            for what, cmd in runs.items():
                wall, cpu = fresh(cmd)
                old = best.get((b.name, what), (np.inf, np.inf))
                best[(b.name, what)] = (min(old[0], wall), min(old[1], cpu))
    for b in (bag, jbag):
        rw, rc = best[(b.name, "read")]
        print(f"  {b.name}: read {rc:.2f} s CPU, {rw:.2f} s wall")
        if args.timeline:
            continue
        for jobs in ("--jobs 1", "--jobs 2"):
            aw, ac = best[(b.name, jobs)]
            print(f"    analyze {jobs}: {ac:.2f} s CPU ({ac / rc:.2f}x the read's), {aw:.2f} s "
                  f"wall ({aw / rw:.2f}x the read's; target <= 1.5: "
                  f"{'met' if aw / rw <= 1.5 else 'NOT met'})")
    for b in (bag, jbag):
        print_critical_path(b, args.repeat, best[(b.name, "read")][1], best[(b.name, "read")][0])
    for b in (bag, jbag) if args.timeline else (bag,):
        for jobs in (2, 1) if args.timeline else (2,):
            print_timeline(b, jobs, args.repeat)
    if not args.timeline:
        ratio = best[(jbag.name, "--jobs 1")][1] / best[(bag.name, "--jobs 1")][1]
        print(f"  jittered / regular analyze --jobs 1 (CPU): {ratio:.2f} (target <= 1.1: "
              f"{'met' if ratio <= 1.1 else 'NOT met'})")
    print(f"  load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
