"""The report of a 3-D (``--model ins3d``) analysis: figures per body axis and one HTML page.

:func:`write_report3d` (``flight-fdi report BAG --model ins3d``, ``flight-fdi run --model
ins3d``) writes to a folder ``index.html`` (the verdict on top), ``summary.json`` (the result
JSON) and the PNG figures:

* ``axis_x.png``, ``axis_y.png``, ``axis_z.png``: per body axis, the accelerometer and the gyro
  bias estimated by the forward filter and after the flight by the two-filter smoother (with its
  1-sigma band), and the true total systematic error of that sensor axis when the bag carries the
  simulator's /sim/truth (``accel_error_*``, ``gyro_error_*``: bias + scale factor and
  misalignment on the true input + fault), and the result's fault (or ambiguous candidates) on
  that axis: its step or ramp from its onset, as the result reports them (``fault_profiles``);
* ``gate.png``: beta^2 over time against the chi-square gate, total and per reference row, the
  alarms;
* ``post_flight.png``: the two-filter chi-square J over time against its bound, and the GLR
  statistic of each body-axis hypothesis over its onset time against the thresholds.

Every figure shades the turns (the observability report's manoeuvres) and marks the isolated
fault's onset.
"""
from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from flight_fdi.core.ins3d.glr3d import threshold_of
from flight_fdi.core.models import DEG_PER_HOUR, G0

from .canvas import canvas, maxpool, save, stride
from .html import CSS, _clean, _num, _table

AXES = ("x", "y", "z")
MG = 1e-3 * G0


def _turns(ax: Any, manoeuvres: list) -> None:
    first = True
    for a, b, kind in manoeuvres:
        if str(kind).startswith("turn"):
            ax.axvspan(a, b, color="#d8e4f4", alpha=0.6, lw=0, label="turn" if first else None)
            first = False


def _onset(ax: Any, res: dict) -> None:
    f = res["post_flight"].get("fault")
    if f and f.get("onset_s") is not None:
        ax.axvline(f["onset_s"], color="#c03030", ls="--", lw=1,
                   label=f"onset ({f['sensor']} {f['axis']})")


def _finish(fig: Any, axes: tuple, res: dict, path: Path) -> Path:
    for ax in axes:
        _onset(ax, res)
        ax.legend(loc="upper left", fontsize=8)
        ax.grid(alpha=0.3)
    return save(fig, path)


def fault_profiles(res: dict, sensor: str, axis: str, t_start: float,
                   t_end: float) -> list[tuple[str, list[float], list[float]]]:
    """(label, times, values SI) of the result's fault, or of each ambiguous candidate, on this
    sensor axis: its step or ramp from its onset, drawn from the record (onset and magnitude as
    the result reports them: the exact fit's after the nonlinear check of a large gyro fault,
    ``Ins3dAnalysis.bias_estimates``'s ``*_fault`` too)."""
    post, out = res["post_flight"], []
    fault = post.get("fault")
    for f in ([fault] if fault else []) + list(post.get("candidates") or []):
        if f["sensor"] != sensor or f["axis"] != axis or f["kind"] not in ("step", "ramp") \
                or f.get("magnitude") is None or f.get("onset_s") is None:
            continue
        on, m = f["onset_s"], f["magnitude"]
        what = "isolated" if f is fault else "candidate"
        label = f"{what} {f['kind']} {f['magnitude_eng']:+.3g} {f['unit_eng']}"
        if f["kind"] == "step":
            out.append((label, [t_start, on, on, t_end], [0.0, 0.0, m, m]))
        else:
            out.append((label, [t_start, on, t_end], [0.0, 0.0, m * (t_end - on)]))
    return out


