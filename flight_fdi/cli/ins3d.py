"""``--model ins3d`` for ``flight-fdi analyze``, ``run`` and ``report``: the 3-D INS error model
(docs/ins3d.md) on a bag of the 3-D contract (/ins/imu, /ins/velocity, /ins/fix,
/reference/velocity; docs/sim3d.md).

``analyze`` reads the bag (``bagio.ins3d_input``) and runs ``core.ins3d.analysis.analyze_ins3d``;
``run`` (``cli.run.run3d``) replays the bag through the node pipeline with ``filter_node`` in its
ins3d mode and the smoother analysing the recording (the same verdict); ``report`` draws the
per-axis figures (``report.figures3d``; cli/ins3d_report.py). The result is the v1 result JSON
with ``"model": "ins3d"`` (``core.ins3d_result``). The error-model options (``--vertical``, ``--latency``,
``--reference-markov``, ``--initial-attitude``) win over the bag description's ``error_model``
block key by key; ``source`` records the block used and the keys they gave.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from contextlib import contextmanager
from pathlib import Path

from flight_fdi.cli.analyze import exit_status, gate_defaults
from flight_fdi.cli.errors import CliError
from flight_fdi.cli.ins3d_height import (HEIGHT_OPTIONS, add_height_options,
                                         height_args_of_source, height_line, height_spec)

#: the single-axis input options that mean nothing to the 3-D model
SINGLE_AXIS_ONLY = (("channel", "--channel"), ("nav_frame", "--nav-frame"),
                    ("odometry_twist_frame", "--odometry-twist-frame"),
                    ("input_profile", "--input-profile"))


#: the grade presets the CLI offers (core/ins3d/grades.py; "perfect" is for tests)
PRESETS = ("navigation", "tactical", "mems")
#: the error-model options: the ``error_model`` key each sets (its dest) and its flag
ERROR_MODEL_OPTIONS = (("vertical", "--vertical"), ("latency", "--latency/--no-latency"),
                       ("reference_markov", "--reference-markov"),
                       ("initial_attitude", "--initial-attitude"))
#: the options that apply only to --model ins3d (dest, flag)
INS3D_ONLY = (("grade", "--grade"), ("rows", "--rows"), ("imu_topic", "--imu-topic"),
              ("fix_topic", "--fix-topic")) + ERROR_MODEL_OPTIONS + HEIGHT_OPTIONS


def add_ins3d_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("3-D model (--model ins3d; docs/ins3d.md)")
    g.add_argument("--grade", default=None, metavar="GRADE|FILE.yaml",
                   help=f"IMU grade of the bias models: a preset ({', '.join(PRESETS)}; default "
                        "navigation) or a YAML grade file (docs/ins3d.md, 'IMU grade from a "
                        "file'; e.g. config/grades/example_mems_custom.yaml)")
    g.add_argument("--rows", type=int, default=None, choices=(2, 3),
                   help="reference rows: 2 (east, north) or 3 (with up, or with "
                        "--height-topic the height) (default 3: the vertical row sees the INS "
                        "height loop's response to a vertical accelerometer error)")
    g.add_argument("--imu-topic", default=None,
                   help="INS attitude and IMU means, sensor_msgs/Imu (default /ins/imu)")
    g.add_argument("--fix-topic", default=None,
                   help="INS latitude and height, sensor_msgs/NavSatFix (default /ins/fix)")
    add_error_model_options(p)
    add_height_options(p)


def add_error_model_options(p: argparse.ArgumentParser) -> None:
    """The error-model options: each sets one key of the bag description's ``error_model``
    block (docs/ins3d.md, "The contract description"), checked as the bag's block is."""
    g = p.add_argument_group(
        "3-D error model (--model ins3d; each option wins over the same key of the bag's "
        "error_model block, which wins over the defaults; docs/ins3d.md)")
    g.add_argument("--vertical", default=None, metavar="{damped,free,loop}",
                   help="the error model's vertical channel: loop (the INS's baro height loop), "
                        "damped (another height loop: dv_U a Markov state of its own) or free "
                        "(a free-inertial INS on a short flight) (default: the bag's block, else "
                        "as without one: docs/ins3d.md, 'The contract description')")
    g.add_argument("--latency", action=argparse.BooleanOptionalAction, default=None,
                   help="estimate the reference's latency as a state, or not (default: the "
                        "bag's block, else yes)")
    g.add_argument("--reference-markov", default=None, metavar="SIGMA_H,SIGMA_V,TAU",
                   help="the reference's Markov noise states: sigma_h, sigma_v (m/s) and tau "
                        "(s), all > 0, or 'none' (white reference noise, e.g. differenced RTK) "
                        "(default: the bag's block, else 0.02,0.03,30)")
    g.add_argument("--initial-attitude", default=None, metavar="{levelled,independent}",
                   help="levelled: the INS levelled itself on its own accelerometers (the "
                        "aligned prior); independent: its attitude came from elsewhere "
                        "(default: the bag's block, else levelled)")


