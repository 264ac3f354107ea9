"""``--height-topic`` and its options for ``analyze``, ``batch``, ``report`` (and ``run``) with
``--model ins3d``: a height reference as the third reference row (``bagio.height_input``;
docs/ins3d.md, "A height reference").

The options make a ``bagio.height_input.HeightSpec``; its defaults are the real-data
evaluation's setting (i): white 0.05 m, a Markov error of 0.4 m over 5 s, the initial vertical
velocity error 1 m/s, the datum ``first``. The third row is then the height, so ``--rows 2``
is refused (``--rows`` may be left out or be 3). A result records the spec in
``source.height`` and ``report RESULT.json`` reads it back (``height_args_of_source``).
"""
from __future__ import annotations

import argparse

from flight_fdi.cli.errors import CliError

#: the height options (dest, flag); all but the topic need it
HEIGHT_OPTIONS = (("height_topic", "--height-topic"), ("height_sigma", "--height-sigma"),
                  ("height_markov", "--height-markov"), ("height_datum", "--height-datum"),
                  ("v0_sigma_up", "--v0-sigma-up"))


def add_height_options(p: argparse.ArgumentParser) -> None:
    from flight_fdi.bagio.height_input import (DATUMS, DEFAULT_MARKOV, DEFAULT_SIGMA_M,
                                               DEFAULT_V0_SIGMA_UP, HEIGHT_TYPES)

    g = p.add_argument_group(
        "3-D height reference (--model ins3d; the third reference row; docs/ins3d.md, 'A "
        "height reference')")
    g.add_argument("--height-topic", default=None, metavar="TOPIC",
                   help=f"a height reference topic ({', '.join(_short(t) for t in HEIGHT_TYPES)}"
                        "): the third row is then the height, interpolated at the reference "
                        "velocity's stamps (default: none)")
    g.add_argument("--height-sigma", type=float, default=None, metavar="M",
                   help="white sigma of a height message without a known variance (default "
                        f"{DEFAULT_SIGMA_M:g})")
    g.add_argument("--height-markov", default=None, metavar="SIGMA,TAU",
                   help="the height's Markov error, sigma (m) and tau (s), both > 0, or 'none' "
                        f"(default {DEFAULT_MARKOV[0]:g},{DEFAULT_MARKOV[1]:g}; the model has one "
                        "tau for all rows' Markov states: this one)")
    g.add_argument("--height-datum", default=None, choices=DATUMS,
                   help="first: the reference offset to the INS height at its first sample (a "
                        "barometric or pressure altitude; default); absolute: as published")
    g.add_argument("--v0-sigma-up", type=float, default=None, metavar="M/S",
                   help="with a height reference: the initial vertical velocity error's sigma "
                        f"(default {DEFAULT_V0_SIGMA_UP:g})")


def _short(msgtype: str) -> str:
    return msgtype.rsplit("/", 1)[-1]


def height_spec(args: argparse.Namespace):
    """The ``HeightSpec`` of the options (None without ``--height-topic``); CliError, one
    line naming the option, for an option without the topic, ``--rows 2`` with it, or a bad
    value."""
    from flight_fdi.bagio.errors import BagError
    from flight_fdi.bagio.height_input import HeightSpec

    topic = getattr(args, "height_topic", None)
    if topic is None:
        given = [flag for dest, flag in HEIGHT_OPTIONS[1:] if getattr(args, dest, None) is not None]
        if given:
            raise CliError(f"{', '.join(given)} need{'s' if len(given) == 1 else ''} "
                           "--height-topic")
        return None
    if getattr(args, "rows", None) == 2:
        raise CliError("--rows 2 and --height-topic: the height reference is the third row "
                       "(give --rows 3 or leave --rows out)")
    kw: dict = {}
    for dest, name in (("height_sigma", "sigma"), ("height_datum", "datum"),
                       ("v0_sigma_up", "v0_sigma_up"), ("height_markov", "markov")):
        value = getattr(args, dest, None)
        if value is None:
            continue
        kw[name] = markov_pair(value) if dest == "height_markov" else value
        try:                        # each value by HeightSpec's own check, naming its option
            HeightSpec(topic, **{name: kw[name]})
        except BagError as exc:
            raise CliError(f"{dict(HEIGHT_OPTIONS)[dest]} {value!r}: "
                           f"{str(exc).split(': ', 1)[-1]}") from None
    try:
        return HeightSpec(topic, **kw)
    except BagError as exc:         # the topic
        raise CliError(f"--height-topic {topic!r}: {str(exc).split(': ', 1)[-1]}") from None


def markov_pair(text: str) -> tuple | None:
    """``--height-markov``: ``none`` -> None, ``S,T`` -> (S, T); CliError otherwise."""
    if text.strip().lower() == "none":
        return None
    try:
        pair = tuple(float(v) for v in text.split(","))
    except ValueError:
        pair = ()
    if len(pair) != 2 or not all(v > 0 and v < float("inf") for v in pair):
        raise CliError(f"--height-markov {text!r}: expected SIGMA,TAU (m, s), both > 0, or none")
    return pair


def height_args_of_source(args: argparse.Namespace, source: dict) -> None:
    """``report RESULT.json``: the height options of the result's ``source.height`` (a
    ``HeightSpec.describe()``) for every one the command leaves unset."""
    h = source.get("height")
    if not isinstance(h, dict) or getattr(args, "height_topic", None) is not None:
        return
    mk = h.get("markov")
    values = {"height_topic": h.get("topic"), "height_sigma": h.get("sigma_m"),
              "height_datum": h.get("datum"), "v0_sigma_up": h.get("v0_sigma_up"),
              "height_markov": "none" if mk is None else
              ",".join(str(v) for v in mk) if isinstance(mk, list) else str(mk)}
    for dest, value in values.items():
        if getattr(args, dest, None) is None and value is not None:
            setattr(args, dest, value)


def height_line(src: dict, section: dict) -> str | None:
    """The result table's line of the height reference (None without one)."""
    h = src.get("height")
    if not isinstance(h, dict):
        return None
    entry = section.get(h.get("topic")) or {}
    mk = h.get("markov")
    kind = str(entry.get("type", "")).split("/")[-1]
    var = entry.get("variance") or {}
    return (f"height reference: {h.get('topic')} ({kind}), white {h.get('sigma_m'):g} m, Markov "
            + ("none" if mk is None else f"{mk[0]:g} m over {mk[1]:g} s")
            + f", datum {h.get('datum')}"
            + (f" (offset {entry['offset_m']:+.2f} m)" if "offset_m" in entry else "")
            + (f", variances: {var.get('message', 0)} from the messages, "
               f"{var.get('configured', 0)} configured" if var else ""))


__all__ = ["HEIGHT_OPTIONS", "add_height_options", "height_args_of_source", "height_line",
           "height_spec", "markov_pair"]