def axis_figure(analysis: Any, res: dict, axis: str, path: Path,
                truth: dict | None = None) -> Path:
    """Estimated vs true accelerometer and gyro bias of one body axis (module docstring)."""
    fwd, names = analysis.forward, list(analysis.model.names)
    man = res["ins3d"]["manoeuvres"]
    j = AXES.index(axis)
    smooth = analysis.bias_estimates() if getattr(analysis, "backward", None) is not None \
        else None
    fig, (a1, a2) = canvas(2, f"body axis {axis}: estimated vs true sensor error")
    for ax, state, sensor, key, scale, unit in (
            (a1, f"ba_{axis}", "accelerometer", f"accel_error_{axis}", MG, "mg"),
            (a2, f"bg_{axis}", "gyro", f"gyro_error_{axis}", DEG_PER_HOUR, "deg/h")):
        _turns(ax, man)
        i = names.index(state)
        t, x = stride(fwd.t, fwd.x[:, i] / scale)
        ax.plot(t, x, color="#7fa7cf", lw=0.9, label=f"forward filter {state}")
        if smooth is not None:
            t, x, sd = stride(smooth["t"], smooth[sensor][:, j] / scale,
                               smooth[f"{sensor}_sd"][:, j] / scale)
            ax.fill_between(t, x - sd, x + sd, color="#9ecae1", alpha=0.5, lw=0,
                            label="1 sigma (smoothed)")
            ax.plot(t, x, color="#1f5fa0", lw=1.4, label="smoothed (two-filter)")
        if truth is not None and key in truth:
            tt, y = stride(truth["t"], truth[key] / scale)
            ax.plot(tt, y, color="k", lw=1, ls=":", label="true (bias + SF/misalignment + fault)")
        for label, tf, yf in fault_profiles(res, sensor, axis, float(fwd.t[0]),
                                            float(fwd.t[-1])):
            ax.plot(tf, np.asarray(yf) / scale, lw=1.4, label=label,
                    color="#d62728" if label.startswith("isolated") else "#ff7f0e")
        _onset(ax, res)
        ax.set_ylabel(f"{sensor} {axis} [{unit}]")
        ax.legend(loc="upper left", fontsize=8)
        ax.grid(alpha=0.3)
    a2.set_xlabel("time [s]")
    return save(fig, path)


def gate_figure3d(analysis: Any, res: dict, path: Path) -> Path:
    """beta^2 (total and per row) over the updates, the gates and the alarms."""
    fwd = analysis.forward
    fig, (a1, a2) = canvas(2, "in flight: the beta^2 gate (forward filter)")
    _turns(a1, res["ins3d"]["manoeuvres"])
    t, b = maxpool(fwd.t_ref, fwd.beta2)
    a1.semilogy(t, np.maximum(b, 1e-6), lw=0.8, color="#1f5fa0", label="beta^2")
    a1.axhline(fwd.threshold, color="#c03030", lw=1, label=f"gate {fwd.threshold:.3g}")
    for k, a in enumerate(res["in_flight"]["alarms"]):
        a1.axvspan(a["start_s"], max(a["end_s"], a["start_s"] + 1.0), color="#f4a0a0",
                   alpha=0.7, lw=0, label="alarm" if k == 0 else None)
    a1.set_ylabel("beta^2 (rows together)")
    _turns(a2, res["ins3d"]["manoeuvres"])
    rows = list(res["ins3d"]["beta2_row_mean"])       # east, north, up or height
    for j, row in enumerate(rows[:fwd.beta2_row.shape[1]]):
        t, b = maxpool(fwd.t_ref, fwd.beta2_row[:, j])
        a2.semilogy(t, np.maximum(b, 1e-6), lw=0.7, label=row)
    a2.axhline(fwd.threshold_row, color="#c03030", lw=1, label=f"row gate {fwd.threshold_row:.3g}")
    a2.set_ylabel("beta^2 per row")
    a2.set_xlabel("time [s]")
    return _finish(fig, (a1, a2), res, path)


def post_flight_figure(analysis: Any, res: dict, path: Path) -> Path | None:
    """The two-filter chi-square J over time with its bound, and the GLR statistic of every
    body-axis hypothesis over its onset time (the isolated one and its runner-up drawn bold,
    each with its own threshold dashed in its colour)."""
    dec = getattr(analysis, "decided", analysis)    # after removed glitches: the rest's
    seed, curves = getattr(dec, "seed", None), getattr(dec, "glr", None)
    if seed is None or not curves:
        return None
    glr = res["post_flight"].get("glr") or {}
    bold = {glr.get("hypothesis"), glr.get("runner_up")}
    fig, (a1, a2) = canvas(2, "after the flight: two-filter chi-square and GLR statistics")
    _turns(a1, res["ins3d"]["manoeuvres"])
    t, J = maxpool(np.asarray(seed.t, dtype=float), np.asarray(seed.J, dtype=float))
    a1.semilogy(t, np.maximum(J, 1e-3), lw=0.7, color="#1f5fa0", label="J (two-filter chi^2)")
    t, g = stride(np.asarray(seed.t, dtype=float), np.asarray(seed.gamma2, dtype=float))
    a1.semilogy(t, g, color="#c03030", lw=1, label="bound gamma^2 (effective dof)")
    a1.set_ylabel("chi-square J")
    _turns(a2, res["ins3d"]["manoeuvres"])
    thresholds = glr.get("thresholds") or {}
    for name, c in curves.items():
        if c.hypothesis.kind == "outliers" or not c.t.size:
            continue
        t, y = maxpool(np.asarray(c.t, dtype=float), np.asarray(c.stat, dtype=float))
        strong = name in bold
        line, = a2.plot(t, y, lw=1.4 if strong else 0.5, alpha=1.0 if strong else 0.5,
                        label=name if strong else None)
        if strong and thresholds:       # its own threshold (per hypothesis, else its kind's)
            a2.axhline(threshold_of(thresholds, c.hypothesis), ls="--", lw=0.8,
                       color=line.get_color())
    a2.set_ylabel("GLR statistic over the onset")
    a2.set_xlabel("time [s] (GLR: onset time)")
    return _finish(fig, (a1, a2), res, path)