def is_ins3d(args: argparse.Namespace) -> bool:
    """True for ``--model ins3d``; refuses options of the other model (one line)."""
    ins3d = getattr(args, "model", None) == "ins3d"
    if ins3d:
        for attr, opt in SINGLE_AXIS_ONLY:
            if getattr(args, attr, None) is not None:
                raise CliError(f"{opt} applies to the single-axis models, not to --model ins3d")
        if args.reference_topic and len(args.reference_topic) > 1:
            raise CliError("--model ins3d takes one --reference-topic")
    else:
        for attr, opt in INS3D_ONLY:
            if getattr(args, attr, None) is not None:
                raise CliError(f"{opt} applies only to --model ins3d")
    return ins3d


def error_model_block(args: argparse.Namespace) -> dict:
    """The ``error_model`` block of the error-model options given (ERROR_MODEL_OPTIONS), each
    value checked by the one check of a bag's block (``bagio.ins3d_input.error_model_options``);
    CliError, one line naming the option, for a bad one."""
    from flight_fdi.bagio.errors import BagError
    from flight_fdi.bagio.ins3d_input import ERROR_MODEL, error_model_options

    block: dict = {}
    for key, flag in ERROR_MODEL_OPTIONS:
        raw = getattr(args, key, None)
        if raw is None:
            continue
        value = markov_value(raw) if key == "reference_markov" else raw
        try:
            error_model_options({ERROR_MODEL: {key: value}}, "the command line")
        except BagError as exc:
            why = str(exc).split(f"{ERROR_MODEL}.{key} ", 1)[-1]
            hint = " (give SIGMA_H,SIGMA_V,TAU or none)" if key == "reference_markov" else ""
            raise CliError(f"{flag} {raw!r}: {why}{hint}") from None
        block[key] = value
    return block


def markov_value(text: str) -> list | None:
    """``--reference-markov``: ``none`` -> None, ``A,B,C`` -> [A, B, C] (a part that is not a
    number is kept as text, which the check refuses)."""
    if text.strip().lower() == "none":
        return None
    out: list = []
    for part in text.split(","):
        try:
            out.append(float(part))
        except ValueError:
            out.append(part.strip())
    return out


def markov_text(value: list | None) -> str:
    """The ``--reference-markov`` text of a block's value (``markov_value`` reads it back)."""
    return "none" if value is None else ",".join(repr(float(v)) for v in value)


def recorded_model(options: dict, block: dict) -> dict:
    """What a result's ``source`` records of the error model: ``error_model``, the complete
    block of the options the analysis ran with, and ``error_model_overrides``, the keys the
    command line gave."""
    from flight_fdi.bagio.ins3d_input import ERROR_MODEL_KEYS, error_model_used

    return {"error_model": error_model_used(options),
            "error_model_overrides": [k for k in ERROR_MODEL_KEYS if k in block]}


