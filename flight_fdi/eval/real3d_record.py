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
    dec = analysis.decided           # the decision reported (after removed glitches: the rest's)
    iso = dec.isolation
    cv = dec.decision_glr
    out.update({"best": iso.best, "rival": iso.rival, "reason": iso.reason,
                "best_statistic": cv[iso.best].statistic if iso.best else None,
                "rival_statistic": cv[iso.rival].statistic if iso.rival else None,
                "pair": iso.pair, "similarity": iso.similarity, "offset": iso.offset,
                "nonlinear": None if dec.nonlinear is None else
                f"{dec.nonlinear.before} -> {dec.nonlinear.after}",
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
    out.update(glitch_fields(analysis, pf))
    return out


def glitch_fields(analysis, pf: dict) -> dict:
    """The reference glitches of a record: the time of the largest outlier statistic over the
    rows (unconditional, before any removal), the glitches reported (``post_flight.glitches``:
    row, times, largest statistic), the times of every reference outlier named (those, or the
    ``glitch`` verdict's outliers without a removal), and whether the removal rounds ran and
    the rest named a fault (``analysis.sequential``)."""
    outl = [c for c in analysis.glr.values() if c.hypothesis.kind == "outliers"]
    top = max(outl, key=lambda c: c.statistic)
    seq = analysis.sequential
    named = [t for g in pf["glitches"] for t in g["times_s"]]
    f = pf.get("fault")
    if not named and f and f["kind"] == "outliers":
        named = sorted({f["onset_s"], f["end_s"]})
    return {"top_outlier_s": float(top.t[top.best]) if top.t.size else None,
            "glitches": [{"axis": g["axis"], "times_s": g["times_s"],
                          "statistic": g["statistic"]} for g in pf["glitches"]],
            "glitch_times_s": named,
            "glitch_rounds": 0 if seq is None else len(seq.removals),
            "glitch_rest_named": None if seq is None else bool(seq.found)}


#: reference glitches in the recordings themselves (time s from the recording's start, the
#: 1-Hz reference's update): vertical/path_14's RTK velocity glitch at the hard braking. The
#: evidence that it is in the RTK and not in a unit (docs/ins3d_real.md, "A reference glitch
#: and a fault in the same flight"): the four units -- independent IMUs, each with its own
#: INS -- have their largest east outlier statistic of the nominal run at the same update,
#: 26.5 s, and they share nothing but the reference.
REFERENCE_GLITCHES: dict[str, tuple[float, ...]] = {"vertical/path_14": (26.5,)}
#: a named outlier within this of a listed glitch is that glitch (half the reference period)
GLITCH_TOLERANCE_S = 0.5


def real_glitch(rec_out: dict, real: tuple[float, ...]) -> bool | None:
    """Whether the reference outliers a record names are all glitches of the recording itself
    (``REFERENCE_GLITCHES``); None when it names none."""
    named = rec_out.get("glitch_times_s") or []
    if not named:
        return None
    return all(any(abs(t - g) <= GLITCH_TOLERANCE_S for g in real) for t in named)


def judge(rec_out: dict, fault: "Fault | None", real_glitches: tuple[float, ...] = ()) -> str:
    """``right`` (the fault's sensor and axis, verdict failure; a reference glitch reported
    beside it only if it is one of the recording's own, ``real_glitches``), ``wrong`` (a
    confident isolation of anything else: another IMU axis, the reference, a glitch that is
    not the recording's, or the right sensor beside such a glitch), ``glitch`` (only the
    recording's own reference glitch named: the injected fault missed, nothing wrong named),
    ``ambiguous`` (candidates named, no fault), ``none`` (no isolation). Without a fault:
    ``false`` for an IMU sensor named, ``reference`` for the reference named (``glitch``: only
    the recording's own glitch), else as above."""
    v, sensor, axis = rec_out["verdict"], rec_out["sensor"], rec_out["axis"]
    own = real_glitch(rec_out, real_glitches)
    if v == "ambiguous":
        return "ambiguous"
    if sensor is None:
        return "none"
    if v == "glitch" and own:
        return "glitch"
    if fault is None:
        return "reference" if sensor == "reference" else "false"
    if v == "failure" and sensor == fault.sensor and axis == fault.axis and own is not False:
        return "right"
    return "wrong"


__all__ = ["GLITCH_TOLERANCE_S", "REFERENCE_GLITCHES", "judge", "real_glitch", "record"]
