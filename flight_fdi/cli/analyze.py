"""``flight-fdi analyze BAG``: the whole post-flight analysis of an input bag, without a ROS graph.

Reads INS and reference velocity from the bag, runs the forward filter with its gate, the backward
information filter, the seed method (chi-square with UDU^T localization, Fisher test) and the GLR
isolator, and prints a short table, or with ``--json`` one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

from flight_fdi.cli.errors import CliError


def add_analysis_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``analyze``, ``run`` and ``report`` (one set of names for one
    configuration)."""
    add_input_options(p)
    p.add_argument("--model", default="ins_channel",
                   help="built-in model name or a model YAML file (default ins_channel); "
                        "ins3d: the 3-D INS error model on a 3-D contract bag (docs/ins3d.md)")
    add_gate_options(p)
    from flight_fdi.cli.ins3d import add_ins3d_options  # --model ins3d (cli/ins3d.py)

    add_ins3d_options(p)
    p.add_argument("--gate-action", default="flag", choices=("flag", "reject"),
                   help="fuse (flag) or drop (reject) a gated sample (default flag)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def add_input_options(p: argparse.ArgumentParser) -> None:
    """The input contract (flight_fdi.bagio.inputs): topics, channel, frames, profile."""
    g = p.add_argument_group("input (default: the sample bags' layout; see config/inputs/)")
    g.add_argument("--input-profile", metavar="FILE", default=None,
                   help="YAML input profile holding any of the settings below (the options "
                        "given here win)")
    g.add_argument("--ins-topic", default=None,
                   help="INS velocity topic (TwistStamped, TwistWithCovarianceStamped or "
                        "Odometry; default /ins/velocity)")
    g.add_argument("--reference-topic", action="append", default=None, metavar="TOPIC",
                   help="reference velocity topic (same types); repeat for redundant "
                        "references, merged by stamp (default /reference/velocity)")
    g.add_argument("--channel", default=None,
                   help="velocity axis: x, y or a direction of --nav-frame (east, north) "
                        "(default x)")
    g.add_argument("--nav-frame", default=None, choices=("enu", "ned"),
                   help="navigation frame of the twists: enu (REP 103: x east, y north) or ned "
                        "(x north, y east) (default enu)")
    g.add_argument("--odometry-twist-frame", default=None, choices=("child", "header"),
                   help="Odometry twist given in child_frame_id (REP 105; rotated into the "
                        "navigation frame by the pose orientation) or already in header.frame_id "
                        "(default child)")
    p.add_argument("--fail-on-fault", action="store_true",
                   help="exit status 3 when a fault was declared (verdict failure, glitch or "
                        "ambiguous); 0 otherwise, 1 on an error, 2 on a malformed command line")


def input_spec(args: argparse.Namespace):
    """InputSpec from the options and --input-profile."""
    from flight_fdi.bagio.inputs import make_spec

    return make_spec(getattr(args, "input_profile", None), ins_topic=args.ins_topic,
                     reference_topics=tuple(args.reference_topic) if args.reference_topic
                     else None, channel=args.channel, nav_frame=args.nav_frame,
                     odometry_twist_frame=getattr(args, "odometry_twist_frame", None))


#: exit status with --fail-on-fault when a fault was declared
EXIT_FAULT = 3
FAULT_VERDICTS = ("failure", "glitch", "ambiguous")


def exit_status(res: dict, args: argparse.Namespace) -> int:
    """0, or EXIT_FAULT with --fail-on-fault when the verdict declares a fault."""
    if getattr(args, "fail_on_fault", False) and \
            res["post_flight"]["verdict"] in FAULT_VERDICTS:
        return EXIT_FAULT
    return 0


def add_gate_options(p: argparse.ArgumentParser) -> None:
    """The in-flight gate and alarm options (read by :func:`analysis_config`)."""
    p.add_argument("--gate-rule", default="chi2", choices=("chi2", "seed"),
                   help="beta^2 gate: chi-square quantile or the seed's m + 3 sqrt(2m) "
                   "(default chi2)")
    p.add_argument("--gate-probability", type=float, default=1e-3,
                   help="per-sample false-alarm probability of the chi2 gate (default 1e-3)")
    p.add_argument("--alarm", default="3/5", metavar="M/N",
                   help="alarm when M of the last N samples exceed the gate (default 3/5)")


#: the gate options (dest, flag) of add_gate_options and --gate-action
GATE_OPTIONS = (("gate_rule", "--gate-rule"), ("gate_probability", "--gate-probability"),
                ("alarm", "--alarm"), ("gate_action", "--gate-action"))


def gate_defaults() -> dict:
    """The defaults of the gate options (GATE_OPTIONS), as the parser declares them."""
    probe = argparse.ArgumentParser(add_help=False)
    add_analysis_options(probe)
    return {d: probe.get_default(d) for d, _ in GATE_OPTIONS}


def gate_flags_given(args: argparse.Namespace) -> list[str]:
    """The gate options of ``args`` not at their defaults (they have defaults: a gate option
    given with its default value cannot be told from one not given)."""
    defaults = gate_defaults()
    return [flag for dest, flag in GATE_OPTIONS
            if getattr(args, dest, defaults[dest]) != defaults[dest]]


def analysis_config(args: argparse.Namespace):
    """AnalysisConfig from the shared options (validated by the core)."""
    from flight_fdi.core.analysis import AnalysisConfig
    from flight_fdi.core.kalman import GateConfig

    try:
        m_txt, n_txt = str(args.alarm).split("/")
        alarm_m, alarm_n = int(m_txt), int(n_txt)
    except ValueError:
        raise CliError(f"--alarm must look like M/N (e.g. 3/5), got {args.alarm!r}") from None
    gate = GateConfig(rule=args.gate_rule, probability=args.gate_probability,
                      alarm_m=alarm_m, alarm_n=alarm_n, action=args.gate_action)
    return AnalysisConfig(gate=gate, jobs=getattr(args, "jobs", 1))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="post-flight analysis of a bag without a ROS graph",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="rosbag2 bag (folder, .mcap or .db3) with an INS and a "
                               "reference velocity (see --ins-topic, --input-profile)")
    add_analysis_options(p)
    p.add_argument("--jobs", type=int, choices=(1, 2), default=default_jobs(),
                   help="processes to use: with 2 the bag is read in a forked child while "
                        "this process loads the estimation core and its compiled kernels, same "
                        "results; with --model ins3d the cores the 3-D analysis's threads may "
                        "run on (1: one core) (default 2 on a machine with 2 or more cores)")
    # on the command line: no cyclic GC, and the process ends once the result is printed
    # (cli.main.main, exit_now)
    p.set_defaults(func=run, short_lived=True)


