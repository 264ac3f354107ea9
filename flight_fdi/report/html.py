"""The report of one analysed flight: PNG figures and one HTML page with the verdict on top.

:func:`write_report` is what ``flight-fdi report`` (and ``flight-fdi run``) call::

    from flight_fdi.report import write_report
    index = write_report(analysis_result, "out/flight1/report", truth=None)

``analysis_result`` is the core's :class:`~flight_fdi.core.analysis.AnalysisResult`
(``run_analysis`` / ``analyze_forward``). The folder receives ``index.html``, ``summary.json`` (the
result in the JSON schema of ``flight-fdi analyze --json``) and the figures: ``gate.png``,
``chi2.png``, ``glr.png`` and ``element_<k>_<name>.png`` per state element.
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any, Iterable

from flight_fdi.core.models import DEG_PER_HOUR, G0
from flight_fdi.core.recording import json_safe as _clean  # (figures3d imports it here)
from flight_fdi.eval.errors import EvalError

from . import figures
from .figures import Truth
from .inputs import inputs_part

CSS = """
body { font-family: sans-serif; margin: 2em; max-width: 1100px; color: #222; }
.verdict { padding: 1em 1.5em; border-radius: 6px; margin-bottom: 1.5em; }
.verdict h1 { margin: 0 0 .3em 0; font-size: 1.8em; }
.no_fault { background: #e3f4e1; border: 1px solid #7bbf73; }
.glitch, .ambiguous { background: #fff4d6; border: 1px solid #e0b040; }
.failure { background: #fbe1e1; border: 1px solid #d06060; }
.insufficient_data { background: #eee; border: 1px solid #999; }
table { border-collapse: collapse; margin: .5em 0 1.5em 0; }
td, th { border: 1px solid #bbb; padding: .25em .6em; text-align: right; }
th { background: #f0f0f0; } td:first-child, th:first-child { text-align: left; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: .9em; color: #555; }
"""


def _num(x: Any, spec: str = ".4g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def _magnitude_text(value: float | None, element: str | None, unit: str) -> str:
    """The magnitude in SI and, for the INS instruments, in mg or deg/h."""
    if value is None:
        return "-"
    text = f"{value:.4g} {unit}".strip()
    if element == "accel_bias" and unit == "m/s^2":
        text += f" ({value / (1e-3 * G0):.4g} mg)"
    elif element == "gyro_drift" and unit == "rad/s":
        text += f" ({value / DEG_PER_HOUR:.4g} deg/h)"
    return text


def _e(x: Any) -> str:
    return html.escape(str(x))


def _table(head: Iterable[str], rows: Iterable[Iterable[Any]]) -> str:
    out = ["<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in row) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def write_report(analysis_result: Any, out_dir: str | Path, truth: Truth | None = None, *,
                 model: Any = None, title: str | None = None,
                 notes: Iterable[str] = ()) -> Path:
    """Write the figures, ``summary.json`` and ``index.html`` of one analysed flight into
    ``out_dir`` (created when missing; files of an earlier report are overwritten).

    truth: the true error state in the analysis' time base (simulated flights), or None.
    model: the LinearModel analysed (for the state units; the built-in models' units are known
    without it). title: the page title (default: the bag and channel). notes: extra lines shown
    under the verdict (e.g. where the data came from). Returns the path of ``index.html``.
    """
    for attr in ("fwd", "bwd", "seed", "glr", "summary", "t0"):
        if not hasattr(analysis_result, attr):
            raise EvalError(f"write_report: expected the core's AnalysisResult, got "
                            f"{type(analysis_result).__name__} without {attr!r}")
    if truth is not None and not isinstance(truth, Truth):
        raise EvalError(f"write_report: truth must be a flight_fdi.report.Truth, got "
                        f"{type(truth).__name__}")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EvalError(f"cannot create the report folder '{out}': {exc.strerror}") from None
    res = analysis_result
    summary = res.summary
    names = figures.state_names(res)

    figs: list[tuple[str, str]] = []  # (file name, caption)
    for k, name in enumerate(names):
        fname = f"element_{k + 1}_{name}.png"
        figures.element_figure(res, k, out / fname, truth=truth, model=model)
        figs.append((fname, f"Element {k + 1}, {name}: "
                     + ("true error, " if truth is not None and truth.series(name) is not None
                        else "")
                     + "filtered and smoothed estimates; chi-square term J(i/k) with "
                       "gamma_k^2; Fisher statistic F_k with eta^2 (seed 000, figures 7.2/7.3)."))
    units = figures.state_units(res, model)
    figures.gate_figure(res, out / "gate.png", unit=units[0] if units and units[0] else "-")
    figs.append(("gate.png", "In flight: the innovation with +-3 sqrt(S); beta^2 with the gate "
                             "and the M-of-N alarm episodes."))
    figures.chi2_figure(res, out / "chi2.png")
    figs.append(("chi2.png", "Post flight: total chi-square statistic J of the two-filter residual "
                             "with gamma^2, shaded where J exceeds it; the seed method's onset."))
    figures.glr_figure(res, out / "glr.png")
    figs.append(("glr.png", "Post flight: GLR statistic over the onset time for each hypothesis, "
                            "with the threshold of its false-alarm probability."))

    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(_clean(summary), indent=2, allow_nan=False) + "\n")
    page = _page(summary, res, figs, title, list(notes))
    index = out / "index.html"
    index.write_text(page, encoding="utf-8")
    return index


def _page(summary: dict, res: Any, figs: list[tuple[str, str]], title: str | None,
          notes: list[str]) -> str:
    post = summary["post_flight"]
    inf = summary["in_flight"]
    seed = post["seed_method"]
    glr = post["glr"]
    verdict = post["verdict"]
    per = getattr(res.glr, "per_hypothesis", {}) or {}
    unit = per.get(glr["hypothesis"], {}).get("unit", "") if glr["hypothesis"] != "none" else ""
    title = title or f"flight-fdi report: {summary.get('bag', '')} channel {summary['channel']}"
    parts = [
        "<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>",
        f"<div class='verdict {_e(verdict)}'>",
        f"<h1>{_e(verdict.replace('_', ' ').upper())}</h1>",
        f"<p><b>{_e(post.get('headline', ''))}</b></p>"
        + (f"<p>Why the methods differ: {_e(post['disagreement'])}</p>"
           if post.get("disagreement") else "") + "<p>"
        f"element <b>{_e(post['element'] or '-')}</b>, onset <b>{_num(post['onset_s'], '.1f')} s"
        f"</b>, magnitude <b>{_e(_magnitude_text(post['magnitude'], post['element'], unit))}</b>"
        f"; the two methods {'agree' if post['methods_agree'] else 'disagree'}.</p>",
        f"<p>Seed method (chi-square + UDU<sup>T</sup> + Fisher): {_e(seed['verdict'])}, element "
        f"{_e(seed['element'] or '-')}.<br>GLR: {_e(glr['hypothesis'])}, onset "
        f"{_num(glr['onset_s'], '.1f')} s, magnitude "
        f"{_e(_magnitude_text(glr['magnitude'], post['element'], unit))}, statistic "
        f"{_num(glr['statistic'])} (threshold {_num(glr['threshold'])}).<br>"
        f"In flight: {len(inf['alarms'])} alarm(s), first at {_num(inf['first_alarm_s'], '.1f')}"
        f" s; beta<sup>2</sup> exceeded the gate {_num(inf['gate_threshold'])} on "
        f"{100 * inf['exceed_fraction']:.2f}% of the samples.</p>",
        "</div>",
        f"<p>{_e(title)} &mdash; {summary['samples']} samples over "
        f"{summary['duration_s']:.1f} s (times in seconds from the start of the record).</p>",
    ]
    for note in notes:
        parts.append(f"<p>{_e(note)}</p>")
    parts.append(inputs_part(summary.get("input")))
    if inf["alarms"]:
        parts.append("<h2>In-flight alarms</h2>")
        parts.append(_table(("start s", "end s", "peak beta^2"),
                            ((_num(a["start_s"], ".1f"), _num(a["end_s"], ".1f"),
                              _num(a["peak_beta2"])) for a in inf["alarms"][:50])))
        if len(inf["alarms"]) > 50:
            parts.append(f"<p>... and {len(inf['alarms']) - 50} more.</p>")
    parts.append("<h2>Seed method per element</h2>")
    parts.append(_table(("element", "J peak", "gamma^2", "F peak", "eta^2", "J exceeded",
                         "dof"),
                        ((e["name"], _num(e["J_peak"]), _num(e["gamma2"]), _num(e["F_peak"]),
                          _num(e["eta2"]), f"{100 * e['exceed_fraction']:.1f}%", e["dof"])
                         for e in seed["elements"])))
    if per:
        parts.append("<h2>GLR per hypothesis</h2>")
        parts.append(_table(("hypothesis", "statistic", "onset s", "magnitude", "std", "unit"),
                            ((h, _num(d["statistic"]),
                              _num(None if d["onset_t"] is None else d["onset_t"] - res.t0,
                                   ".1f"),
                              _num(d["magnitude"]), _num(d["magnitude_std"]), d["unit"])
                             for h, d in per.items())))
    parts.append("<h2>Figures</h2>")
    for fname, caption in figs:
        parts.append(f"<figure><img src='{_e(fname)}' alt='{_e(fname)}'>"
                     f"<figcaption>{_e(caption)}</figcaption></figure>")
    parts.append("<p><a href='summary.json'>summary.json</a> (the result in the schema of "
                 "<code>flight-fdi analyze --json</code>)</p>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
