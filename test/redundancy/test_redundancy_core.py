"""KF2 / AF gains, steady-state covariances and sensor criticality (seed 001).

Expected values come from closed forms (scalar Riccati), FilterPy's Kalman filter iterated to
steady state, a brute-force Riccati recursion, and the textbook gain on the reduced rows.
"""
from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from filterpy.kalman import KalmanFilter as FilterPyKF

from flight_fdi.core.errors import CoreError
from flight_fdi.core.models import LinearModel
from flight_fdi.core.redundancy import (_dare_doubling, accuracy, af_gain, anomaly_matrix,
                                        criticality, exclusion_matrix, kf2_gain,
                                        load_redundant_model, pattern_of,
                                        redundant_model_from_dict, steady_state,
                                        steady_state_mode)

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "config" / "models" / "redundant_5ch.yaml"


# ------------------------------------------------------------------------ helpers (independent)

def riccati_iterate(Phi, Q, H, R, P0, steps=20000, tol=1e-15):
    """Brute-force Riccati recursion (predict, update) until P stops changing."""
    n = Phi.shape[0]
    P = P0.copy()
    for _ in range(steps):
        Pm = Phi @ P @ Phi.T + Q
        if H.shape[0]:
            S = H @ Pm @ H.T + R
            K = Pm @ H.T @ np.linalg.inv(S)
            Pn = (np.eye(n) - K @ H) @ Pm
        else:
            Pn = Pm
        Pn = 0.5 * (Pn + Pn.T)
        if np.max(np.abs(Pn - P)) <= tol * max(1.0, np.max(np.abs(Pn))):
            return Pn
        P = Pn
    return P


def laub_steady(Phi, Q, H, R, scale=None):
    """Steady-state a posteriori P by Laub's eigenvector method: the stable invariant subspace
    [U1; U2] of the symplectic matrix of the filter DARE gives P- = U2 U1^-1 (a third algorithm,
    independent of scipy's QZ and of doubling); computed in coordinates x / scale."""
    n = Phi.shape[0]
    s = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    A = (Phi * (s[None, :] / s[:, None])).T           # control form: A = Phi^T
    Qs = Q / np.outer(s, s)
    Hs = H * s[None, :]
    G = Hs.T @ np.linalg.solve(R, Hs)
    Ait = np.linalg.inv(A).T
    Z = np.block([[A + G @ Ait @ Qs, -G @ Ait], [-Ait @ Qs, Ait]])
    lam, V = np.linalg.eig(Z)
    stable = V[:, np.abs(lam) < 1.0]
    assert stable.shape[1] == n
    Pm = np.real(stable[n:] @ np.linalg.inv(stable[:n]))
    Pm = 0.5 * (Pm + Pm.T)
    S = Hs @ Pm @ Hs.T + R
    P = Pm - Pm @ Hs.T @ np.linalg.solve(S, Hs @ Pm)
    return P * np.outer(s, s)


def filterpy_steady(Phi, Q, H, R, steps=3000):
    kf = FilterPyKF(dim_x=Phi.shape[0], dim_z=H.shape[0])
    kf.F, kf.Q, kf.H, kf.R = Phi, Q, H, R
    kf.P = np.eye(Phi.shape[0])
    for _ in range(steps):
        kf.predict()
        kf.update(np.zeros(H.shape[0]))
    return kf.P.copy(), kf.K.copy()


def random_model(rng, n, m):
    """A stable, observable random discrete model with m measurement rows."""
    A = rng.normal(size=(n, n))
    Phi = 0.95 * A / max(abs(np.linalg.eigvals(A)))
    G = rng.normal(size=(n, n))
    Q = 0.1 * G @ G.T + 1e-3 * np.eye(n)
    H = rng.normal(size=(m, n))
    L = rng.normal(size=(m, m))
    R = 0.05 * L @ L.T + 0.05 * np.eye(m)
    return Phi, Q, H, R


# ------------------------------------------------------------------------ one-step math

def test_exclusion_and_anomaly_matrices():
    E = exclusion_matrix(5, [1, 3])
    np.testing.assert_array_equal(E, np.eye(5)[[0, 2, 4]])
    C = anomaly_matrix(5, [3, 1])
    np.testing.assert_array_equal(C, np.eye(5)[:, [1, 3]])
    assert exclusion_matrix(3, []).shape == (3, 3) and anomaly_matrix(3, []).shape == (3, 0)
    with pytest.raises(CoreError, match="not a row index"):
        exclusion_matrix(3, [3])


