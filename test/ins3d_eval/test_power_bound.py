"""The detection / isolation power bounds (flight_fdi/eval/power_bound.py): known answers first --
a constant signature seen in white noise (lambda in closed form, the GLR's power = scipy's
non-central chi^2, the Neyman-Pearson power at its false-alarm level), the two-Gaussian
separation, the GLR told the onsets against a bivariate Monte Carlo, the onset-mixture bound
against the Neyman-Pearson power of a known onset -- then the ins3d flight: the noiseless sweep's
information is the signature's, the model-drawn data are linear in the fault, and the GLR's
detection rate on data drawn from the model lies between the GLR-at-the-true-onset rate and the
Neyman-Pearson bound (binomial error)."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import beta, ncx2, norm

from flight_fdi.core.ins3d.glr3d import GlrCurve, Hypothesis
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.onset_bound import quad
from flight_fdi.eval.power_bound import (ALPHA, glr_known_onsets, glr_power,
                                         log_mixture_lr, mixture_achieved,
                                         mixture_power_bound, np_power,
                                         separation, separation_bound)

DEG_H = math.radians(1.0) / 3600.0
REPO = Path(__file__).resolve().parents[2]


def _binom_tol(p: float, n: int, k: float = 3.5) -> float:
    return k * math.sqrt(max(p * (1.0 - p), 1.0 / n) / n)


# --------------------------------------------------------------------------- closed forms

def test_constant_signature_lambda_and_power_match_the_closed_form():
    """rho_j = c, S_j = sigma^2 over N samples: lambda = b^2 N c^2 / sigma^2; the GLR
    (rho' S^-1 nu)^2 / (rho' S^-1 rho) above a threshold is ncx2.sf(threshold, 1, lambda)
    (simulated), the one-sided known-signature test at level alpha has power
    Phi(sqrt(lambda) - z_(1-alpha)) and false-alarm rate alpha (simulated)."""
    N, c, sigma, b, thr = 400, 0.7, 0.3, 0.05, 20.0
    rho = np.full((N, 1), c)
    S_inv = np.full((N, 1, 1), 1.0 / sigma**2)
    lam = b * b * quad(rho, S_inv, rho)
    assert lam == pytest.approx(b * b * N * c * c / sigma**2, rel=1e-12)
    rng = np.random.default_rng(5)
    reps = 4000
    nu = b * c + sigma * rng.standard_normal((reps, N))
    e = nu @ rho[:, 0] / sigma**2
    glr = e * e / (N * c * c / sigma**2)
    p = glr_power(lam, thr)
    assert p == pytest.approx(ncx2.sf(thr, 1, lam), rel=1e-12)
    assert abs(np.mean(glr > thr) - p) < _binom_tol(p, reps)
    z = e / math.sqrt(N * c * c / sigma**2)            # N(sqrt(lambda), 1)
    zc = norm.isf(ALPHA)
    assert abs(np.mean(z > zc) - np_power(lam)) < _binom_tol(np_power(lam), reps)
    z0 = (sigma * rng.standard_normal((reps, N))) @ rho[:, 0] / sigma**2 / math.sqrt(
        N * c * c / sigma**2)
    assert abs(np.mean(z0 > zc) - ALPHA) < _binom_tol(ALPHA, reps)
    # 95 % power needs sqrt(lambda) = z_0.99 + z_0.95
    assert np_power((norm.isf(0.01) + norm.isf(0.05)) ** 2) == pytest.approx(0.95, abs=1e-12)
    with pytest.raises(EvalError):
        np_power(1.0, alpha=0.0)


def test_separation_bound_is_the_midpoint_rule_of_two_gaussians():
    """Two means at Mahalanobis distance d: the midpoint rule names the right one with
    probability Phi(d / 2) under both; the bound is that."""
    rng = np.random.default_rng(6)
    d = 2.4
    x = rng.standard_normal(20000)                     # along the line of the two means
    right = np.mean(x < d / 2)                         # under the first, mean 0
    assert separation_bound(d * d) == pytest.approx(norm.cdf(d / 2), rel=1e-12)
    assert abs(right - separation_bound(d * d)) < _binom_tol(0.885, 20000)


@pytest.mark.parametrize("lam,cos2,margin", [(30.0, 0.0, 0.0), (30.0, 0.5, 9.21),
                                             (60.0, 0.8, 9.21), (25.0, 1.0, 9.21)])
def test_glr_told_the_onsets_matches_a_bivariate_monte_carlo(lam, cos2, margin):
    rng = np.random.default_rng(7)
    n, thr = 200000, 21.4
    w1, w2 = rng.standard_normal((2, n))
    z1 = math.sqrt(lam) + w1
    z2 = math.sqrt(cos2) * z1 + math.sqrt(max(1.0 - cos2, 0.0)) * w2
    det, iso = glr_known_onsets(lam, cos2, thr, margin)
    assert det == pytest.approx(ncx2.sf(thr, 1, lam), abs=1e-6)
    assert abs(det - np.mean(z1**2 > thr)) < _binom_tol(det, n)
    mc = np.mean((z1**2 > thr) & (z1**2 - z2**2 >= margin))
    assert abs(iso - mc) < _binom_tol(iso, n)
    if cos2 == 1.0:
        assert iso == 0.0


def test_glr_told_the_onsets_tends_to_certainty_for_large_faults():
    """lambda -> infinity with cos2 < 1: the gap lambda (1 - cos2) grows without bound."""
    det, iso = glr_known_onsets(1e6, 0.9, 21.4)
    assert det == pytest.approx(1.0) and iso == pytest.approx(1.0, abs=1e-9)
    assert glr_known_onsets(1e6, 1.0, 21.4)[1] == 0.0


def test_mixture_bound_of_a_known_onset_is_at_least_the_neyman_pearson_power():
    """A one-point prior: L = exp(sqrt(lambda) z - lambda / 2), z ~ N(sqrt(lambda), 1) under the
    fault; min_k P_1(L > k) + k alpha is an upper bound of the NP power (up to the draws'
    error) and above it by at most k_NP alpha (k_NP the NP test's threshold on L) plus the
    k grid's step."""
    rng = np.random.default_rng(8)
    for lam in (4.0, 12.0, 25.0):
        z = math.sqrt(lam) + rng.standard_normal(20000)
        bound = mixture_power_bound(math.sqrt(lam) * z - lam / 2)
        p = float(np_power(lam))
        assert bound >= p - _binom_tol(p, 20000)
        k_np = math.exp(math.sqrt(lam) * norm.isf(ALPHA) - lam / 2)
        assert bound <= p + k_np * ALPHA + 0.05
    with pytest.raises(EvalError):
        mixture_power_bound(np.array([]))


def test_mixture_test_at_one_over_alpha_has_its_level_and_the_closed_form_power():
    """One-point prior: L > 1/alpha <=> z > (ln(1/alpha) + lambda/2) / sqrt(lambda): power
    Phi(sqrt(lambda)/2 - ln(1/alpha)/sqrt(lambda)) under the fault (<= the NP power), level
    <= alpha under no fault (Markov)."""
    rng = np.random.default_rng(9)
    lam = 16.0
    z1 = math.sqrt(lam) + rng.standard_normal(20000)
    z0 = rng.standard_normal(20000)
    want = norm.cdf(math.sqrt(lam) / 2 - math.log(1 / ALPHA) / math.sqrt(lam))
    got = mixture_achieved(math.sqrt(lam) * z1 - lam / 2)
    assert abs(got - want) < _binom_tol(want, 20000)
    assert got <= float(np_power(lam)) + _binom_tol(want, 20000)
    assert mixture_achieved(math.sqrt(lam) * z0 - lam / 2) <= ALPHA
    with pytest.raises(EvalError):
        mixture_achieved([])


def test_log_mixture_lr_of_a_curve_is_the_mean_likelihood_ratio_over_the_window():
    h = Hypothesis("gyro_x_step", "gyro", "x", "step", 3)
    t = np.arange(0.0, 10.0, 1.0)
    sd = np.linspace(1.0, 2.0, t.size)
    mag = np.linspace(-0.5, 0.8, t.size)
    c = GlrCurve(h, t, (mag / sd) ** 2, mag, sd)
    b = 0.7
    on = (t >= 2.0) & (t <= 6.0)
    want = math.log(np.mean(np.exp(b * mag[on] / sd[on] ** 2 - 0.5 * b * b / sd[on] ** 2)))
    assert log_mixture_lr(c, b, (2.0, 6.0)) == pytest.approx(want, rel=1e-12)
    with pytest.raises(EvalError):
        log_mixture_lr(c, b, (20.0, 30.0))


# --------------------------------------------------------------------------- an ins3d flight

# (the flight: the ``pf`` fixture of conftest.py)


def test_noiseless_sweep_gives_the_signature_information_and_is_linear(pf):
    """The true step's noiseless GLR at its onset is rho' S^-1 rho; every rival's is at most
    that (Cauchy-Schwarz); the sweep's fault information is linear in the innovations."""
    sig = pf.sig
    rho = sig.rho("gyro", "y", sig.boundary(200.0))
    signal = pf.noiseless("gyro", "y", 200.0)
    sep = separation(pf.curves(signal), "gyro", "y", 200.0)
    assert sep.info == pytest.approx(quad(rho, sig.fwd.S_inv, rho), rel=1e-8)
    assert sep.rivals and all(0.0 <= r.cos2 <= 1.0 for r in sep.rivals)
    assert [r.cos2 for r in sep.rivals] == sorted((r.cos2 for r in sep.rivals), reverse=True)
    assert all(not r.name.startswith("gyro_y_") for r in sep.rivals)
    b = 0.3 * DEG_H
    assert sep.d2(b) == pytest.approx(sep.lam(b) * (1.0 - sep.rivals[0].cos2))
    rng = np.random.default_rng(3)
    w = np.einsum("jik,jk->ji", pf.chol, rng.standard_normal(rho.shape))
    direct = pf.sweep(w + b * rho)
    lin = pf.sweep(w).eta + b * signal.eta
    assert np.max(np.abs(direct.eta - lin)) <= 1e-9 * np.max(np.abs(direct.eta))


def test_glr_on_model_data_lies_between_its_known_onset_rate_and_the_np_bound(pf):
    """Data drawn from the filter's own model with a gyro x step whose lambda is ~20 at 200 s:
    the rate at which the true hypothesis' GLR (max over its onsets) exceeds the threshold is
    at least P(chi^2_1(lambda) > c) (its value at the true onset) and at most the Neyman-
    Pearson power at the level of that same test on nominal draws (its exact 95 % upper
    limit: the test's level is measured, not assumed). A lambda twice too large fails the lower
    side; the upper one only a lambda several times too small."""
    signal = pf.noiseless("gyro", "x", 200.0)
    sep = pf.separation("gyro", "x", 200.0, signal)
    b = math.sqrt(20.0 / sep.info)
    lam = sep.lam(b)
    thr = pf.thresholds["step"]
    rng = np.random.default_rng(11)
    n = 80
    hits = false = 0
    for _ in range(n):
        noise = pf.noise(rng)
        hits += pf.curves(noise, signal, b)["gyro_x_step"].statistic > thr
        false += pf.curves(noise)["gyro_x_step"].statistic > thr
    rate = hits / n
    level = float(beta.ppf(0.95, false + 1, n - false))      # exact upper limit of the level
    assert level < 0.1
    lo, hi = float(glr_power(lam, thr)), float(np_power(lam, level))
    assert 0.3 < lo < 0.7 and hi < 0.9999
    assert lo - _binom_tol(lo, n) <= rate <= hi + _binom_tol(hi, n)


def test_the_tool_fails_with_one_line_on_bad_arguments(tmp_path):
    p = subprocess.run([sys.executable, str(REPO / "tools" / "ins3d_power_bound.py"),
                        "--flights", "0", "--out", str(tmp_path)], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1
    p = subprocess.run([sys.executable, str(REPO / "tools" / "ins3d_power_bound.py"),
                        "--render-only", "--out", str(tmp_path)], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2 and "no records" in p.stderr and "Traceback" not in p.stderr


def test_the_decision_rules_on_the_same_draws(pf):
    """``decide_rules``: "hyp_excess" is the isolator the analysis uses (``decide``),
    "kinds_raw" the rule before per-hypothesis thresholds (per-kind thresholds, raw
    statistics); a 600-s flight's gyro z step far above every threshold is right by all four."""
    from flight_fdi.core.ins3d.glr3d import isolate
    from flight_fdi.eval.power_bound import RULES

    rng = np.random.default_rng(4)
    noise = pf.noise(rng)
    signal = pf.noiseless("gyro", "z", 200.0)
    kinds = {k: v for k, v in pf.thresholds.items() if k in ("step", "ramp", "jump", "outliers")}
    for b in (0.0, 3.0 * DEG_H, 300.0 * DEG_H):
        cv = pf.curves(noise, signal, b)
        d = pf.decide_rules(cv, "gyro", "z")
        assert set(d) == set(RULES)
        own = pf.decide(cv, "gyro", "z")
        assert d["hyp_excess"] == [own["named"], own["isolation"], own["right"]]
        old = isolate(cv, kinds, compare="raw")
        assert d["kinds_raw"][:2] == [old.best, old.isolation]
    assert all(v[2] for v in d.values())
    with pytest.raises(ValueError, match="compare"):
        isolate(cv, kinds, compare="rank")
