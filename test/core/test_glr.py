"""GLR fault isolation (flight_fdi.core.glr).

Expected values come from outside the code under test: a brute-force forward simulation of the
fault signature for every onset (written here from the physics of the fault, not from glr's
recursions), Cauchy-Schwarz (a noise-free fault maximizes l exactly at its own hypothesis and onset,
with l = mu^2 den), closed forms of the threshold, scipy's bivariate normal, and seeded Monte Carlo.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.stats import chi2, multivariate_normal

from flight_fdi.core import CoreError, attitude_axis, ins_channel
from flight_fdi.core.glr import GlrConfig, first_crossing_probability, isolate
from flight_fdi.core.kalman import GateConfig, run_forward
from flight_fdi.core.glr_threshold import A_EDGES, threshold as glr_threshold

DEG_H = np.pi / 180.0 / 3600.0  # rad/s per deg/h

# How a persistent instrument fault enters the dynamics, written from the physics (not from glr):
# an accelerometer bias step adds to dV' = -g tilt + da, a gyro drift step to tilt' = dV/R + dw, a
# disturbance-torque step to rate' = m_c u + m_d. The faulty state itself reads the step on top of
# its healthy (Gauss-Markov) value.
FORCING = {
    ("ins_channel", "accel_bias"): [1.0, 0.0, 0.0, 0.0],
    ("ins_channel", "gyro_drift"): [0.0, 1.0, 0.0, 0.0],
    ("attitude_axis", "disturbance"): [0.0, 1.0, 0.0],
}


def simulate(model, duration, *, seed=0, fault=None, onset=None, magnitude=0.0, noise=True,
             flights=1, ins_hz=50, ref_hz=10, t=None):
    """Seeded flights: the true error state at the INS rate (exact discretization of the model,
    augmented with a constant fault input), reference measurements z = H x + noise at ref_hz.

    fault: None, a state name (persistent step in that instrument from ``onset`` on),
    ("jump", row) or ("outlier", row). Returns t (M,), z (flights, M, m), the true state
    (flights, M, n) at the reference stamps.
    """
    rng = np.random.default_rng(seed)
    n = model.n
    if t is None:
        step = ins_hz // ref_hz
        t_ins = np.arange(int(round(duration * ins_hz)) + 1) / ins_hz
        keep = np.arange(0, t_ins.size, step)
    else:  # given reference stamps; simulate at exactly those instants
        t_ins = np.asarray(t, dtype=float)
        keep = np.arange(t_ins.size)
    forcing = np.zeros(n)
    j = None
    if isinstance(fault, str):
        forcing = np.array(FORCING[(model.name, fault)])
        j = model.index(fault)
    Aa = np.zeros((n + 1, n + 1))
    Aa[:n, :n] = model.A
    Aa[:n, n] = forcing
    x = np.zeros((flights, n + 1))
    if noise:
        x[:, :n] = rng.standard_normal((flights, n)) * np.sqrt(np.diag(model.P0))
    out = np.empty((flights, t_ins.size, n))
    cache = {}
    for k, tk in enumerate(t_ins):
        if k:
            dt = round(tk - t_ins[k - 1], 12)
            if dt not in cache:
                _, Qd, _ = model.discretize(dt)
                ev, V = np.linalg.eigh(Qd)
                cache[dt] = (expm(Aa * dt), V * np.sqrt(np.clip(ev, 0.0, None)))
            Phi, Lq = cache[dt]
            x = x @ Phi.T
            if noise:
                x[:, :n] += rng.standard_normal((flights, n)) @ Lq.T
        if j is not None and abs(tk - onset) < 1e-9:
            x[:, n] = magnitude
        out[:, k] = x[:, :n]
        if j is not None:
            out[:, k, j] += x[:, n]
    truth = out[:, keep]
    tr = t_ins[keep]
    z = np.einsum("mi,fki->fkm", model.H, truth)
    if noise:
        z += rng.standard_normal(z.shape) @ np.linalg.cholesky(model.R).T
    if isinstance(fault, tuple):
        kind, row = fault
        if kind == "jump":
            z[:, tr >= onset - 1e-9, row] += magnitude
        else:
            z[:, int(np.argmin(np.abs(tr - onset))), row] += magnitude
    return tr, z, truth


def brute_force(model, fwd, hypothesis):
    """num(theta), den(theta) for every onset by simulating the fault's signature forward through
    the filter's gains, one column per onset (physical units)."""
    N, n = len(fwd.t), model.n
    Sinv = np.linalg.inv(fwd.S)
    w = np.einsum("kij,kj->ki", Sinv, fwd.nu)
    K = fwd.K * fwd.fused[:, None, None]
    kind, what = hypothesis
    onsets = np.arange(N)
    if kind == "step":
        j = model.index(what)
        Aa = np.zeros((n + 1, n + 1))
        Aa[:n, :n] = model.A
        Aa[:n, n] = FORCING[(model.name, what)]
        y = np.zeros((n + 1, N))  # [healthy-part deviation; step], one column per onset
    num = np.zeros(N)
    den = np.zeros(N)
    d_upd = np.zeros((n, N))
    for k in range(N):
        if k:
            d = model.discretize(fwd.dt[k])[0] @ d_upd
            if kind == "step":
                y = expm(Aa * fwd.dt[k]) @ y
        else:
            d = np.zeros((n, N))
        if kind == "step":
            y[:, k] = 0.0
            y[n, k] = 1.0
            dev = y[:n] + np.outer(np.eye(n)[j], y[n])
            rho = fwd.H[k] @ (dev - d)
        else:
            e = np.zeros((model.m, N))
            row = model.measurement_names.index(what)
            e[row] = (onsets <= k) if kind == "jump" else (onsets == k)
            rho = e - fwd.H[k] @ d
        num += rho.T @ w[k]
        den += np.sum(rho * (Sinv[k] @ rho), axis=0)
        d_upd = d + K[k] @ rho
    return num, den


