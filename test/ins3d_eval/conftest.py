"""Fixtures shared by the ins3d evaluation tests."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def pf():
    """``power_bound.PowerFlight`` of 600 s of cruise_turns (first turn 303-372 s), navigation
    grade, nominal (the sweeps' data are drawn from the filter's own model)."""
    from flight_fdi.eval.montecarlo3d import Case3D, Study3DConfig
    from flight_fdi.eval.onset_bound import Signatures, analyse_case
    from flight_fdi.eval.power_bound import PowerFlight

    cfg = Study3DConfig(nominal=1, per_scenario=0, duration_s=600.0, profile="cruise_turns",
                        single_axis=False)
    _, an = analyse_case(Case3D(0, "nominal", 11, 12), cfg)
    return PowerFlight(Signatures(an))
