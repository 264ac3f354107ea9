"""``Ins3dForward.prior(j)``: one update's prior state and covariance in physical units, equal to
the rows of ``x_prior`` / ``P_prior`` (which build the whole (M, n, n) array at each access: the
nonlinear check's window needs one row)."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.filter import run_forward
from flight_fdi.core.ins3d.model import Ins3dModel

from .conftest import flight


def test_one_prior_equals_the_rows_of_the_whole_arrays():
    inp = from_flight(flight("cruise_turns", 60.0, "tactical", "baro", 3))
    m = Ins3dModel.from_grade("tactical", rows=3)
    fwd = run_forward(m, inp.steps, inp.refs, keep_prior=True, threads=1)
    assert fwd.xs_prior.shape[0] == inp.refs.t.size > 100
    s = fwd.s
    x, P = fwd.x_prior, fwd.P_prior
    np.testing.assert_array_equal(x, fwd.xs_prior * s)
    np.testing.assert_array_equal(P, fwd.Ps_prior * s[:, None] * s[None, :])
    for j in (0, 57, inp.refs.t.size - 1):
        xj, Pj = fwd.prior(j)
        np.testing.assert_array_equal(xj, x[j])
        np.testing.assert_array_equal(Pj, P[j])
        assert np.all(np.diag(Pj) > 0)
    plain = run_forward(m, inp.steps, inp.refs, threads=1)
    assert plain.x_prior is None and plain.P_prior is None
    with pytest.raises(CoreError, match="keep_prior"):
        plain.prior(0)
