"""core/special.py against SciPy (to ~1e-12 relative over the ranges the analysis uses) and
against closed forms where SciPy's own accuracy is only absolute (Owen's T at tiny a)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.optimize
import scipy.special

from flight_fdi.core.errors import CoreError
from flight_fdi.core.special import brentq, chi2_isf, chi2_sf, normal_sf, owens_t

#: the degrees of freedom the analysis asks for: the gate's m rows, the seed's n states
DOFS = list(range(1, 31))
#: the probabilities: the configurable ones (gate, episodes) anywhere in (0, 1)
PROBS = np.concatenate([np.logspace(-300, -1, 60), np.linspace(0.1, 0.99, 12), [0.999]])


def test_normal_sf_equals_scipy():
    x = np.concatenate([np.linspace(-10.0, 37.0, 941), [0.0, 1e-12]])
    ref = 0.5 * scipy.special.erfc(x / np.sqrt(2.0))
    np.testing.assert_allclose(normal_sf(x), ref, rtol=1e-13, atol=0.0)
    assert isinstance(normal_sf(1.5), float)
    assert normal_sf(1.5) == 0.5 * math.erfc(1.5 / math.sqrt(2.0))


@pytest.mark.parametrize("k", DOFS)
def test_chi2_sf_equals_scipy(k):
    x = np.concatenate([[0.0, 1e-9], np.logspace(-6, np.log10(2000.0), 120)])
    ours = np.array([chi2_sf(v, k) for v in x])
    ref = scipy.special.chdtrc(k, x)
    ok = ref > 1e-300
    np.testing.assert_allclose(ours[ok], ref[ok], rtol=1e-12)
    assert chi2_sf(-1.0, k) == 1.0


@pytest.mark.parametrize("k", DOFS)
def test_chi2_isf_equals_scipy(k):
    ours = np.array([chi2_isf(p, k) for p in PROBS])
    np.testing.assert_allclose(ours, scipy.special.chdtri(k, PROBS), rtol=1e-12)
    # and it inverts the upper tail (tiny p: by its logarithm, no underflow)
    for p, x in zip(PROBS, ours):
        if p > 1e-290:
            assert chi2_sf(x, k) == pytest.approx(p, rel=1e-12)


def test_chi2_known_quantiles():
    # chi2(2) upper tail exp(-x/2); chi2(1) 95 % = 1.959964^2; the gate's default 1e-3, m = 1
    for p in (1e-12, 1e-3, 0.5, 0.9):
        assert chi2_isf(p, 2) == pytest.approx(-2.0 * math.log(p), rel=1e-14)
    assert chi2_isf(0.05, 1) == pytest.approx(3.841458820694124, rel=1e-14)
    assert chi2_isf(1e-3, 1) == pytest.approx(10.827566170662733, rel=1e-13)


@pytest.mark.parametrize("bad", [(0.0, 1), (1.0, 1), (-0.1, 2), (0.1, 0), (0.1, 1.5),
                                 (0.1, True)])
def test_chi2_isf_rejects_bad_arguments(bad):
    with pytest.raises(CoreError):
        chi2_isf(*bad)


def test_owens_t_equals_scipy():
    # GLR's threshold: h = u in [0, ~20] (its root search), a in [1e-9, 1] and 1/a
    h = np.concatenate([[0.0, 1e-8, 1e-3], np.linspace(0.01, 20.0, 300)])
    a = np.concatenate([np.logspace(-9.0, 9.0, 181), [1.0]])
    H, A = np.meshgrid(h, a)
    ours, ref = owens_t(H, A), scipy.special.owens_t(H, A)
    # SciPy's T is accurate to ~1e-16 *absolutely*: relative where it is not tiny
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-22)
    mid = (A >= 1e-3) & (A <= 1e3) & (ref > 1e-250)
    np.testing.assert_allclose(ours[mid], ref[mid], rtol=1e-12, atol=0.0)
    # odd in a, even in h, scalars in, float out
    np.testing.assert_array_equal(owens_t(-H, -A), -ours)
    assert isinstance(owens_t(1.0, 0.5), float)
    assert owens_t(1.0, 0.5) == pytest.approx(float(scipy.special.owens_t(1.0, 0.5)), rel=1e-14)


def test_owens_t_known_answers():
    h = np.linspace(0.0, 20.0, 201)
    # T(h, 1) = Q(h) (1 - Q(h)) / 2;  T(0, a) = atan(a) / (2 pi);  T(h, 0) = 0
    np.testing.assert_allclose(owens_t(h, 1.0), 0.5 * normal_sf(h) * (1.0 - normal_sf(h)),
                               rtol=1e-13)
    a = np.logspace(-9.0, 9.0, 73)
    np.testing.assert_allclose(owens_t(0.0, a), np.arctan(a) / (2.0 * np.pi), rtol=1e-14)
    assert owens_t(3.0, 0.0) == 0.0
    # tiny a (where SciPy is only absolutely accurate): e^{-h^2/2} (a - a^3 (1 + h^2/2) / 3) / 2pi
    H, A = np.meshgrid(np.linspace(0.0, 12.0, 49), np.logspace(-9.0, -4.0, 21))
    series = np.exp(-0.5 * H * H) * (A - A ** 3 * (1.0 + 0.5 * H * H) / 3.0) / (2.0 * np.pi)
    np.testing.assert_allclose(owens_t(H, A), series, rtol=1e-12)


def _cases():
    return [(lambda x: math.cos(x) - x ** 3, 0.0, 2.0),
            (lambda x: x ** 3 - 2.0 * x - 5.0, 2.0, 3.0),         # Wallis' cubic
            (lambda x: math.exp(x) - 1e6, 0.0, 40.0),
            (lambda x: math.atan(x - 1.0 / 3.0), -5.0, 100.0),
            (lambda x: (x - 1.0) ** 9 if x != 1.0 else 0.0, 0.0, 3.5),
            (lambda x: x - 0.25, 0.25, 1.0)]                        # a root at the bracket


@pytest.mark.parametrize("case", range(6))
def test_brentq_takes_scipys_steps(case):
    f, a, b = _cases()[case]
    for xtol, rtol in ((2e-12, 8.9e-16), (1e-10, 1e-12), (1e-300, 4.0 * np.finfo(float).eps)):
        try:
            ref = scipy.optimize.brentq(f, a, b, xtol=xtol, rtol=rtol)
        except RuntimeError:      # (x - 1)^9 to 1e-300: no convergence in 100 steps, either
            with pytest.raises(CoreError, match="no convergence"):
                brentq(f, a, b, xtol=xtol, rtol=rtol)
            continue
        assert brentq(f, a, b, xtol=xtol, rtol=rtol) == ref


def test_brentq_errors():
    with pytest.raises(CoreError, match="opposite signs"):
        brentq(lambda x: x * x + 1.0, -1.0, 1.0)
    with pytest.raises(CoreError, match="no convergence"):
        brentq(lambda x: math.atan(x - 1.0 / 3.0), -5.0, 100.0, maxiter=3)
