"""The 3-D study end to end on tiny flights: the plan (seeded, spread over axes and levels), the
records independent of the worker count, the ladder's stopping rule, the configuration errors."""
from __future__ import annotations

import json

import pytest

from flight_fdi.eval import ladder3d
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.montecarlo3d import SCENARIOS, Study3DConfig, plan_study, run_study


def test_plan_is_seeded_and_spread_over_axes_and_levels():
    cfg = Study3DConfig(nominal=3, per_scenario=18, scenarios=("gyro_step", "ref_jump"),
                        levels={"gyro_step": (0.1, 0.05)}, duration_s=600.0, seed=7)
    cases = plan_study(cfg)
    assert cases == plan_study(cfg)
    assert cases != plan_study(Study3DConfig(**{**cfg.__dict__, "seed": 8}))
    assert [c.index for c in cases] == list(range(3 + 36))
    gyro = [c for c in cases if c.scenario == "gyro_step"]
    assert sorted({(c.axis, c.level) for c in gyro}) == [
        (a, lv) for a in ("x", "y", "z") for lv in (0.05, 0.1)]
    assert {c.axis for c in cases if c.scenario == "ref_jump"} == {"east", "north"}
    assert all(60.0 <= c.onset_s <= 480.0 for c in gyro)
    assert {c.magnitude > 0 for c in gyro} == {True, False}
    f = gyro[0].fault()
    assert (f.target, f.type, f.axis) == ("gyro", "step", gyro[0].axis)
    assert abs(f.magnitude) == pytest.approx(gyro[0].level * SCENARIOS["gyro_step"][6])
    ref = next(c for c in cases if c.scenario == "ref_jump" and c.axis == "north").fault()
    assert ref.axis == "y"                      # the simulator's ENU axis


@pytest.mark.parametrize("kwargs, match", [
    ({"scenarios": ("accel_stp",)}, "unknown scenario"),
    ({"levels": {"accel_step": (0.3, -1.0)}}, "levels"),
    ({"duration_s": 30.0}, "duration_s"),
    ({"profile": "loop"}, "profile"),
    ({"grade": "consumer"}, "grade"),
    ({"onset_window": (0.5, 0.2)}, "onset_window"),
    ({"nominal": -1}, "nominal"),
    ({"nominal": 0, "per_scenario": 0}, "no flights"),
])
def test_bad_configuration_is_one_clear_error(kwargs, match):
    with pytest.raises(EvalError, match=match):
        Study3DConfig(**kwargs)


@pytest.mark.slow
def test_records_do_not_depend_on_the_worker_count():
    cfg = Study3DConfig(nominal=1, per_scenario=1, scenarios=("accel_step", "ref_jump"),
                        duration_s=120.0, profile="cruise_turns", seed=3)
    one = run_study(cfg, jobs=1)
    two = run_study(cfg, jobs=2)
    assert two.jobs == 2 and "local Dask cluster" in two.engine
    assert json.dumps(one.records, sort_keys=True) == json.dumps(two.records, sort_keys=True)
    assert one.metrics == two.metrics
    r = one.records[1]
    assert (r["scenario"], r["sensor"], r["kind"]) == ("accel_step", "accelerometer", "step")
    assert set(r) >= {"ins3d", "single_axis", "onset_in_turn", "next_turn_s"}
    assert set(r["single_axis"]["channels"]) == {"east", "north"}


def test_ladder_climbs_down_while_it_passes_and_up_while_it_fails(monkeypatch):
    """From a passing top the rungs go down until the right rate drops below 95 % (the smallest
    level is the last passing rung); from a failing top they go up until one passes; a group
    that never passes reports none."""
    calls = []

    def fake_run_cases(cases, config, jobs=1, progress=False, on_record=None, scheduler=None,
                       info=None, desc=""):
        calls.append(len(cases))
        out = []
        for c in cases:
            # accelerometer: isolated down to 0.25 mg; gyro x/y from 0.8 deg/h up; z never
            ok = (c.level >= 0.25) if c.scenario == "accel_step" else \
                (c.axis != "z" and c.level >= 0.8)
            iso = {"verdict": "failure", "isolation": "single", "sensor": c.sensor,
                   "axis": c.axis, "kind": c.kind, "onset_s": c.onset_s,
                   "magnitude": c.magnitude, "candidates": []}
            out.append({"index": c.index, "scenario": c.scenario, "sensor": c.sensor,
                        "axis": c.axis, "ins3d": iso if ok else {**iso, "axis": "q"}})
        return out

    monkeypatch.setattr(ladder3d, "run_cases", fake_run_cases)
    lad = ladder3d.run_ladder(Study3DConfig(duration_s=600.0), runs=4, rungs=4)
    by = {(g["scenario"], g["axis"]): g for g in lad["groups"]}
    acc = by[("accel_step", "x")]
    assert [r["level"] for r in acc["rungs"]] == [1.0, 0.5, 0.25, 0.125]
    assert acc["smallest_95"] == 0.25 and not acc["bottom_reached"]
    assert acc["direction"] == "down" and acc["rungs"][3]["wrong"] == 4
    gx = by[("gyro_step", "x")]
    assert gx["direction"] == "up"
    assert [r["level"] for r in gx["rungs"]] == [0.2, 0.4, 0.8]
    assert gx["smallest_95"] == 0.8
    gz = by[("gyro_step", "z")]
    assert [r["level"] for r in gz["rungs"]] == [0.2, 0.4, 0.8, 1.6]
    assert gz["smallest_95"] is None
    assert calls == [6 * 4, 6 * 4, 6 * 4, 4 * 4]     # gyro x/y stop once they pass at 0.8
    text = ladder3d.format_ladder(lad)
    assert "| navigation | gyro_step | z | not reached (> 1.6 deg/h) |" in text
    assert "| navigation | accel_step | y | 0.25 mg |" in text


def test_axes_re_run_a_subset_of_the_same_flights():
    """Study3DConfig.axes keeps the whole plan's flights on those axes: same index, seeds,
    level, onset and sign (a study re-run on one axis is the same flights)."""
    cfg = Study3DConfig(nominal=2, per_scenario=18, scenarios=("gyro_step", "accel_step"),
                        duration_s=600.0, seed=7)
    full = plan_study(cfg)
    sub = plan_study(Study3DConfig(**{**cfg.__dict__, "axes": ("z",)}))
    assert sub == [c for c in full if c.scenario == "nominal" or c.axis == "z"]
    assert {c.axis for c in sub if c.scenario != "nominal"} == {"z"}
    assert len([c for c in sub if c.scenario != "nominal"]) == 12
    with pytest.raises(EvalError, match="axes"):
        Study3DConfig(**{**cfg.__dict__, "axes": ("east",)})
