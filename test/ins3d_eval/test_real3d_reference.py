"""A real-data fault run keeps the nominal run's reference (``real3d.contract_arrays``'s
``reference_of``): the reference velocity is the RTK mean over its span plus the INS's own shape
within the span, and that shape must come from the INS before the fault -- a reference does not
see the IMU under test. Built from the faulty INS it carried the fault's curvature, which no
exact removal of the fault can take back (on the full recordings: the 4 gyro steps of 3000 deg/h
named an accelerometer ramp with confidence, docs/ins3d_real.md)."""
from __future__ import annotations

import math

import numpy as np

from flight_fdi.core.ins3d.analysis import initial_covariance
from flight_fdi.core.ins3d.data import coarsen
from flight_fdi.core.ins3d.model import Ins3dModel
from flight_fdi.core.ins3d.nonlinear import corrected, neg2_log_likelihood
from flight_fdi.eval import real3d as R


def test_the_fault_run_reference_is_the_nominal_one(rec, cal):
    fault = R.Fault("gyro", "y", math.radians(5.0), 5.0)
    nominal = R.contract_arrays(rec, *cal)
    own = R.contract_arrays(fault.apply(rec), *cal)
    kept = R.contract_arrays(fault.apply(rec), *cal, reference_of=rec)
    np.testing.assert_array_equal(kept["v_ref"], nominal["v_ref"])
    assert np.abs(own["v_ref"] - nominal["v_ref"]).max() > 0.02      # m/s (measured 0.045)
    # everything else is the faulty unit's
    np.testing.assert_array_equal(kept["v"], own["v"])
    np.testing.assert_array_equal(kept["q"], own["q"])


def test_the_fault_removed_exactly_gives_the_nominal_likelihood_back(rec, cal):
    """The 5 deg/s gyro y step at 5 s removed exactly (on the input grid, from its first
    faulty step): -2 ln L of the no-fault filter equals the nominal flight's to 0.5 with the
    nominal reference; with the faulty INS's shape in the reference it stays 2.5 off."""
    st = R.Settings()
    model = Ins3dModel.from_grade(st.grade(), rows=2, vertical="free", latency=True)
    fault = R.Fault("gyro", "y", math.radians(5.0), 5.0)
    clean = R.build_contract(rec, *cal)
    steps, refs = coarsen(clean.steps, clean.refs, 0.1)
    P0 = initial_covariance(model, steps.C[0], steps.f_n[0], float(steps.lat[0]), False)
    nominal = neg2_log_likelihood(model, steps, refs, P0)

    def removed(reference_of):
        inp = R.build_contract(fault.apply(rec), *cal, reference_of=reference_of)
        k0 = int(np.flatnonzero(np.abs(inp.steps.w_b - clean.steps.w_b).max(axis=1) > 0)[0])
        s, r = corrected(model, inp.steps, inp.refs, "gyro", "y", "step", k0, fault.magnitude)
        return neg2_log_likelihood(model, *coarsen(s, r, 0.1), P0)

    assert abs(removed(rec) - nominal) < 0.5
    assert removed(None) - nominal > 1.5