# ------------------------------------------------------------------------------ exactness

@pytest.fixture(scope="module")
def irregular_flight():
    """A short flight with jittered stamps, an accelerometer fault, and gate rejections."""
    model = ins_channel()
    rng = np.random.default_rng(11)
    t = np.cumsum(0.1 + 0.02 * (rng.random(500) - 0.5))
    t -= t[0]
    _, z, _ = simulate(model, None, seed=3, fault="accel_bias", onset=t[200], magnitude=0.02,
                       t=t)
    z = z[0]
    z[[120, 121, 350]] += 2.0  # wild samples, rejected by the gate
    fwd = run_forward(model, t, z, gate=GateConfig(action="reject"))
    assert (~fwd.fused).sum() >= 3
    hyps = {"accel_bias_step": ("step", "accel_bias"), "gyro_drift_step": ("step", "gyro_drift"),
            "reference_jump": ("jump", "velocity"), "reference_outlier": ("outlier", "velocity")}
    return model, fwd, {name: brute_force(model, fwd, hyp) for name, hyp in hyps.items()}


@pytest.mark.parametrize("block_size", [0, 2, 7, 10_000])
def test_every_onset_equals_brute_force(irregular_flight, block_size):
    model, fwd, reference = irregular_flight
    res = isolate(model, fwd, GlrConfig(curve_points=0, block_size=block_size))
    for name, (num, den) in reference.items():
        ok = den > 0
        l_ref = np.where(ok, num**2 / np.where(ok, den, 1.0), 0.0)
        t_curve, l = res.curves[name]
        np.testing.assert_array_equal(t_curve, fwd.t)
        np.testing.assert_allclose(l, l_ref, rtol=1e-8, atol=1e-9 * l_ref.max())
        k = int(np.argmax(l_ref))
        best = res.per_hypothesis[name]
        assert best["onset_index"] == k
        assert best["onset_t"] == fwd.t[k]
        assert best["magnitude"] == pytest.approx(num[k] / den[k], rel=1e-8)
        assert best["magnitude_std"] == pytest.approx(1.0 / np.sqrt(den[k]), rel=1e-8)
    # a bias step at the very last sample leaves no trace: not a test
    assert res.curves["accel_bias_step"][1][-1] == 0.0