def _e(x: Any) -> str:
    return html.escape(str(x))


def _page(res: dict, figs: list[tuple[str, str]], notes: list[str]) -> str:
    from flight_fdi.bagio.ins3d_input import REASON_TEXT3D
    from flight_fdi.core.ins3d_result import fault_line

    from .inputs import inputs_part

    post, inf, summ = res["post_flight"], res["in_flight"], res["ins3d"]
    verdict = post["verdict"]
    parts = ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
             f"<title>flight-fdi ins3d report: {_e(res['bag'])}</title><style>{CSS}</style>"
             "</head><body>", f"<div class='verdict {_e(verdict)}'>",
             f"<h1>{_e(verdict.replace('_', ' ').upper())}</h1>",
             f"<p><b>{_e(post.get('headline', ''))}</b></p><p>{_e(fault_line(res))}</p>",
             f"<p>In flight: {len(inf['alarms'])} alarm(s), first at "
             f"{_num(inf['first_alarm_s'], '.1f')} s; beta<sup>2</sup> mean "
             f"{summ['beta2_mean']:.3f} ({len(summ['beta2_row_mean'])} rows), gate "
             f"{_num(inf['gate_threshold'])} exceeded on {100 * inf['exceed_fraction']:.2f}% of "
             "the updates.</p></div>",
             f"<p>Model ins3d, {_e(summ['grade'])} grade, {len(summ['states'])} states; "
             f"{res['samples']} reference updates over {res['duration_s']:.1f} s (times in "
             "seconds from the first stamp of the inputs). Turns are shaded in the figures.</p>"]
    parts += [f"<p>{_e(n)}</p>" for n in notes]
    parts.append(inputs_part(res.get("input"), REASON_TEXT3D))
    obs = summ.get("observability") or {}
    if obs:
        parts.append("<h2>Observability (when each state became observable)</h2>")
        parts.append(_table(("state", "observable from s"),
                            ((k, _num(v, ".0f") if isinstance(v, (int, float)) else "never")
                             for k, v in obs.items())))
    parts.append("<h2>Final estimates</h2>")
    parts.append(_table(("state", "estimate", "1 sigma"),
                        ((k, _num(v), _num(summ["final_sd"][k]))
                         for k, v in summ["final_state"].items())))
    parts.append("<h2>Figures</h2>")
    parts += [f"<figure><img src='{_e(f)}' alt='{_e(f)}'><figcaption>{_e(c)}</figcaption>"
              "</figure>" for f, c in figs]
    parts.append("<p><a href='summary.json'>summary.json</a> (the result of "
                 "<code>flight-fdi analyze --model ins3d --json</code>)</p></body></html>")
    return "\n".join(parts) + "\n"


def write_report3d(res: dict, analysis: Any, out_dir: str | Path, truth: dict | None = None,
                   notes: list[str] | None = None) -> Path:
    """Write the figures, summary.json and index.html; returns the index path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = []
    for axis in AXES:
        axis_figure(analysis, res, axis, out / f"axis_{axis}.png", truth)
        figs.append((f"axis_{axis}.png", f"Body axis {axis}: accelerometer and gyro bias "
                     "estimates (forward filter; two-filter smoother with 1 sigma)"
                     + (", and the true sensor error" if truth else "")))
    gate_figure3d(analysis, res, out / "gate.png")
    figs.append(("gate.png", "beta^2 against the gate, total and per reference row"))
    if post_flight_figure(analysis, res, out / "post_flight.png") is not None:
        figs.append(("post_flight.png", "After the flight: chi-square J with its bound; GLR "
                     "statistic per body-axis hypothesis over the onset time, the best one's "
                     "and its runner-up's thresholds dashed"))
    notes = list(notes or [])
    if truth is None:
        notes.append("The bag has no /sim/truth: no true sensor errors are drawn.")
    (out / "summary.json").write_text(json.dumps(_clean(res), allow_nan=False, indent=1),
                                      encoding="utf-8")
    index = out / "index.html"
    index.write_text(_page(res, figs, notes), encoding="utf-8")
    return index


__all__ = ["axis_figure", "gate_figure3d", "post_flight_figure", "write_report3d"]