def topics(args: argparse.Namespace) -> dict[str, str]:
    """The contract topic names given as options (the rest: bagio.ins3d_input.TOPICS)."""
    out = {"ins_velocity": args.ins_topic, "ins_imu": args.imu_topic,
           "ins_fix": args.fix_topic,
           "ref_velocity": args.reference_topic[0] if args.reference_topic else None}
    return {k: v for k, v in out.items() if v}


def settings(args: argparse.Namespace) -> dict:
    """grade, rows, the gate and the height reference (``ins3d_height.height_spec``: None or
    a HeightSpec) of the options."""
    from flight_fdi.cli.analyze import analysis_config

    return {"grade": grade_option(args.grade or "navigation"), "rows": args.rows or 3,
            "gate": analysis_config(args).gate, "height": height_spec(args)}


def grade_option(value: str) -> str:
    """``--grade``: a preset name, or the absolute path of a valid YAML grade file (the
    pipeline's filter_node loads it again); CliError (one line) otherwise."""
    from flight_fdi.core.errors import CoreError
    from flight_fdi.core.ins3d.grade_file import is_grade_file, load_grade

    if value in PRESETS:
        return value
    path = Path(value)
    if not is_grade_file(value):
        raise CliError(f"--grade {value!r}: not a preset ({', '.join(PRESETS)}) nor a YAML "
                       "grade file")
    try:
        load_grade(path)
    except CoreError as exc:
        raise CliError(f"--grade: {exc}") from None
    return str(path.resolve())


def source(names: dict[str, str], s: dict, model: dict | None = None) -> dict:
    """A result's ``source``: topics, grade, rows, the gate (``gate_options``) and ``model``
    (``recorded_model``)."""
    height = s.get("height")
    return {"ins_topic": names["ins_velocity"], "reference_topics": [names["ref_velocity"]],
            "imu_topic": names["ins_imu"], "fix_topic": names["ins_fix"],
            "grade": s["grade"], "rows": s["rows"], "gate": gate_options(s["gate"]),
            **({} if height is None else {"height": height.describe()}), **(model or {})}


def gate_options(gate) -> dict:
    """The gate options (GATE_OPTIONS' dests) that give ``gate`` (a ``GateConfig``)."""
    return {"gate_rule": gate.rule, "gate_probability": float(gate.probability),
            "alarm": f"{gate.alarm_m}/{gate.alarm_n}", "gate_action": gate.action}


def analyze_bag(bag: str, args: argparse.Namespace):
    """(result dict, Ins3dAnalysis, Ins3dInput) of one bag; the result's ``input`` section
    counts each contract topic's messages, used and dropped (``input_section3d``)."""
    from flight_fdi.bagio.ins3d_input import input_section3d, model_options_with, read_ins3d
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.core.ins3d.defaults import ANALYZE_DEFAULTS
    from flight_fdi.core.ins3d_result import ins3d_result

    s = settings(args)
    block = error_model_block(args)
    # the topics checked there, before anything is read
    inp = read_ins3d(bag, topics(args), height=s["height"])
    names = inp.topics
    options = model_options_with(inp, block, f"bag '{bag}'")
    rows, model = {"rows": s["rows"]}, dict(options)
    if inp.height is not None:       # the third row the height (with its own Markov noise; the
        #                              source records the velocity reference's, options')
        rows = inp.height.options(options.get("ref_markov", ANALYZE_DEFAULTS["ref_markov"]))
        model["ref_markov"] = rows.pop("ref_markov")
    analysis = analyze_ins3d(inp.steps, inp.refs, grade=s["grade"], gate=s["gate"], **rows,
                             **model)
    res = ins3d_result(analysis, bag, source(names, s, recorded_model(options, block)))
    section = input_section3d(inp)    # what was read and left out (batch's dropped_samples)
    if section is not None:
        res["input"] = section
    return res, analysis, inp