NOISE_FREE = [
    ("accel_bias", "accel_bias_step", 0.004),
    ("accel_bias", "accel_bias_step", -0.01),
    ("gyro_drift", "gyro_drift_step", 2.0 * DEG_H),
    (("jump", 0), "reference_jump", -0.7),
    (("outlier", 0), "reference_outlier", 0.9),  # l = mu^2 / S: must beat the threshold (~26)
]


@pytest.mark.parametrize("fault, name, magnitude", NOISE_FREE)
def test_noise_free_fault_is_recovered_exactly(fault, name, magnitude):
    # nu = mu rho(theta0, h0) exactly, so by Cauchy-Schwarz l is largest at (theta0, h0), where
    # l = mu^2 den and mu_hat = mu: this checks the signature against a physically injected fault.
    model = ins_channel()
    t, z, _ = simulate(model, 200.0, fault=fault, onset=120.0, magnitude=magnitude, noise=False)
    fwd = run_forward(model, t, z[0])
    res = isolate(model, fwd)
    if name == "gyro_drift_step":
        # on one velocity channel a gyro drift step w and an accelerometer bias ramp -g w have
        # the same signature: a tie, reported as ambiguous with both named
        assert {res.hypothesis, res.runner_up} == {name, "accel_bias_ramp"}
        assert res.isolation == "ambiguous" and not res.confident
        ramp = res.per_hypothesis["accel_bias_ramp"]
        assert ramp["statistic"] == pytest.approx(res.statistic, rel=1e-6)
        assert ramp["magnitude"] == pytest.approx(-model.params["g"] * magnitude, rel=1e-6)
        assert ramp["unit"] == "m/s^3"
    else:
        assert res.hypothesis == name and res.isolation == "single" and res.confident
    best = res.per_hypothesis[name]
    assert best["onset_index"] == int(np.argmin(np.abs(t - 120.0)))
    assert best["onset_t"] == pytest.approx(120.0, abs=1e-9)
    assert best["magnitude"] == pytest.approx(magnitude, rel=1e-6)
    assert best["statistic"] == pytest.approx(res.statistic, rel=1e-9)
    assert res.statistic > res.threshold
    assert best["unit"] == ("m/s" if name.startswith("reference")
                            else model.state_units[model.index(fault)])


def test_general_model_named_hypotheses():
    model = attitude_axis()  # angle only; a Jordan-block A
    t, z, _ = simulate(model, 100.0, fault="disturbance", onset=40.0, magnitude=3e-5,
                       noise=False)
    fwd = run_forward(model, t, z[0])
    hyps = ("step:disturbance", "rate_step", "reference_jump", "reference_outlier")
    res = isolate(model, fwd, GlrConfig(hypotheses=hyps))
    assert res.hypothesis == "step:disturbance"
    assert res.onset_t == pytest.approx(40.0, abs=1e-9)
    assert res.magnitude == pytest.approx(3e-5, rel=1e-6)
    assert res.per_hypothesis["step:disturbance"]["unit"] == "rad/s^2"

    model2 = attitude_axis(sigma_rate=1e-4)  # two measurement rows
    t, z, _ = simulate(model2, 100.0, fault=("jump", 1), onset=30.0, magnitude=-2e-3,
                       noise=False)
    fwd = run_forward(model2, t, z[0])
    hyps = ("step:disturbance", "jump:angle", "jump:rate", "outlier:rate")
    res = isolate(model2, fwd, GlrConfig(hypotheses=hyps))
    assert res.hypothesis == "jump:rate"
    assert res.onset_t == pytest.approx(30.0, abs=1e-9)
    assert res.magnitude == pytest.approx(-2e-3, rel=1e-6)
    with pytest.raises(CoreError, match="jump:<measurement>"):
        isolate(model2, fwd, GlrConfig(hypotheses=("reference_jump",)))


# ------------------------------------------------------------------------------ noisy flights