def default_jobs() -> int:
    import os

    return 2 if (os.cpu_count() or 1) >= 2 else 1


def analyze_bag(bag: str, args: argparse.Namespace) -> dict:
    """The result of one bag (the summary with ``input`` per topic and ``source``)."""
    return analyse_flight_bag(bag, args)[0].summary


def analyse_flight_bag(bag: str, args: argparse.Namespace, with_truth: bool = False):
    """(AnalysisResult with the complete summary, FlightData) of one bag."""
    from flight_fdi.bagio import read_flight
    from flight_fdi.core.forked import ForkedCall

    spec = input_spec(args)
    # with two jobs the bag is read in a forked child while this process imports the estimation
    # core and loads its kernels (~0.5 s CPU, docs/performance.md); errors of either side come
    # out here, the child never outlives this (it is reaped at the end, once it has exited)
    with ForkedCall(read_flight, (bag,), {"spec": spec, "with_truth": with_truth},
                    fork=getattr(args, "jobs", 1) == 2) as job:
        import_numba()
        from flight_fdi.core.analysis import run_analysis
        from flight_fdi.core.models import get_model

        config = analysis_config(args)
        model = get_model(args.model)
        if job.forked:  # numba's start-up and the kernels' machine code, beside the read
            from flight_fdi.core.warmup import preload

            preload(model, config)
        flight = job.result()
        # times relative to the first INS/reference message, exact from integer nanoseconds
        res = run_analysis(model, flight.ins_rel_s, flight.v_ins, flight.ref_rel_s, flight.v_ref,
                           flight.r_ref, config, bag=str(bag), channel=spec.component, t0=0.0)
    complete_summary(res.summary, flight, res.aligned)
    return res, flight