def test_af_gain_is_the_kalman_gain_of_the_remaining_rows():
    rng = np.random.default_rng(1)
    n, m = 4, 5
    _, _, H, R = random_model(rng, n, m)
    B = rng.normal(size=(n, n))
    P = B @ B.T + np.eye(n)
    failed = [1, 4]
    keep = [0, 2, 3]
    K, S = af_gain(P, H, R, failed)
    Hr, Rr = H[keep], R[np.ix_(keep, keep)]
    Kr = P @ Hr.T @ np.linalg.inv(Hr @ P @ Hr.T + Rr)
    np.testing.assert_allclose(K[:, keep], Kr, rtol=1e-10)
    np.testing.assert_array_equal(K[:, failed], 0.0)
    np.testing.assert_allclose(S, H @ P @ H.T + R, rtol=1e-12)
    # the seed's form K = P H^T E^T (E S E^T)^-1 E
    E = exclusion_matrix(m, failed)
    np.testing.assert_allclose(K, P @ H.T @ E.T @ np.linalg.inv(E @ S @ E.T) @ E, rtol=1e-10)
    # nothing failed: the plain Kalman gain
    K0, _ = af_gain(P, H, R)
    np.testing.assert_allclose(K0, P @ H.T @ np.linalg.inv(H @ P @ H.T + R), rtol=1e-10)


def test_kf2_gain_adds_the_anomaly_covariance_and_tends_to_af():
    rng = np.random.default_rng(2)
    n, m = 3, 4
    _, _, H, R = random_model(rng, n, m)
    P = np.diag([1.0, 2.0, 0.5])
    failed = [2, 0]
    Gamma = np.diag([3.0, 7.0])  # rows 0 and 2 (sorted order)
    K, S = kf2_gain(P, H, R, failed, Gamma)
    R2 = R.copy()
    R2[0, 0] += 3.0
    R2[2, 2] += 7.0
    np.testing.assert_allclose(S, H @ P @ H.T + R2, rtol=1e-12)
    np.testing.assert_allclose(K, P @ H.T @ np.linalg.inv(S), rtol=1e-10)
    # Gamma -> infinity: KF2 -> AF
    Kbig, _ = kf2_gain(P, H, R, failed, [1e12, 1e12])
    Kaf, _ = af_gain(P, H, R, failed)
    np.testing.assert_allclose(Kbig, Kaf, atol=1e-9)
    with pytest.raises(CoreError, match="Gamma"):
        kf2_gain(P, H, R, failed)
    with pytest.raises(CoreError, match="2 x 2"):
        kf2_gain(P, H, R, failed, np.eye(3))


def test_accuracy_is_trace_of_DP():
    D = np.diag([1.0, 2.0])
    P = np.array([[3.0, 1.0], [1.0, 5.0]])
    assert accuracy(D, P) == 13.0
    assert accuracy(D, np.full((2, 2), np.inf)) == math.inf


# ------------------------------------------------------------------------ steady state

@pytest.mark.parametrize("q, r", [(1.0, 1.0), (0.01, 4.0), (5.0, 0.1)])
def test_scalar_random_walk_closed_form(q, r):
    """x+ = x + w, z = x + v: P- = (q + sqrt(q^2 + 4 q r)) / 2, P = P- r / (P- + r)."""
    ss = steady_state([[1.0]], [[q]], [[1.0]], [[r]])
    Pm = 0.5 * (q + math.sqrt(q * q + 4 * q * r))
    assert ss.P_prior[0, 0] == pytest.approx(Pm, rel=1e-10)
    assert ss.P[0, 0] == pytest.approx(Pm * r / (Pm + r), rel=1e-10)
    assert ss.K[0, 0] == pytest.approx(Pm / (Pm + r), rel=1e-10)
    # two identical sensors of variance r are one sensor of variance r / 2
    two = steady_state([[1.0]], [[q]], [[1.0], [1.0]], np.diag([r, r]))
    one = steady_state([[1.0]], [[q]], [[1.0]], [[r / 2]])
    assert two.P[0, 0] == pytest.approx(one.P[0, 0], rel=1e-10)