NOISY = [
    # fault, hypothesis, magnitude, onset tolerance [s]
    ("accel_bias", "accel_bias_step", 0.005, 5.0),     # 0.5 mg
    ("accel_bias", "accel_bias_step", -0.005, 5.0),
    ("gyro_drift", "gyro_drift_step", 3.0 * DEG_H, 5.0),
    (("jump", 0), "reference_jump", 0.5, 0.1),         # 5 sigma of the reference noise
    (("outlier", 0), "reference_outlier", 1.0, 0.1),
]


@pytest.fixture(scope="module")
def nominal_flight():
    """1000 s of a healthy INS channel: truth at 50 Hz, reference at 10 Hz, sigma 0.1 m/s."""
    model = ins_channel()
    t, z, _ = simulate(model, 1000.0, seed=21)
    return model, t, z[0]


@pytest.mark.parametrize("fault, name, magnitude, onset_tol", NOISY)
def test_isolates_faults_in_noisy_flights(nominal_flight, fault, name, magnitude, onset_tol):
    model, t, z_nominal = nominal_flight
    # the system is linear: faulty flight = healthy flight + the fault's own (noise-free) response
    t_f, z_fault, _ = simulate(model, 1000.0, fault=fault, onset=500.0, magnitude=magnitude,
                               noise=False, ins_hz=10, ref_hz=10)
    np.testing.assert_allclose(t_f, t, rtol=0, atol=1e-9)
    res = isolate(model, run_forward(model, t, z_nominal + z_fault[0]))
    if name == "gyro_drift_step":  # its twin, the accelerometer ramp: ambiguous, both named
        assert {res.hypothesis, res.runner_up} == {name, "accel_bias_ramp"}
        assert res.isolation == "ambiguous"
    else:
        assert res.hypothesis == name and res.isolation == "single"
    best = res.per_hypothesis[name]
    assert abs(best["onset_t"] - 500.0) <= onset_tol
    assert abs(best["magnitude"] - magnitude) <= 4.0 * best["magnitude_std"]
    assert best["magnitude"] == pytest.approx(magnitude, rel=0.15)
    assert best["statistic"] == pytest.approx(res.statistic, rel=1e-6)
    assert res.statistic > res.threshold


def test_nominal_flight_reports_none(nominal_flight):
    model, t, z = nominal_flight
    res = isolate(model, run_forward(model, t, z))
    assert res.hypothesis == "none"
    assert res.onset_index is None and res.onset_t is None and res.magnitude is None
    assert not res.detected
    assert res.statistic <= res.threshold
    assert set(res.per_hypothesis) == set(GlrConfig().hypotheses)


def test_false_alarm_rate_is_at_most_p_false_alarm():
    # H0 Monte Carlo: flights drawn from the model itself, so the filter is consistent
    model = ins_channel()
    flights, p_fa = 120, 0.2
    t, z, _ = simulate(model, 60.0, seed=5, flights=flights, ins_hz=10, ref_hz=10)
    config = GlrConfig(p_false_alarm=p_fa)
    alarms = sum(isolate(model, run_forward(model, t, z[i]), config).detected
                 for i in range(flights))
    # binomial(120, <= 0.2): mean <= 24, sd 4.4; the bound is not vacuous either
    assert alarms <= flights * p_fa + 2.5 * np.sqrt(flights * p_fa * (1 - p_fa))
    assert alarms >= flights * p_fa / 4


# ------------------------------------------------------------------------------ threshold

def test_threshold_closed_forms():
    model = ins_channel()
    # one onset, one hypothesis: l ~ chi2(1) exactly
    t, z, _ = simulate(model, 0.0, seed=1, ins_hz=10, ref_hz=10)
    fwd = run_forward(model, t, z[0])
    res = isolate(model, fwd, GlrConfig(p_false_alarm=0.01, hypotheses=("reference_jump",)))
    assert res.threshold == pytest.approx(chi2.isf(0.01, 1), rel=1e-8)
    # many onsets: between the single-test quantile and Bonferroni over all (onset, hypothesis)
    t, z, _ = simulate(model, 300.0, seed=2, ins_hz=10, ref_hz=10)
    fwd = run_forward(model, t, z[0])
    res = isolate(model, fwd, GlrConfig(p_false_alarm=1e-3))
    n_tests = 4 * t.size
    assert chi2.isf(1e-3, 1) < res.threshold <= chi2.isf(1e-3 / n_tests, 1)
    # smooth step signatures: far fewer effective onsets than samples
    steps = isolate(model, fwd, GlrConfig(hypotheses=("accel_bias_step", "gyro_drift_step")))
    assert steps.threshold < chi2.isf(1e-3 / (2 * t.size), 1) - 3.0