def import_numba() -> None:
    """Import numba without its ``coverage`` hook: numba imports coverage (installed with
    pytest-cov) only to report compiled lines to a running coverage measurement, ~0.1 s of a
    fresh ``analyze``. Left alone when numba or coverage is already imported, or when a
    measurement of subprocesses is configured (COVERAGE_PROCESS_START). Also loads SciPy's
    BLAS module alone for numba's start-up (:func:`_load_cython_blas`)."""
    _load_cython_blas()
    if "numba" in sys.modules or "coverage" in sys.modules \
            or os.environ.get("COVERAGE_PROCESS_START"):
        return
    sys.modules["coverage"] = None  # type: ignore[assignment]  # import coverage: ImportError
    try:
        import numba  # noqa: F401
    finally:
        del sys.modules["coverage"]


def _load_cython_blas() -> None:
    """Load ``scipy.linalg.cython_blas`` (the BLAS entry points numba's compiled ``np.dot``
    calls) by itself, without the ``scipy.linalg`` package around it. numba's target start-up
    (``numba.np.arraymath``, at the first kernel call) checks that BLAS is there by importing
    that module, and ``import scipy.linalg.cython_blas`` runs the whole package first: ~0.15 s
    CPU of a fresh ``analyze`` (SciPy's array-API layer, mostly), none of whose functions the
    analysis calls. The module found already loaded, the check is free; numba's BLAS wrappers
    and SciPy's own Cython modules import it by that name too and get this same module. (A
    ``scipy.linalg`` imported later works as usual, except that the attribute
    ``scipy.linalg.cython_blas`` is missing: ``from scipy.linalg import cython_blas`` works.)
    Nothing is done when ``scipy.linalg`` is already imported or the module is not found where
    the package keeps it (numba's start-up then imports the package, as before)."""
    name = "scipy.linalg.cython_blas"
    if "scipy.linalg" in sys.modules or name in sys.modules:
        return
    import importlib.machinery
    import importlib.util

    try:
        import scipy
    except ImportError:
        return
    finder = importlib.machinery.FileFinder(
        os.path.join(scipy.__path__[0], "linalg"),
        (importlib.machinery.ExtensionFileLoader, importlib.machinery.EXTENSION_SUFFIXES))
    spec = finder.find_spec(name)
    if spec is None or spec.loader is None:
        return
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise


def complete_summary(summary: dict, flight, aligned) -> dict:
    """Put the bag's ``input`` (per topic, every drop reason) and ``source`` into a summary."""
    summary["input"] = flight.input_section(aligned)
    summary["source"] = flight.spec.describe()
    return summary


def _fmt(value, spec: str = ".3g", none: str = "-") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return none
    return format(value, spec)