@pytest.mark.parametrize("seed", range(4))
def test_steady_state_matches_filterpy_and_iteration(seed):
    rng = np.random.default_rng(100 + seed)
    Phi, Q, H, R = random_model(rng, 4, 3)
    ss = steady_state(Phi, Q, H, R)
    P_fp, K_fp = filterpy_steady(Phi, Q, H, R)
    np.testing.assert_allclose(ss.P, P_fp, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(ss.K, K_fp, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(ss.P, riccati_iterate(Phi, Q, H, R, np.eye(4)), rtol=1e-8,
                               atol=1e-12)


def test_doubling_solves_the_same_dare_as_scipy(monkeypatch):
    rng = np.random.default_rng(7)
    Phi, Q, H, R = random_model(rng, 5, 2)
    X = _dare_doubling(Phi.T, H.T @ np.linalg.solve(R, H), Q)
    ss = steady_state(Phi, Q, H, R)
    assert ss.method == "scipy"
    np.testing.assert_allclose(X, ss.P_prior, rtol=1e-9, atol=1e-13)
    # when scipy's solver fails, the doubling fallback gives the same steady state
    import flight_fdi.core.redundancy as red

    def broken(*a, **k):
        raise np.linalg.LinAlgError("singular pencil")

    monkeypatch.setattr(red, "solve_discrete_are", broken)
    fb = steady_state(Phi, Q, H, R)
    assert fb.method == "doubling"
    np.testing.assert_allclose(fb.P, ss.P, rtol=1e-9, atol=1e-13)


def test_scaled_coordinates_keep_stiff_models_accurate():
    """The INS-like magnitudes (m/s next to rad/s): scaling must not change the answer."""
    Phi = np.array([[1.0, -0.098], [1e-6, 1.0]])
    Q = np.diag([1e-6, 1e-16])
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.01]])
    a = steady_state(Phi, Q, H, R, scale=[0.1, 1e-5])
    ref = laub_steady(Phi, Q, H, R, scale=[0.1, 1e-5])
    np.testing.assert_allclose(np.diag(a.P), np.diag(ref), rtol=1e-7)
    # an unscaled solution of the same DARE agrees too (the scaling is only for accuracy)
    b = steady_state(Phi, Q, H, R)
    np.testing.assert_allclose(np.diag(b.P), np.diag(ref), rtol=1e-5)


def test_undetectable_mode_has_no_finite_steady_state():
    # an unstable state that the remaining rows do not see
    Phi = np.diag([1.01, 0.5])
    ss = steady_state(Phi, np.eye(2) * 0.1, np.array([[0.0, 1.0]]), [[1.0]])
    assert not ss.finite and "not observed" in ss.reason
    assert accuracy(np.eye(2), ss.P) == math.inf
    # no measurement at all, stable: the Lyapunov solution P = Phi P Phi^T + Q
    Phi = np.diag([0.9, 0.5])
    ss = steady_state(Phi, np.diag([1.0, 2.0]), np.zeros((0, 2)), np.zeros((0, 0)))
    np.testing.assert_allclose(np.diag(ss.P), [1 / (1 - 0.81), 2 / (1 - 0.25)], rtol=1e-10)


# ------------------------------------------------------------------------ KF2 never worse than AF

def _all_sets(ns):
    return [c for r in range(ns + 1) for c in itertools.combinations(range(ns), r)]


def test_kf2_at_least_as_accurate_as_af_on_the_example():
    model, spec = load_redundant_model(EXAMPLE)
    res = criticality(model, spec)
    assert len(res.sets) == 2 ** len(spec.sensors)
    assert res.kf2_never_worse()
    for s in res.sets:
        assert s.J["kf2"] <= s.J["af"] * (1 + 1e-12)
        if s.failed:
            assert s.J["kf2"] >= res.J_nominal * (1 - 1e-12)  # a fault never helps


@pytest.mark.parametrize("seed", range(6))
def test_kf2_at_least_as_accurate_as_af_on_random_models(seed):
    """P_AF - P_KF2 is positive semidefinite for every fault set (so tr(D P) too, D >= 0)."""
    rng = np.random.default_rng(200 + seed)
    n, m = int(rng.integers(2, 5)), int(rng.integers(2, 5))
    Phi, Q, H, R = random_model(rng, n, m)
    gamma = 10.0 * np.diag(R) * rng.uniform(1, 100, m)
    for failed in _all_sets(m)[1:]:
        kf2 = steady_state_mode(Phi, Q, H, R, "kf2", failed, gamma)
        af = steady_state_mode(Phi, Q, H, R, "af", failed)
        if not af.finite:
            continue  # KF2 is finite (it still uses the rows), AF has no steady state
        gap = np.linalg.eigvalsh(af.P - kf2.P)
        assert gap.min() >= -1e-9 * max(1.0, np.abs(af.P).max()), (failed, gap)
        # and AF equals the filter of the remaining rows, computed independently
        keep = [i for i in range(m) if i not in failed]
        P_it = riccati_iterate(Phi, Q, H[keep], R[np.ix_(keep, keep)], np.eye(n))
        np.testing.assert_allclose(af.P, P_it, rtol=1e-7, atol=1e-12)


def test_af_accuracy_degrades_monotonically_with_more_failures():
    model, spec = load_redundant_model(EXAMPLE)
    res = criticality(model, spec)
    by_set = {s.failed: s.J["af"] for s in res.sets}
    for failed, J in by_set.items():
        for extra in range(len(spec.sensors)):
            if extra not in failed:
                bigger = tuple(sorted(failed + (extra,)))
                assert by_set[bigger] >= J * (1 - 1e-12)


