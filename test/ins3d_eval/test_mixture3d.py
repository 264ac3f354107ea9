"""The onset mixture with the size unknown (flight_fdi/eval/mixture3d.py): known answers first --
M equals a numerical integral over the size prior on a small constructed curve, reduces to the
single-onset Bayes factor with one onset, gives an onset without information no weight whatever
its GLR -- then data drawn from the filter's own model on an ins3d flight: M is larger with a
true signature than on the noise alone."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import norm

from flight_fdi.core.ins3d.glr3d import GlrCurve, Hypothesis
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.mixture3d import (log_bayes_factors, mixture_statistic, mixture_statistics,
                                       prior_sd, tail_thresholds)

DEG_H = math.radians(1.0) / 3600.0
GX = Hypothesis("gyro_x_step", "gyro", "x", "step", 3)


def _curve(mag, sd, t=None):
    mag, sd = np.asarray(mag, float), np.asarray(sd, float)
    t = np.arange(mag.size, dtype=float) if t is None else t
    return GlrCurve(GX, t, np.nan_to_num((mag / sd) ** 2), mag, sd)


def test_mixture_is_the_integral_over_the_size_prior_averaged_over_the_onsets():
    s = 0.8
    mag = np.array([0.3, -1.2, 2.0, 0.05, np.nan])
    sd = np.array([1.0, 0.5, 0.7, 3.0, np.nan])        # the last: no information, left out
    bf = []
    for m, v in zip(mag[:4], sd[:4]):
        d, e = 1.0 / v ** 2, m / v ** 2
        f = lambda b: math.exp(b * e - 0.5 * b * b * d) * norm.pdf(b, 0.0, s)  # noqa: E731
        bf.append(quad(f, -12.0 * s, 12.0 * s, epsabs=0, epsrel=1e-11, limit=200)[0])
    want = 2.0 * math.log(np.mean(bf))
    assert mixture_statistic(_curve(mag, sd), s) == pytest.approx(want, rel=1e-8)
    t = np.arange(5.0)
    assert mixture_statistic(_curve(mag, sd, t), s, (1.0, 2.0)) == pytest.approx(
        2.0 * math.log(np.mean(bf[1:3])), rel=1e-8)


def test_one_onset_gives_the_single_onset_bayes_factor():
    """2 ln BF = L I s^2 / (1 + I s^2) - ln(1 + I s^2), L = e^2 / d the GLR, I = d."""
    for m, v, s in ((1.5, 0.4, 0.3), (-0.2, 2.0, 5.0), (3.0, 0.1, 1e-3)):
        L, info = (m / v) ** 2, 1.0 / v ** 2
        want = L * info * s * s / (1.0 + info * s * s) - math.log1p(info * s * s)
        assert mixture_statistic(_curve([m], [v]), s) == pytest.approx(want, rel=1e-10,
                                                                        abs=1e-14)


def test_an_onset_without_information_gets_no_weight_whatever_its_glr():
    """GLR 400 at an onset with d s^2 = 1e-10: its BF is 1 (the maximum over onsets is 400)."""
    s = 1.0
    c = _curve([20e5], [1e5])
    assert c.statistic == pytest.approx(400.0)
    assert abs(mixture_statistic(c, s)) < 1e-7
    # large values stay finite (log-sum-exp)
    big = mixture_statistic(_curve([1e3, 1.0], [1.0, 1.0]), s)
    assert math.isfinite(big) and big == pytest.approx(
        2.0 * (float(log_bayes_factors(np.array([1e3]), np.array([1.0]), s)[0])
               - math.log(2.0)), rel=1e-12)


def test_prior_rule_and_bad_input():
    assert prior_sd(GX) == pytest.approx(0.05 * DEG_H)
    acc = Hypothesis("accelerometer_y_step", "accelerometer", "y", "step", 1)
    assert prior_sd(acc) == pytest.approx(0.3e-3 * 9.80665, rel=1e-3)
    jump = Hypothesis("reference_east_jump", "reference", "east", "jump", 12)
    assert prior_sd(jump) == pytest.approx(0.3)
    with pytest.raises(EvalError):
        prior_sd(Hypothesis("x", "magnetometer", "x", "step", 0))
    with pytest.raises(EvalError):
        mixture_statistic(_curve([1.0], [1.0]), 0.0)
    with pytest.raises(EvalError):
        mixture_statistic(_curve([np.nan], [np.nan]), 1.0)


# --------------------------------------------------------------------------- an ins3d flight

# (the flight: the ``pf`` fixture of conftest.py)


def test_mixture_is_larger_with_a_true_signature_on_model_drawn_data(pf):
    """A gyro y step at 200 s with lambda = 25 added to 8 noise draws from the filter's own
    model: the gyro y step's M exceeds its value on the same noise alone in every draw; the
    noise alone keeps M below 2 ln 100 (E_0 of the Bayes factor is 1: P_0(M > 2 ln 100) <=
    1 %), which the median with the fault exceeds."""
    signal = pf.noiseless("gyro", "y", 200.0)
    sep = pf.separation("gyro", "y", 200.0, signal)
    b = math.sqrt(25.0 / sep.info)
    rng = np.random.default_rng(5)
    with_fault, alone = [], []
    for _ in range(8):
        noise = pf.noise(rng)
        with_fault.append(mixture_statistics(pf.curves(noise, signal, b))["gyro_y_step"])
        alone.append(mixture_statistics(pf.curves(noise))["gyro_y_step"])
    assert all(f > a for f, a in zip(with_fault, alone))
    assert max(alone) < 2.0 * math.log(100.0) < float(np.median(with_fault))


def test_tail_thresholds_use_the_one_tail_rule_per_hypothesis():
    from flight_fdi.eval.calibrate3d import tail_threshold

    rng = np.random.default_rng(2)
    rows = [{"duration_s": 7200.0, "M": {"a": float(x), "b": float(y)}}
            for x, y in rng.standard_normal((40, 2))]
    thr = tail_thresholds(rows, 5e-4)
    assert thr["a"] == tail_threshold(np.array([r["M"]["a"] for r in rows]), 5e-4)
    assert set(thr) == {"a", "b"}
    with pytest.raises(EvalError):
        tail_thresholds(rows + [{"duration_s": 1800.0, "M": {"a": 0.0, "b": 0.0}}], 0.01)


def test_the_tool_fails_with_one_line(tmp_path):
    """tools/ins3d_mixture.py report on two nominal rows (too few flights for the tail rule)
    and on a missing file: one line on stderr, a non-zero exit."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    tool = Path(__file__).resolve().parents[2] / "tools" / "ins3d_mixture.py"
    rows = tmp_path / "n.jsonl"
    rows.write_text("".join(json.dumps({"seed": i, "duration_s": 7200.0, "M": {"a": 0.0},
                                        "glr": {"a": 1.0}}) + "\n" for i in range(2)))
    for out in (rows, tmp_path / "missing.jsonl"):
        r = subprocess.run([sys.executable, str(tool), "report", "--out", str(out)],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode != 0
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_procedure_thresholds_move_the_long_flights_by_their_growth():
    """2-h rows = the 30-min rows + 1 for every hypothesis: growth 1 / ln 4, both sets pooled
    at the 30-min length are the 30-min values twice, and the 2-h threshold is their tail
    threshold at the equal share (0.75 x 1 % / 15) plus 1."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS
    from flight_fdi.eval.calibrate3d import tail_threshold
    from flight_fdi.eval.mixture3d import procedure_thresholds

    rng = np.random.default_rng(4)
    x = rng.standard_normal((30, len(PER_HYPOTHESIS)))
    short = [{"duration_s": 1800.0, "M": dict(zip(PER_HYPOTHESIS, map(float, v)))} for v in x]
    long = [{"duration_s": 7200.0, "M": {h: v + 1.0 for h, v in r["M"].items()}}
            for r in short]
    thr = procedure_thresholds(short, long)
    for i, h in enumerate(PER_HYPOTHESIS):
        want = tail_threshold(np.concatenate([x[:, i], x[:, i]]), 0.75 * 0.01 / 15) + 1.0
        assert thr[h] == pytest.approx(want, abs=0.006)       # (calibrate rounds to 0.01)