def format_result(res: dict) -> str:
    """A short human-readable table of an analysis result."""
    inf = res["in_flight"]
    post = res["post_flight"]
    seed = post["seed_method"]
    glr = post["glr"]
    lines = _head_lines(res) + [
        "",
        f"in flight: gate beta2 > {inf['gate_threshold']:.3g}, exceeded on "
        f"{100 * inf['exceed_fraction']:.2f}% of samples; first alarm at "
        f"{_fmt(inf['first_alarm_s'], '.1f')} s; {len(inf['alarms'])} alarm(s)",
    ]
    for a in inf["alarms"][:5]:
        lines.append(f"  alarm {a['start_s']:9.1f} .. {a['end_s']:9.1f} s  peak beta2 "
                     f"{a['peak_beta2']:.3g}")
    if len(inf["alarms"]) > 5:
        lines.append(f"  ... {len(inf['alarms']) - 5} more")
    lines += [
        "",
        f"post flight: {post['verdict'].upper()}  isolation {post.get('isolation', '-')}  "
        f"element {_fmt(post['element'], 's')}  onset {_fmt(post['onset_s'], '.1f')} s",
    ]
    for fault in ([post["fault"]] if post.get("fault") else []) + post.get("candidates", []):
        lines.append(_fault_line(fault))
    if post.get("disagreement"):
        lines.append(f"  methods disagree: {post['disagreement']}")
    lines += [
        "",
        f"seed method (chi2/UDU^T + Fisher): {seed['verdict']}, element "
        f"{_fmt(seed['element'], 's')}",
        f"  {'element':<16}{'J peak':>10}{'gamma2':>9}{'F peak':>10}{'eta2':>8}"
        f"{'exceed':>9}{'dof':>5}",
    ]
    for e in seed["elements"]:
        lines.append(f"  {e['name']:<16}{_fmt(e['J_peak']):>10}{_fmt(e['gamma2']):>9}"
                     f"{_fmt(e['F_peak']):>10}{_fmt(e['eta2']):>8}"
                     f"{100 * e['exceed_fraction']:>8.1f}%{e['dof']:>5}")
    lines += [
        f"GLR: {glr['hypothesis']}  onset {_fmt(glr['onset_s'], '.1f')} s  magnitude "
        f"{_fmt(glr['magnitude'], '.4g')}  statistic {glr['statistic']:.4g} "
        f"(threshold {glr['threshold']:.4g})",
    ]
    return "\n".join(lines)


def _head_lines(res: dict) -> list[str]:
    """Verdict headline, the flight, the inputs and one warning per drop reason."""
    from flight_fdi.bagio.inputs import warnings

    post = res["post_flight"]
    lines = [f"{post['verdict'].upper()}: {post.get('headline', '')}", "",
             f"bag {res['bag']}  channel {res['channel']}  {res['duration_s']:.1f} s  "
             f"{res['samples']} samples"]
    src = res.get("source")
    if src:
        lines.append(f"input: INS {src['ins_topic']}, reference "
                     f"{', '.join(src['reference_topics'])}, {src['nav_frame'].upper()} axis "
                     f"{src['channel']} ({src['axis_name']})")
    return lines + warnings(res.get("input") or {})


def _fault_line(fault: dict) -> str:
    """One fault (or candidate) with both units, its 1-sigma, onset interval and statistics."""
    runner = fault.get("runner_up")
    return (f"  {fault['sensor']} {fault['axis']} {fault['kind']}: "
            f"{_fmt(fault['magnitude_eng'], '+.4g')} {fault['unit_eng']} "
            f"({_fmt(fault['magnitude'], '+.4g')} {fault['unit']}, 1-sigma "
            f"{_fmt(fault['magnitude_std'], '.2g')}), onset 95 % "
            f"{_interval(fault['onset_interval_s'])} s; statistic {fault['statistic']:.4g} vs "
            f"threshold {_fmt(fault['threshold'], '.4g')}"
            + (f", runner-up {runner['hypothesis']} {runner['statistic']:.4g}" if runner else ""))


def _interval(iv) -> str:
    return "-" if not iv or iv[0] is None else f"{iv[0]:.1f} .. {iv[1]:.1f}"


def run(args: argparse.Namespace) -> int:
    from flight_fdi.cli import ins3d

    if ins3d.is_ins3d(args):
        return ins3d.run_analyze(args)
    res = analyze_bag(args.bag, args)
    if args.json:
        json.dump(res, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(format_result(res))
    return exit_status(res, args)