def _scipy_threshold(fresh, counts, p_false_alarm):
    """The threshold's root search written with SciPy's erfc, owens_t and brentq (what
    glr_threshold used before core/special replaced them)."""
    from scipy.optimize import brentq
    from scipy.special import erfc, owens_t

    counts = np.asarray(counts)[:A_EDGES.size]
    keep = counts > 0
    a, n = np.clip(A_EDGES[keep], 1e-300, 1.0), counts[keep].astype(float)

    def bound(u):
        q = 0.5 * float(erfc(u / np.sqrt(2.0)))
        cross = 4.0 * owens_t(u, a) - 4.0 * (0.5 * q - owens_t(u, 1.0 / a))
        return fresh * 2.0 * q + float(n @ np.maximum(cross, 0.0))

    hi = 8.0
    while bound(hi) > p_false_alarm:
        hi *= 2.0
    return brentq(lambda x: bound(x) - p_false_alarm, 0.0, hi, xtol=1e-10, rtol=1e-12) ** 2


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_threshold_equals_the_scipy_root_search(seed):
    # random bin counts like a flight's (steps near a = 1e-4, outliers near a = 1), 1-3 hours
    rng = np.random.default_rng(seed)
    counts = np.zeros(A_EDGES.size + 1, dtype=np.int64)
    for centre, total in ((rng.uniform(80, 140), rng.integers(1e5, 5e5)),
                          (rng.uniform(200, 240), rng.integers(1e4, 2e5))):
        idx = np.clip(rng.normal(centre, 8.0, int(total)).astype(int), 0, A_EDGES.size - 1)
        counts += np.bincount(idx, minlength=counts.size)
    for p_fa in (1e-2, 1e-3, 1e-6):
        fresh = int(rng.integers(1, 20))
        assert glr_threshold(fresh, counts, p_fa) == \
            pytest.approx(_scipy_threshold(fresh, counts, p_fa), rel=1e-12)


@pytest.mark.parametrize("u", [0.5, 2.0, 4.5])
@pytest.mark.parametrize("c", [0.0, 0.3, -0.6, 0.95, 0.999])
def test_first_crossing_probability_matches_bivariate_normal(u, c):
    mvn = multivariate_normal(mean=[0.0, 0.0], cov=[[1.0, c], [c, 1.0]])
    inside_both = (mvn.cdf([u, u]) - mvn.cdf([-u, u]) - mvn.cdf([u, -u]) + mvn.cdf([-u, -u]))
    inside_x = 1.0 - 2.0 * (1.0 - multivariate_normal(0.0, 1.0).cdf(u))
    expected = inside_x - inside_both  # P(|X| <= u < |Y|)
    got = float(first_crossing_probability(u, np.array([c]))[0])
    assert got == pytest.approx(expected, rel=1e-5, abs=1e-12)


# ------------------------------------------------------------------------------ result and API

def test_curves_are_max_pooled():
    model = ins_channel()
    t, z, _ = simulate(model, 400.0, seed=8, fault="accel_bias", onset=200.0, magnitude=0.01,
                       ins_hz=10, ref_hz=10)
    fwd = run_forward(model, t, z[0])
    full = isolate(model, fwd, GlrConfig(curve_points=0))
    pooled = isolate(model, fwd, GlrConfig(curve_points=100))
    for name, (tc, lc) in pooled.curves.items():
        tf, lf = full.curves[name]
        assert len(tf) == t.size and 50 <= len(tc) <= 100
        assert np.all(np.diff(tc) > 0)
        assert lc.max() == full.per_hypothesis[name]["statistic"]
        assert tc[np.argmax(lc)] == full.per_hypothesis[name]["onset_t"]
        assert set(np.round(lc, 12)) <= set(np.round(lf, 12))
    assert pooled.hypothesis == full.hypothesis == "accel_bias_step"


