"""The GLR threshold (glr module docstring, "Threshold"): the first-crossing union bound on
P(max |Z| > u) over all onsets and hypotheses, in closed form with Owen's T function."""
from __future__ import annotations

import numpy as np

from .special import brentq, normal_sf as _Q, owens_t


def first_crossing_probability(u: float, c: np.ndarray) -> np.ndarray:
    """P(|X| <= u < |Y|) for standard bivariate normal (X, Y) with correlation c (closed form via
    Owen's T: P(X > u, Y > u) = Q(u) - 2 T(u, sqrt((1 - c) / (1 + c))))."""
    ac = np.clip(np.abs(np.asarray(c, dtype=float)), 0.0, 1.0)
    a = np.sqrt((1.0 - ac) / (1.0 + ac))
    return _crossing_from_a(u, np.asarray(a, dtype=float))


def _crossing_from_a(u: float, a: np.ndarray) -> np.ndarray:
    a = np.clip(a, 1e-300, 1.0)
    # = 2 Q - 2 [L(u,u;|c|) + L(u,u;-|c|)],  L(u,u;rho) = Q(u) - 2 T(u, a(rho)),  a(-|c|) = 1/a
    out = 4.0 * owens_t(u, a) - 4.0 * (0.5 * _Q(u) - owens_t(u, 1.0 / a))
    return np.maximum(out, 0.0)


#: the bins of a = sqrt((1-|c|)/(1+|c|)): bin i holds edges[i-1] < a <= edges[i]
A_EDGES = np.logspace(-9.0, 0.0, 241)


def bin_counts(pair_a: np.ndarray) -> np.ndarray:
    """How many of the a values fall in each bin of :data:`A_EDGES` (length A_EDGES.size + 1:
    the last one would count a > 1, which the clip to [0, 1] leaves empty)."""
    idx = np.searchsorted(A_EDGES, np.clip(pair_a, 0.0, 1.0), side="left")
    return np.bincount(idx, minlength=A_EDGES.size + 1)


def threshold(fresh: int, counts: np.ndarray, p_false_alarm: float) -> float:
    """Smallest l threshold u^2 whose first-crossing bound is p_false_alarm. ``fresh`` onsets
    start a run (term P(|Z| > u)); ``counts`` (:func:`bin_counts`) holds how many neighbouring
    pairs have a = sqrt((1-|c|)/(1+|c|)) in each bin of :data:`A_EDGES`, and a pair counts as
    its bin's upper edge: the terms grow with a, so this only loosens the bound (by < 10 % for
    the affected terms) and keeps the root search cheap."""
    if fresh == 0:
        return float("inf")
    counts = np.asarray(counts)[:A_EDGES.size]
    keep = counts > 0
    edges, counts = A_EDGES[keep], counts[keep].astype(float)

    def bound(u: float) -> float:
        return fresh * 2.0 * _Q(u) + float(counts @ _crossing_from_a(u, edges))

    hi = 8.0
    while bound(hi) > p_false_alarm:
        hi *= 2.0
    u = brentq(lambda x: bound(x) - p_false_alarm, 0.0, hi, xtol=1e-10, rtol=1e-12)
    return float(u * u)
