"""Models: exact discretization, batch discretization of jittered dts, observability, YAML."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from flight_fdi.core import CoreError, attitude_axis, ins_channel
from flight_fdi.core.models import model_from_dict


def _qd_by_quadrature(A, Qc, dt):
    """Qd = int_0^dt e^{As} Qc e^{A^T s} ds by integrating the Lyapunov ODE (independent of Van Loan)."""
    n = A.shape[0]
    sol = solve_ivp(lambda s, q: (A @ q.reshape(n, n) + q.reshape(n, n) @ A.T + Qc).ravel(),
                    (0.0, dt), np.zeros(n * n), rtol=1e-12, atol=1e-30)
    return sol.y[:, -1].reshape(n, n)


@pytest.mark.parametrize("model", [ins_channel(), attitude_axis()], ids=lambda m: m.name)
def test_discretize_matches_expm_and_quadrature(model):
    Phi, Qd, _ = model.discretize(0.1)
    np.testing.assert_allclose(Phi, expm(model.A * 0.1), rtol=1e-12, atol=1e-15)
    ref = _qd_by_quadrature(model.A, model.Qc, 0.1)
    scale = np.sqrt(np.outer(np.diag(ref), np.diag(ref))) + 1e-300
    assert np.max(np.abs(Qd - ref) / scale) < 1e-6


def test_default_ins_channel_is_rank_deficient_and_says_so():
    # det of the observability matrix is g^2 (1/(tau_a tau_w) - 1/tau_a^2): zero when tau_a == tau_w
    rep = ins_channel().observability(3600.0, 1.0)
    assert rep.rank == 3 and not rep.observable
    assert "NOT observable" in rep.message()
    rep2 = ins_channel(tau_w=7200.0).observability(3600.0, 1.0)
    assert rep2.rank == 4
    # velocity error is far better observed than the gyro drift over one minute
    short = ins_channel().observability(60.0, 0.1)
    assert short.std_ratio[0] < 0.2 and short.std_ratio[3] > 0.9
    assert "gyro_drift" in short.weak_states()


def test_attitude_axis_is_observable():
    rep = attitude_axis().observability(10.0)
    assert rep.observable and max(rep.std_ratio) < 0.1


def test_model_from_dict_and_errors():
    data = {"name": "cv", "states": [{"name": "p", "unit": "m"}, {"name": "v", "unit": "m/s"}],
            "A": [[0, 1], [0, 0]], "G": [[0], [0.1]], "H": [[1, 0]], "R": [[0.01]],
            "P0": [[1, 0], [0, 1]]}
    m = model_from_dict(data)
    np.testing.assert_allclose(m.Qc, [[0, 0], [0, 0.01]])
    with pytest.raises(CoreError, match="missing key 'H'"):
        model_from_dict({k: v for k, v in data.items() if k != "H"})
    with pytest.raises(CoreError, match="R: not positive definite"):
        model_from_dict({**data, "R": [[0.0]]})
    with pytest.raises(CoreError, match="NaN"):
        model_from_dict({**data, "A": [[0, float("nan")], [0, 0]]})
    with pytest.raises(CoreError, match="exactly one of"):
        model_from_dict({**data, "Qc": [[0, 0], [0, 1]]})
    with pytest.raises(CoreError, match="dt must be finite"):
        m.discretize(-1.0)