@pytest.mark.parametrize("kwargs, field", [
    ({"p_false_alarm": 0.0}, "p_false_alarm"),
    ({"p_false_alarm": 1.0}, "p_false_alarm"),
    ({"p_false_alarm": float("nan")}, "p_false_alarm"),
    ({"p_false_alarm": True}, "p_false_alarm"),
    ({"hypotheses": ()}, "hypotheses"),
    ({"hypotheses": "accel_bias_step"}, "hypotheses"),
    ({"hypotheses": ("reference_jump", "reference_jump")}, "hypotheses"),
    ({"hypotheses": ("none",)}, "hypotheses"),
    ({"hypotheses": ("",)}, "hypotheses"),
    ({"block_size": -1}, "block_size"),
    ({"block_size": 1}, "block_size"),
    ({"block_size": 2.5}, "block_size"),
    ({"curve_points": -3}, "curve_points"),
    ({"threads": 0}, "threads"),
    ({"threads": 1.5}, "threads"),
    ({"threads": True}, "threads"),
])
def test_config_is_validated(kwargs, field):
    with pytest.raises(CoreError, match=f"GlrConfig.{field}"):
        GlrConfig(**kwargs)


def test_bad_hypotheses_and_inputs_are_rejected():
    model = ins_channel()
    t, z, _ = simulate(model, 10.0, seed=1, ins_hz=10, ref_hz=10)
    fwd = run_forward(model, t, z[0])
    with pytest.raises(CoreError, match="unknown hypothesis 'bogus'"):
        isolate(model, fwd, GlrConfig(hypotheses=("bogus",)))
    with pytest.raises(CoreError, match="needs a state 'tilt_rate'"):
        isolate(model, fwd, GlrConfig(hypotheses=("tilt_rate_step",)))
    with pytest.raises(CoreError, match="no measurement 'angle'"):
        isolate(model, fwd, GlrConfig(hypotheses=("jump:angle",)))
    with pytest.raises(CoreError, match="needs a state 'accel_bias'"):
        isolate(attitude_axis(), fwd)  # default hypotheses are the INS channel's
    fields = {k: getattr(fwd, k) for k in ("t", "dt", "nu", "S", "K", "H", "fused")}
    missing = SimpleNamespace(**{k: v for k, v in fields.items() if k != "S"})
    with pytest.raises(CoreError, match="no field 'S'"):
        isolate(model, missing)
    with pytest.raises(CoreError, match="'nu' has shape"):
        isolate(model, SimpleNamespace(**{**fields, "nu": fields["nu"][:-1]}))
    nu = fields["nu"].copy()
    nu[4] = np.nan
    with pytest.raises(CoreError, match="sample 4 was fused"):
        isolate(model, SimpleNamespace(**{**fields, "nu": nu}))
    # a sample that was not fused and has no innovation is simply not a test
    res = isolate(model, SimpleNamespace(**{**fields, "nu": nu,
                                            "fused": np.arange(len(t)) != 4}))
    assert res.curves["reference_outlier"][1][4] == 0.0
    with pytest.raises(CoreError, match="config must be a GlrConfig"):
        isolate(model, fwd, {"p_false_alarm": 0.1})


def test_tied_hypotheses_keep_the_declared_order_whatever_the_rounding():
    from flight_fdi.core.glr import rank_hypotheses

    base = 3707.0
    for eps in (+3e-12, -3e-12, 0.0):  # rounding in either direction
        per = {"accel_bias_step": {"statistic": 900.0},
               "gyro_drift_step": {"statistic": base},
               "accel_bias_ramp": {"statistic": base * (1 + eps)},
               "reference_jump": {"statistic": 905.0}}
        assert rank_hypotheses(per) == ["gyro_drift_step", "accel_bias_ramp", "reference_jump",
                                        "accel_bias_step"]
    # a real difference is not a tie
    per = {"gyro_drift_step": {"statistic": 100.0}, "accel_bias_ramp": {"statistic": 100.1}}
    assert rank_hypotheses(per) == ["accel_bias_ramp", "gyro_drift_step"]
