"""The fleet outputs of ``flight-fdi batch``: summary.csv and the fleet page index.html (a
sortable table of every flight, counts per verdict and per sensor, links to each flight's result
and report -- or the command that makes the report)."""
from __future__ import annotations

import csv
import html
import os
import shlex
from collections import Counter
from pathlib import Path
from typing import Any

from .summary import COLUMNS

#: clicking a header sorts by that column (numbers by value, empty cells last); again: reverse
SORT_JS = """
document.querySelectorAll('table.fleet th').forEach(function (th, col) {
  th.addEventListener('click', function () {
    var body = th.closest('table').tBodies[0];
    var rows = Array.from(body.rows);
    var dir = th.dataset.dir === 'asc' ? -1 : 1;
    th.closest('tr').querySelectorAll('th').forEach(function (h) { delete h.dataset.dir; });
    th.dataset.dir = dir === 1 ? 'asc' : 'desc';
    function key(r) {
      var c = r.cells[col];
      return c.dataset.v !== undefined ? c.dataset.v : c.textContent;
    }
    rows.sort(function (a, b) {
      var x = key(a), y = key(b);
      if (x === '' || y === '') { return (x === '') - (y === ''); }
      var nx = parseFloat(x), ny = parseFloat(y);
      var c = (!isNaN(nx) && !isNaN(ny)) ? nx - ny : x.localeCompare(y);
      return dir * c;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  });
});
"""

FLEET_CSS = """
table.fleet th { cursor: pointer; user-select: none; }
table.fleet th[data-dir=asc]::after { content: ' \\25B2'; }
table.fleet th[data-dir=desc]::after { content: ' \\25BC'; }
td.failure { background: #fbe1e1; } td.glitch, td.ambiguous { background: #fff4d6; }
td.no_fault { background: #e3f4e1; } td.err { color: #a00; text-align: left; }
code { font-size: .85em; }
"""


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return format(v, ".10g")
    return str(v)


def write_summary_csv(rows: list[dict], path: Path) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([_fmt(r.get(c)) for c in COLUMNS])
    os.replace(tmp, path)


def _e(x: Any) -> str:
    return html.escape("" if x is None else str(x))


def _cell(value: Any, text: str | None = None, cls: str | None = None) -> str:
    sort = "" if value is None else (format(value, ".10g") if isinstance(value, float)
                                     else str(value))
    klass = f' class="{_e(cls)}"' if cls else ""
    return f'<td data-v="{_e(sort)}"{klass}>{text if text is not None else _e(_short(value))}</td>'


def _short(v: Any) -> str:
    if isinstance(v, float):
        return format(v, ".4g")
    return "" if v is None else str(v)


def _counts(title: str, counter: Counter) -> str:
    body = "".join(f"<tr><td>{_e(k)}</td><td>{n}</td></tr>"
                   for k, n in sorted(counter.items(), key=lambda kv: (-kv[1], kv[0])))
    return f"<table><tr><th>{_e(title)}</th><th>flights</th></tr>{body}</table>"


def report_command(flight: str, extra: list[str]) -> str:
    """The command (run in the output folder) that makes a flight's report."""
    return shlex.join(["flight-fdi", "report", f"flights/{flight}.json", "--out",
                       f"reports/{flight}", *extra])


def write_fleet_page(rows: list[dict], out: Path, reports: dict[str, str],
                     report_options: list[str] | None = None, note: str = "") -> Path:
    """out/index.html of the fleet; ``reports``: flight -> its report page (relative)."""
    verdicts = Counter(r["verdict"] or ("error" if r["error"] else "-") for r in rows)
    sensors = Counter(r["sensor"] or "none" for r in rows if r["verdict"] is not None)
    head = ("flight", "duration s", "verdict", "sensor", "axis", "kind", "onset s", "magnitude",
            "unit", "confidence", "dropped", "error", "report")
    lines = []
    for r in rows:
        name = r["flight"]
        result = out / "flights" / f"{name}.json"
        link = (f'<a href="flights/{_e(name)}.json">{_e(name)}</a>' if result.is_file()
                else _e(name))
        if name in reports:
            rep = f'<a href="{_e(reports[name])}">report</a>'
        elif result.is_file():
            rep = f"<code>{_e(report_command(name, report_options or []))}</code>"
        else:
            rep = ""
        lines.append("<tr>" + "".join([
            _cell(name, link), _cell(r["duration_s"]),
            _cell(r["verdict"], cls=r["verdict"]), _cell(r["sensor"]), _cell(r["axis"]),
            _cell(r["kind"]), _cell(r["onset_s"]), _cell(r["magnitude"]), _cell(r["unit"]),
            _cell(r["confidence"]), _cell(r["dropped_samples"]),
            _cell(r["error"], cls="err" if r["error"] else None), _cell(None, rep)]) + "</tr>")
    from flight_fdi.report.html import CSS

    page = f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>flight_fdi fleet: {len(rows)} flights</title>
<style>{CSS}{FLEET_CSS}</style></head><body>
<h1>Fleet: {len(rows)} flights</h1>
<p>{_e(note)}</p>
<div style="display:flex; gap:2em">{_counts("verdict", verdicts)}{_counts("sensor", sensors)}</div>
<p>Click a column header to sort. Reports not made yet: run the command shown in the output
folder, or <code>flight-fdi batch ... --reports faults|all|NAME,...</code>.</p>
<table class="fleet"><thead><tr>{"".join(f"<th>{_e(h)}</th>" for h in head)}</tr></thead>
<tbody>
{chr(10).join(lines)}
</tbody></table>
<script>{SORT_JS}</script>
</body></html>
"""
    index = out / "index.html"
    tmp = index.with_name(f".index.html.{os.getpid()}.tmp")
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, index)
    return index