def format_result(res: dict) -> str:
    """A short table of a 3-D result; one warning per topic and drop reason (the single-axis
    table's, ``bagio.inputs.warnings``)."""
    from flight_fdi.bagio.inputs import warnings
    from flight_fdi.bagio.ins3d_input import REASON_TEXT3D
    from flight_fdi.core.ins3d.observability import bias_line
    from flight_fdi.core.ins3d_result import fault_line

    post, inf, summ = res["post_flight"], res["in_flight"], res["ins3d"]
    src = res.get("source") or {}
    lines = [f"{post['verdict'].upper()}: {post.get('headline', '')}",
             "  " + fault_line(res), "",
             f"bag {res['bag']}  model ins3d ({summ['grade']} grade, {len(summ['states'])} "
             f"states, rows {res['channel']})  {res['duration_s']:.1f} s  {res['samples']} "
             "reference updates"]
    if src:
        lines.append(f"input: IMU {src['imu_topic']}, INS {src['ins_topic']}, fix "
                     f"{src['fix_topic']}, reference {', '.join(src['reference_topics'])}")
    if src.get("error_model"):
        lines.append(model_line(src["error_model"], src.get("error_model_overrides") or []))
    if height_line(src, res.get("input") or {}):
        lines.append(height_line(src, res.get("input") or {}))
    lines += warnings(res.get("input") or {}, REASON_TEXT3D)  # what was left out, as 1-axis
    rows = ", ".join(f"{k} {v:.3f}" for k, v in summ["beta2_row_mean"].items())
    lines += ["",
              f"in flight: beta2 mean {summ['beta2_mean']:.3f} (per row {rows}); gate "
              f"{inf['gate_threshold']:.3g} exceeded on {100 * inf['exceed_fraction']:.2f}% "
              f"of updates; {len(inf['alarms'])} alarm(s)"
              + (f", the first at {inf['first_alarm_s']:.1f} s" if inf["alarms"] else "")]
    for a in inf["alarms"][:5]:
        lines.append(f"  alarm {a['start_s']:9.1f} .. {a['end_s']:9.1f} s  peak beta2 "
                     f"{a['peak_beta2']:.3g}")
    glr, seed = post.get("glr"), post.get("seed_method")
    if glr:
        lines.append(f"after the flight: GLR {glr['hypothesis']} statistic {glr['statistic']:.4g} "
                     f"(threshold {glr['threshold']:.4g})"
                     + (f", runner-up {glr['runner_up']} {glr['runner_up_statistic']:.4g}"
                        if glr.get("runner_up") else "")
                     + (f"; told apart from {post['ambiguity_resolved_s']:.0f} s"
                        if post.get("ambiguity_resolved_s") is not None else ""))
    if seed:
        lines.append(f"  seed method (two-filter chi2, UDU^T, Fisher): {seed['verdict']}, "
                     f"element {seed['element'] or '-'}")
    turns = [m for m in summ["manoeuvres"] if m[2].startswith("turn")]
    if turns:
        lines.append("turns: " + ", ".join(f"{a:.0f}-{b:.0f} s" for a, b, _ in turns))
    known = bias_line(summ.get("observability") or {})
    if known:
        lines.append(known)
    return "\n".join(lines)


def model_line(used: dict, given: list[str]) -> str:
    """The table's line of the error-model options used (``recorded_model``)."""
    mk = used["reference_markov"]
    return (f"error model: vertical {used['vertical']}, latency state "
            f"{'yes' if used['latency'] else 'no'}, reference Markov "
            + ("none" if mk is None else "/".join(f"{v:g}" for v in mk))
            + f", initial attitude {used['initial_attitude']}"
            + (f" (from the command line: {', '.join(given)})" if given else ""))


