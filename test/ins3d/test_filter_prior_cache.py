"""``Ins3dForward.x_prior`` / ``P_prior`` (physical units) are made once and kept: two accesses
give the same array, equal to the construction from the scaled priors (before: rebuilt, the
whole (M, n, n) array, at every access)."""
from __future__ import annotations

import dataclasses

import numpy as np

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.ins3d.filter import run_forward
from flight_fdi.core.ins3d.model import Ins3dModel

from .conftest import flight


def test_priors_are_built_once_with_the_same_values():
    inp = from_flight(flight("cruise_turns", 60.0, "tactical", "baro", 3))
    m = Ins3dModel.from_grade("tactical", rows=3)
    fwd = run_forward(m, inp.steps, inp.refs, keep_prior=True, threads=1)
    assert fwd.xs_prior.shape[0] == inp.refs.t.size > 100
    s = fwd.s
    x, P = fwd.x_prior, fwd.P_prior
    assert fwd.x_prior is x and fwd.P_prior is P          # cached: the same objects
    # exactly the former construction (scaled prior times the scales)
    np.testing.assert_array_equal(x, fwd.xs_prior * s)
    np.testing.assert_array_equal(P, fwd.Ps_prior * s[:, None] * s[None, :])
    assert np.all(np.diagonal(P, axis1=1, axis2=2) > 0)
    # a pass made from it (dataclasses.replace) builds its own, from its own arrays
    other = dataclasses.replace(fwd, xs_prior=2.0 * fwd.xs_prior)
    np.testing.assert_array_equal(other.x_prior, 2.0 * x)
    assert other.P_prior is not P
    np.testing.assert_array_equal(other.P_prior, P)
    # without keep_prior: None, also cached
    plain = run_forward(m, inp.steps, inp.refs, threads=1)
    assert plain.x_prior is None and plain.P_prior is None
