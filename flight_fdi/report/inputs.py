"""The report's inputs part: what the analysis received and left out, per topic, from the
result's ``input`` section alone (``bagio.inputs.input_section``; 3-D:
``bagio.ins3d_input.input_section3d``) -- the table of the text output's warnings
(``bagio.inputs.warnings``)."""
from __future__ import annotations

import html
from typing import Any

from flight_fdi.bagio.inputs import REASON_TEXT


def _e(x: Any) -> str:
    return html.escape(str(x))


def _dropped(entry: dict, what: dict) -> str:
    """'n reason' per reason that occurred (in the warnings' words), '; '-joined; 'none'."""
    parts = [f"{n} {what.get(k, k.replace('_', ' '))}"
             for k, n in (entry.get("dropped") or {}).items() if n]
    if entry.get("reordered"):
        parts.append(f"{entry['reordered']} out of header-stamp order (sorted, kept)")
    return "; ".join(parts) or "none"


def inputs_part(section: dict | None, texts: dict | None = None) -> str:
    """The HTML of the inputs part: a heading and one row per topic -- topic, role, messages
    received, used, and dropped by reason (``REASON_TEXT`` with ``texts``, another input's
    reasons, over them). A result without an ``input`` section says so (nothing left out
    silently)."""
    head = "<h2>Inputs</h2>"
    topics = {k: e for k, e in (section or {}).items() if isinstance(e, dict)}
    if not topics:
        return head + "\n<p>The result records no input section: what was received and " \
            "dropped is not known.</p>"
    what = {**REASON_TEXT, **(texts or {})}
    rows = ["<table><tr><th>topic</th><th>role</th><th>received</th><th>used</th>"
            "<th>dropped, by reason</th></tr>"]
    for topic, e in topics.items():
        rows.append(f"<tr><td>{_e(topic)}</td><td>{_e(e.get('role', '-'))}</td>"
                    f"<td>{_e(e.get('messages', '-'))}</td><td>{_e(e.get('used', '-'))}</td>"
                    f"<td style='text-align:left'>{_e(_dropped(e, what))}</td></tr>")
    rows.append("</table>")
    return head + "\n" + "\n".join(rows)


__all__ = ["inputs_part"]
