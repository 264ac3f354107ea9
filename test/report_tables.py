"""The inputs table of a report page, read back (test/eval/test_report_inputs.py,
test/ins3d_cli/test_report_inputs3d.py)."""
from __future__ import annotations

import html
import re


def table_rows(page: str) -> dict[str, list[str]]:
    """{topic: [role, received, used, dropped]} of the page's inputs table."""
    part = page.split("<h2>Inputs</h2>", 1)[1].split("</table>", 1)[0]
    rows = {}
    for tr in re.findall(r"<tr>(.*?)</tr>", part, re.S)[1:]:
        cells = [html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", tr, re.S)]
        rows[cells[0]] = cells[1:]
    return rows


def agrees(rows: dict[str, list[str]], section: dict) -> None:
    assert set(rows) == set(section)
    for topic, e in section.items():
        role, received, used, _ = rows[topic]
        assert (role, int(received), int(used)) == (e["role"], e["messages"], e["used"])
