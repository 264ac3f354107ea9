"""The text report of a Monte Carlo study's metrics (:func:`format_metrics`: plain text and
Markdown tables of :func:`flight_fdi.eval.study_metrics.summarize`'s output)."""
from __future__ import annotations

from .decisions import ISOLATION_LEVEL, METHODS, fmt_num, fmt_pct
from .onset import format_onset_errors


def format_metrics(metrics: dict) -> str:
    """A human-readable report of :func:`summarize`'s metrics (plain text / Markdown tables)."""
    fl = metrics["flights"]
    fa = metrics["false_alarms"]
    lines = [f"flights: {fl['nominal']} nominal, {fl['accel']} accelerometer, {fl['gyro']} gyro",
             "",
             "false alarms on nominal flights:",
             "  in-flight gate: per sample "
             f"{fmt_num(fa['in_flight']['per_sample_exceed_rate'], '.2e')}"
             f" (beta^2 > gate), per flight {fmt_pct(fa['in_flight']['per_flight_rate'])} "
             f"(M-of-N alarm)",
             f"  seed method: per sample {fmt_num(fa['seed']['per_sample_J_exceed_rate'], '.2e')}"
             f" (J > gamma^2), per flight {fmt_pct(fa['seed']['per_flight_rate'])}",
             f"  GLR: per flight {fmt_pct(fa['glr']['per_flight_rate'])}",
             "",
             "| detector | type I (false alarm) | type II (missed) | confidently wrong element "
             "| ambiguous |",
             "|---|---|---|---|---|"]
    for det, e in metrics["error_rates"].items():
        wrong = fmt_pct(e.get("wrong_isolation_rate")) if "wrong_isolation_rate" in e else "n/a"
        amb = fmt_pct(e.get("ambiguous_rate")) if "ambiguous_rate" in e else "n/a"
        lines.append(f"| {det} | {fmt_pct(e['type_I'])} ({e['false_alarms']}/{e['nominal']}) | "
                     f"{fmt_pct(e['type_II'])} ({e['missed']}/{e['faulty']}) | {wrong} | {amb} |")
    for m, cm in metrics["confusion"].items():
        lines += ["", f"confusion matrix, {m} (rows: true, columns: isolated)",
                  "| true \\ isolated | " + " | ".join(cm["predicted"]) + " |",
                  "|---" * (len(cm["predicted"]) + 1) + "|"]
        for name, row in zip(cm["true"], cm["counts"]):
            lines.append(f"| {name} | " + " | ".join(str(c) for c in row) + " |")
    for kind, d in metrics["detection_delay_s"].items():
        lines += ["", f"in-flight detection delay, {kind}: n {d['n']}, median "
                  f"{fmt_num(d['median'], '.1f')} s, 5-95% {fmt_num(d['p05'], '.1f')} .. "
                  f"{fmt_num(d['p95'], '.1f')} s"]
    lines.append("")
    for m in METHODS:
        for which, label in (("onset_error_s", "isolated"), ("onset_error_detected_s",
                                                             "detected")):
            for kind, d in metrics[which][m].items():
                lines.append(f"onset error {m}, {kind} ({label}): n {d['n']}, median "
                             f"{fmt_num(d['median'], '.2f')} s, "
                             f"5-95% {fmt_num(d['p05'], '.2f')} .. "
                             f"{fmt_num(d['p95'], '.2f')} s")
    for kind, d in metrics["magnitude_error_relative"]["glr"].items():
        lines.append(f"magnitude error glr, {kind} (relative, isolated): n {d['n']}, median "
                     f"{fmt_pct(d['median'])}, 5-95% {fmt_pct(d['p05'])} .. {fmt_pct(d['p95'])}")
    for kind, rows in metrics["by_level"].items():
        lines += ["", f"{kind} faults by magnitude:",
                  "| level | n | in-flight detected | median delay s | seed detected | "
                  "seed isolated | GLR detected | GLR isolated | GLR onset err s | "
                  "GLR magnitude err |", "|---" * 10 + "|"]
        for r in rows:
            lines.append(
                f"| {r['level']:g} {r['unit']} | {r['n']} | {fmt_pct(r['in_flight_detected'])} | "
                f"{fmt_num(r['delay_median_s'], '.1f')} | {fmt_pct(r['seed_detected'])} | "
                f"{fmt_pct(r['seed_isolated'])} | {fmt_pct(r['glr_detected'])} | "
                f"{fmt_pct(r['glr_isolated'])} | {fmt_num(r['glr_onset_error_median_s'], '.1f')} | "
                f"{fmt_pct(r['glr_magnitude_error_median'])} |")
    lines += ["", f"smallest fault isolated in >= {100 * ISOLATION_LEVEL:.0f}% of runs "
              "(at that level and every larger one):"]
    for m, per in metrics["smallest_isolated_95"].items():
        parts = [f"{k}: " + ("not reached" if v["level"] is None else f"{v['level']:g} {v['unit']}")
                 for k, v in per.items()]
        lines.append(f"  {m}: " + ", ".join(parts))
    if metrics.get("onset_error_glr"):
        lines += ["", "GLR onset error where GLR names the true fault (isolated, or among the "
                      "candidates of an ambiguous result):", "",
                  format_onset_errors(metrics["onset_error_glr"])]
    return "\n".join(lines)