def emit(res: dict, args: argparse.Namespace, extra: list[str] = ()) -> int:
    if args.json:
        json.dump(res, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(format_result(res))
        for line in extra:
            print(line)
    return exit_status(res, args)


def run_analyze(args: argparse.Namespace) -> int:
    with bounded_cores(getattr(args, "jobs", None)):
        res, _, _ = analyze_bag(args.bag, args)
    return emit(res, args)


@contextmanager
def bounded_cores(n: int | None):
    """``analyze --model ins3d --jobs N``: the 3-D analysis on at most ``n`` cores. Its parallel
    parts are threads (the forward pass's discretisation ahead, the observability Gramian, the
    backward sweep's combination, the decision's signatures and nonlinear fits): the CPU
    affinity of this thread, which they inherit, is cut to ``n`` of its cores, and
    ``FLIGHT_FDI_THREADS`` (``core.threads.usable_threads``, by which the parts that can run
    alone do) is set to ``n``; a lower ``FLIGHT_FDI_THREADS`` already set wins. Both are
    restored after. None: no bound."""
    from flight_fdi.core.threads import ENV, usable_threads

    if n is None:
        yield
        return
    n = max(1, min(int(n), usable_threads()))
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    before = os.environ.get(ENV)
    os.environ[ENV] = str(n)
    try:
        if cores is not None and len(cores) > n:
            os.sched_setaffinity(0, cores[:n])
        yield
    finally:
        if cores is not None and len(cores) > n:
            os.sched_setaffinity(0, cores)
        if before is None:
            del os.environ[ENV]
        else:
            os.environ[ENV] = before


def options_of_result(args: argparse.Namespace, doc: dict) -> None:
    """``settings_of_result`` of a result JSON ``doc``, checked: a ``source`` that is not an
    object, or options in it that ``analyze`` would refuse, are one line naming the result."""
    from flight_fdi.core.errors import CoreError

    src = doc.get("source") or {}
    if not isinstance(src, dict):
        raise CliError(f"{args.input}: its 'source' is not an object: not a result of "
                       "flight-fdi analyze / run")
    settings_of_result(args, src)
    try:
        settings(args)
        error_model_block(args)
    except (CliError, CoreError) as exc:
        raise CliError(f"{args.input}: analysing its bag again as the result was made: "
                       f"{exc}") from None


def settings_of_result(args: argparse.Namespace, source: dict) -> None:
    """``report RESULT.json``: the bag is analysed again as the result was made -- its grade,
    reference rows, contract topics, height reference, gate and error-model overrides
    (``source``) for every
    option the command leaves unset (an option given on the command line wins; a gate option
    at its default counts as unset). A part of ``source`` of the wrong type is left out (the
    checks of ``options_of_result`` see the values)."""
    def part(key: str, kind: type):
        value = source.get(key)
        return value if isinstance(value, kind) else kind()

    for attr, kind in (("grade", str), ("rows", int), ("ins_topic", str), ("imu_topic", str),
                       ("fix_topic", str)):
        value = part(attr, kind)
        if getattr(args, attr, None) is None and value:
            setattr(args, attr, value)
    refs = part("reference_topics", list)
    if not args.reference_topic and len(refs) == 1:
        args.reference_topic = list(refs)
    height_args_of_source(args, source)
    defaults = gate_defaults()
    for attr, value in part("gate", dict).items():          # at its default: the result's
        if attr in defaults and getattr(args, attr, defaults[attr]) == defaults[attr]:
            setattr(args, attr, value)
    used = part("error_model", dict)
    for key in part("error_model_overrides", list):         # the rest: the bag's block again
        if key in dict(ERROR_MODEL_OPTIONS) and getattr(args, key, None) is None \
                and key in used:
            value = used[key]
            if key == "reference_markov":               # the option's text (checked as one)
                value = markov_text(value) if value is None or (isinstance(value, list) and all(
                    isinstance(v, (int, float)) for v in value)) else str(value)
            setattr(args, key, value)
