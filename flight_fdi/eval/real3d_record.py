"""The measured outcome of one real-data analysis (``record``) and its judgement against the
injected fault (``judge``): the records of tools/ins3d_real_eval.py (docs/ins3d_real.md)."""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .real3d import Fault


def record(analysis, t0: float = 0.0) -> dict:
    """The measured outcome of one analysis: verdict, named fault (sensor, axis, kind, onset,
    magnitude), the largest GLR statistic per kind, the thresholds, beta^2 per row, latency;
    whether a relinearisation was tried (``post_flight.relinearization``), a pass kept, how
    many; and the model's validity (``post_flight.model_validity``: valid, largest smoothed
    attitude error in deg; None without the post-flight part)."""
    pf = analysis.post_flight_dict(t0=t0)
    summ = analysis.summary()
    f = pf.get("fault")
    out = {"verdict": pf["verdict"], "isolation": pf.get("isolation"),
           "sensor": f and f["sensor"], "axis": f and f["axis"], "kind": f and f["kind"],
           "onset_s": f and f["onset_s"], "magnitude": f and f["magnitude"],
           "statistic": f and f["statistic"],
           "candidates": [f"{c['sensor']} {c['axis']} {c['kind']}" for c in pf["candidates"]],
           "thresholds": dict(pf["glr"]["thresholds"]),
           "seed_verdict": pf["seed_method"]["verdict"],
           "seed_element": pf["seed_method"]["element"],
           "beta2": summ["beta2_mean"], "beta2_rows": summ["beta2_row_mean"],
           "latency_s": summ["final_state"].get("latency")}
    iso = analysis.isolation
    cv = analysis.decision_glr
    out.update({"best": iso.best, "rival": iso.rival, "reason": iso.reason,
                "best_statistic": cv[iso.best].statistic if iso.best else None,
                "rival_statistic": cv[iso.rival].statistic if iso.rival else None,
                "pair": iso.pair, "similarity": iso.similarity, "offset": iso.offset,
                "nonlinear": None if analysis.nonlinear is None else
                f"{analysis.nonlinear.before} -> {analysis.nonlinear.after}",
                "turn_on": [{k: t[k] for k in ("sensor", "axis", "magnitude", "magnitude_std",
                                                "prior_sigmas", "statistic")}
                            for t in pf["turn_on_bias"]]})
    rel, val = pf.get("relinearization"), pf.get("model_validity")
    out.update({"relinearisation_tried": rel is not None,       # the first pass left it
                "relinearised": bool(rel and rel["passes"] > 0),    # a pass about it kept
                "relinearisation_passes": rel["passes"] if rel else 0,
                "model_valid": None if val is None else bool(val["valid"]),
                "attitude_error_max_deg": None if val is None else val["attitude_error_max_deg"]})
    for kind in ("step", "ramp", "jump", "outliers"):     # unconditional (not given turn-on)
        top = max((c for c in analysis.glr.values() if c.hypothesis.kind == kind),
                  key=lambda c: c.statistic)
        out[f"max_{kind}"] = float(top.statistic)
        out[f"max_{kind}_hyp"] = top.hypothesis.name
    return out


def judge(rec_out: dict, fault: "Fault | None") -> str:
    """``right`` (the fault's sensor and axis, verdict failure), ``wrong`` (a confident
    isolation of anything else: another IMU axis, the reference, a glitch), ``ambiguous``
    (candidates named, no fault), ``none`` (no isolation). Without a fault: ``false`` for an
    IMU sensor named, ``reference`` for the reference named, else as above."""
    v, sensor, axis = rec_out["verdict"], rec_out["sensor"], rec_out["axis"]
    if v == "ambiguous":
        return "ambiguous"
    if sensor is None:
        return "none"
    if fault is None:
        return "reference" if sensor == "reference" else "false"
    if v == "failure" and sensor == fault.sensor and axis == fault.axis:
        return "right"
    return "wrong"


__all__ = ["judge", "record"]
