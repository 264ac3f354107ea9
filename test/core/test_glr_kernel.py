"""The compiled GLR recursion (core/glr_kernel.py via core/glr_system.py) against a small numpy
reference written here: for a few onsets theta, the signature rho_k(theta) of every hypothesis is
simulated forwards through the filter's own gains in the full fault state (no reduction to the
reachable states, scipy's expm for Phi and Psi, the fault state [beta; r] of a ramp as the glr
module docstring defines it), and num, den and the neighbour correlation cross are summed from
it. Regular and jittered stamps, with gated and rejected samples."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from flight_fdi.core import ins_channel
from flight_fdi.core.glr import DEFAULT_HYPOTHESES, GlrConfig, isolate
from flight_fdi.core import glr_kernel
from flight_fdi.core.glr_kernel import kernel_for, onset_statistics
from flight_fdi.core.glr_system import each_system, prepare, resolve, systems
from flight_fdi.core.glr_threshold import A_EDGES, bin_counts
from flight_fdi.core.kalman import GateConfig, run_forward


_EXPM: dict = {}


def _expm_steps(key, M, dt):
    """expm(M dt[k]) for every k (cached per flight and matrix: the reference is slow enough)."""
    if key not in _EXPM:
        _EXPM[key] = np.stack([expm(M * d) for d in dt])
    return _EXPM[key]


def reference_signature(model, fwd, hyp, theta):
    """rho_k (N, m) of a unit fault of ``hyp`` from sample theta, scaled coordinates, by direct
    simulation: rho_k = D f_k - H_k d_k, d_{k+1} = Phi_{k+1} (d_k + K_k rho_k), f_{k+1} = Psi f_k."""
    N, m, n = fwd.H.shape
    sc = model.scale
    A_s = model.A / sc[:, None] * sc[None, :]
    Hs = fwd.H * sc
    Ks = np.where(fwd.fused[:, None, None], fwd.K / sc[:, None], 0.0)
    if hyp.kind in ("step", "ramp"):
        q = n + (hyp.kind == "ramp")
        Abar = np.zeros((q, q))
        Abar[:n, :n] = A_s
        Abar[hyp.index, :] = 0.0
        if hyp.kind == "ramp":
            Abar[hyp.index, n] = 1.0
        f = np.zeros(q)
        f[n if hyp.kind == "ramp" else hyp.index] = 1.0
    else:
        f = np.ones(1)
    Phis = _expm_steps((id(fwd), "Phi"), A_s, fwd.dt)
    if hyp.kind in ("step", "ramp"):
        Psis = _expm_steps((id(fwd), hyp.kind, hyp.index), Abar, fwd.dt)
    d = np.zeros(n)
    rho = np.zeros((N, m))
    for k in range(theta, N):
        if hyp.kind in ("step", "ramp"):
            Df = Hs[k] @ f[:n]
        else:
            Df = np.zeros(m)
            Df[hyp.index] = f[0]
        rho[k] = Df - Hs[k] @ d
        if k + 1 < N:
            d = Phis[k + 1] @ (d + Ks[k] @ rho[k])
            if hyp.kind in ("step", "ramp"):
                f = Psis[k + 1] @ f
            elif hyp.kind == "outlier":
                f = np.zeros(1)
    return rho


def reference_statistics(model, fwd, hyp, theta):
    Sinv = np.linalg.inv(fwd.S)
    w = np.einsum("kij,kj->ki", Sinv, fwd.nu)
    r0 = reference_signature(model, fwd, hyp, theta)
    r1 = reference_signature(model, fwd, hyp, theta + 1)
    num = np.sum(r0 * w)
    den = np.einsum("ki,kij,kj->", r0, Sinv, r0)
    cross = np.einsum("ki,kij,kj->", r0, Sinv, r1)
    return num, den, cross, r0


@pytest.fixture(scope="module", params=["regular", "jittered"])
def flight(request):
    model = ins_channel()
    rng = np.random.default_rng(7)
    N = 400
    t = np.arange(N) * 0.1
    if request.param == "jittered":
        t = t + rng.normal(0.0, 1e-3, N)
    z = rng.normal(0.0, 0.1, N) + 0.05 * (t > 20.0)
    z[[50, 51, 300]] += 3.0                      # gated and rejected
    fwd = run_forward(model, t, z, gate=GateConfig(action="reject"))
    assert (~fwd.fused).sum() >= 3
    return model, fwd


ONSETS = [0, 49, 50, 173, 398]


def first_pass(model, fwd):
    """(hypotheses, {name: (num, den, cross)}) of the compiled scan over every onset."""
    flt = prepare(model, fwd)
    hyps = [resolve(model, h) for h in DEFAULT_HYPOTHESES]
    return hyps, each_system(lambda system: system.scan(flt), systems(model, hyps))


def test_kernel_statistics_equal_the_reference(flight):
    model, fwd = flight
    hyps, raw = first_pass(model, fwd)
    for hyp in hyps:
        num, den, cross = raw[hyp.name]
        for theta in ONSETS:
            n_ref, d_ref, c_ref, _ = reference_statistics(model, fwd, hyp, theta)
            assert num[theta] == pytest.approx(n_ref, rel=1e-9, abs=1e-9 * np.sqrt(d_ref)), \
                (hyp.name, theta)
            assert den[theta] == pytest.approx(d_ref, rel=1e-9), (hyp.name, theta)
            assert cross[theta] == pytest.approx(c_ref, rel=1e-9, abs=1e-9 * d_ref), \
                (hyp.name, theta)


def test_signature_and_second_pass_numerator_equal_the_reference(flight):
    model, fwd = flight
    flt = prepare(model, fwd)
    hyps = [resolve(model, h) for h in DEFAULT_HYPOTHESES]
    by_name = systems(model, hyps)
    for hyp in hyps:
        rho_ref = reference_signature(model, fwd, hyp, 173)
        rho = by_name[hyp.name].signature(flt, 173, hyp.name)
        np.testing.assert_allclose(rho, rho_ref, rtol=1e-9, atol=1e-9 * np.abs(rho_ref).max())
    # the second pass: num on other innovations equals the reference numerator on them
    rng = np.random.default_rng(3)
    w2 = rng.normal(size=flt.w.shape) * (flt.Sinv[:, :, 0] > 0)
    other = flt.with_innovations(w2)
    for hyp in hyps:
        num2 = by_name[hyp.name].num(other)[hyp.name]
        for theta in ONSETS[:3]:
            ref = np.sum(reference_signature(model, fwd, hyp, theta) * w2)
            assert num2[theta] == pytest.approx(ref, rel=1e-9, abs=1e-9), (hyp.name, theta)


def test_shared_systems_change_nothing(flight):
    # a step evaluated inside its ramp's system, and a jump beside an outlier, give the same
    # statistics as each hypothesis alone
    model, fwd = flight
    together = isolate(model, fwd, GlrConfig(curve_points=0))
    for name in DEFAULT_HYPOTHESES:
        alone = isolate(model, fwd, GlrConfig(hypotheses=(name,), curve_points=0))
        np.testing.assert_allclose(together.curves[name][1], alone.curves[name][1],
                                   rtol=1e-10, atol=1e-10 * alone.curves[name][1].max())


def test_threads_change_nothing(flight):
    # the fault systems scanned on two threads give the same bits as in one
    model, fwd = flight
    one = isolate(model, fwd, GlrConfig(curve_points=0, threads=1))
    two = isolate(model, fwd, GlrConfig(curve_points=0, threads=2))
    assert (one.hypothesis, one.statistic, one.threshold, one.residual) == \
        (two.hypothesis, two.statistic, two.threshold, two.residual)
    assert one.per_hypothesis == two.per_hypothesis
    for name in DEFAULT_HYPOTHESES:
        np.testing.assert_array_equal(one.curves[name][1], two.curves[name][1])


def test_kernels_compiled_per_size_equal_the_generic_ones(flight, monkeypatch):
    # the INS channel's fault systems run kernels compiled for their sizes (n, m, q) = (4, 1, 4)
    # and (4, 1, 2), the loops unrolled; the generic kernels (sizes read from the arrays, what
    # a model of another size runs) give the same bits, the second pass included
    model, fwd = flight
    for name in ("filter_information", "hypothesis_scan", "hypothesis_num"):
        assert kernel_for(name, 4, 1, 4) is not kernel_for(name, 3, 1, 4)
    assert kernel_for("hypothesis_scan", 4, 1, 2) is not kernel_for("hypothesis_scan", 4, 1, 4)
    assert kernel_for("hypothesis_scan", 3, 1, 4) is kernel_for("hypothesis_scan", 5, 2, 1)
    sized = isolate(model, fwd, GlrConfig(curve_points=0, threads=1))
    monkeypatch.setattr(glr_kernel, "SPECIALISED", ())
    generic = isolate(model, fwd, GlrConfig(curve_points=0, threads=1))
    assert sized.residual is not None
    assert (sized.hypothesis, sized.statistic, sized.threshold, sized.residual) == \
        (generic.hypothesis, generic.statistic, generic.threshold, generic.residual)
    assert sized.per_hypothesis == generic.per_hypothesis
    for name in DEFAULT_HYPOTHESES:
        np.testing.assert_array_equal(sized.curves[name][1], generic.curves[name][1])


def test_compiled_onset_statistics_equal_the_numpy_formulas(flight):
    """l = num^2 / den where den > 0, the runs of tests, and the threshold's bins of
    a = sqrt((1-|c|)/(1+|c|)) of neighbouring tests (numpy's searchsorted) -- bit for bit,
    with onsets that are no test (den = 0) in the middle of the record."""
    model, fwd = flight
    hyps, raw = first_pass(model, fwd)
    num, den, cross = raw["reference_outlier"]
    den = den.copy()
    den[[10, 11, 200]] = 0.0                    # three onsets that test nothing
    raw["holes"] = num, den, cross
    for name, (num, den, cross) in raw.items():
        l, ok = np.empty(num.size), np.empty(num.size, dtype=bool)
        counts = np.zeros(A_EDGES.size + 1, dtype=np.int64)
        fresh = onset_statistics(num, den, cross, A_EDGES, l, ok, counts)
        ok_ref = den > 1e-300
        np.testing.assert_array_equal(ok, ok_ref)
        np.testing.assert_array_equal(l, np.where(ok_ref, num ** 2 / np.where(ok_ref, den, 1.0),
                                                  0.0))
        assert fresh == int(ok_ref[0]) + np.count_nonzero(ok_ref[1:] & ~ok_ref[:-1]), name
        both = ok_ref[:-1] & ok_ref[1:]
        c = np.clip(np.abs(cross[:-1][both] / np.sqrt(den[:-1][both] * den[1:][both])), 0, 1)
        np.testing.assert_array_equal(counts, bin_counts(np.sqrt((1.0 - c) / (1.0 + c))))
        assert counts.sum() == both.sum() > 0