# ------------------------------------------------------------------------ criticality classes

def test_criticality_classes_of_the_example_match_an_independent_computation():
    model, spec = load_redundant_model(EXAMPLE)
    res = criticality(model, spec)
    Phi, Qd, _ = model.discretize(spec.dt)
    H, R = np.asarray(model.H), np.asarray(model.R)
    gamma = spec.gamma_rows(model.m)
    D = spec.D
    sc = model.scale
    J0 = np.trace(D @ laub_steady(Phi, Qd, H, R, sc))
    assert res.J_nominal == pytest.approx(J0, rel=1e-8)
    for mode in ("kf2", "af"):
        vital, less = [], []
        for k, sensor in enumerate(spec.sensors):
            rows = list(sensor.rows)
            if mode == "af":
                keep = [i for i in range(model.m) if i not in rows]
                P = laub_steady(Phi, Qd, H[keep], R[np.ix_(keep, keep)], sc)
            else:
                R2 = R + np.diag(np.where(np.isin(np.arange(model.m), rows), gamma, 0.0))
                P = laub_steady(Phi, Qd, H, R2, sc)
            J = np.trace(D @ P)
            assert res.single(k).J[mode] == pytest.approx(J, rel=1e-8)
            (vital if J / J0 - 1 >= spec.vital_threshold else less).append(sensor.name)
        assert list(res.vital[mode]) == vital and list(res.less_important[mode]) == less
    # the example's design: the two airspeed sources back each other up (less important),
    # the angle-of-attack vane and the pitch-rate gyro have no backup (vital)
    for mode in ("kf2", "af"):
        assert {"pitot", "gnss"} <= set(res.less_important[mode])
        assert {"aoa_vane", "rate_gyro"} <= set(res.vital[mode])
    # admissibility is J <= bound, per mode
    for s in res.sets:
        for mode in ("kf2", "af"):
            assert s.admissible[mode] == (s.J[mode] <= spec.bound)
    assert res.admissible_sets("af") and res.inadmissible_sets("af")


def test_pattern_notation_is_the_seeds():
    assert pattern_of((), 5) == "11111"
    assert pattern_of((1,), 5) == "10111"       # J_[10111]: the second sensor failed
    assert pattern_of((0, 4), 5) == "01110"


# ------------------------------------------------------------------------ bad model files

def _example_data():
    return yaml.safe_load(EXAMPLE.read_text())


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.pop("redundancy"), "no 'redundancy:' section"),
    (lambda d: d["redundancy"]["sensors"][0].update(rows=[7]), "not a row index of H"),
    (lambda d: d["redundancy"]["sensors"][1].update(rows=[0]), "row 0 belongs to two sensors"),
    (lambda d: d["redundancy"]["sensors"][0].pop("gamma"), "missing 'gamma'"),
    (lambda d: d["redundancy"]["sensors"][0].update(gamma=-1.0), "gamma: must be a positive"),
    (lambda d: d["redundancy"].update(bound=0), "bound: must be a positive"),
    (lambda d: d["redundancy"].update(D=[1.0, 2.0]), "expected 4 weights"),
    (lambda d: d["redundancy"].update(D=[1.0, -1.0, 1.0, 1.0]), "positive semidefinite"),
    (lambda d: d["redundancy"].update(dt="fast"), "is not a number"),
    (lambda d: d["redundancy"].update(extra=1), "unknown keys"),
    (lambda d: d["redundancy"].pop("sensors"), "missing key 'sensors'"),
    (lambda d: d.update(A=[[1, 2], [3, 4]]), "A: expected shape"),
])
def test_bad_redundancy_sections_raise_clear_errors(mutate, match):
    data = _example_data()
    mutate(data)
    with pytest.raises(CoreError, match=match):
        redundant_model_from_dict(data, "test.yaml")


def test_bad_model_files(tmp_path):
    with pytest.raises(CoreError, match="No such file"):
        load_redundant_model(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("A: [1, 2\n")
    with pytest.raises(CoreError, match="not valid YAML"):
        load_redundant_model(bad)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("42\n")
    with pytest.raises(CoreError, match="mapping"):
        load_redundant_model(scalar)


def test_example_model_loads_as_documented():
    model, spec = load_redundant_model(EXAMPLE)
    assert isinstance(model, LinearModel) and model.m == 5 and len(spec.sensors) == 5
    assert [s.rows for s in spec.sensors] == [(0,), (1,), (2,), (3,), (4,)]
    assert spec.bound > 0 and spec.dt == 0.02
