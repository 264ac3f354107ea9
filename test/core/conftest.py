"""Shared helpers for the core tests: seeded simulation of a LinearModel (truth and
measurements), generated here independently of the code under test."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm


def _noise_factor(Qd: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """G with G G^T = Qd (via the eigen-decomposition in scaled coordinates; Qd is only PSD)."""
    Qs = Qd / np.outer(scale, scale)
    lam, V = np.linalg.eigh(0.5 * (Qs + Qs.T))
    return scale[:, None] * (V * np.sqrt(np.clip(lam, 0.0, None)))


def simulate_truth(model, t, rng, x0=None):
    """States of ``model`` at the times ``t`` (x0 ~ N(0, P0) unless given), exact discretization."""
    n = model.n
    x = rng.multivariate_normal(np.zeros(n), model.P0) if x0 is None else np.array(x0, float)
    w = rng.standard_normal((len(t), n))
    X = np.empty((len(t), n))
    cache = {}
    for k in range(len(t)):
        if k:
            dt = round(float(t[k] - t[k - 1]), 9)
            if dt not in cache:
                Phi, Qd, _ = model.discretize(dt)
                cache[dt] = (Phi, _noise_factor(Qd, model.scale))
            Phi, G = cache[dt]
            x = Phi @ x + G @ w[k]
        X[k] = x
    return X


def step_response(model, t, state, onset, magnitude):
    """Deterministic deviation of the states after a persistent step of ``magnitude`` in
    ``state`` at ``onset``: beta' = A_bar beta with row ``state`` of A zeroed (the instrument
    error stays at the step), beta(onset) = magnitude e_state."""
    j = model.index(state)
    Abar = np.array(model.A, dtype=float)
    Abar[j, :] = 0.0
    out = np.zeros((len(t), model.n))
    idx = np.flatnonzero(t >= onset)
    if idx.size == 0:
        return out
    beta = expm(Abar * (t[idx[0]] - onset)) @ (magnitude * np.eye(model.n)[j])
    cache = {}
    prev = t[idx[0]]
    for k in idx:
        dt = round(float(t[k] - prev), 9)
        if dt not in cache:
            cache[dt] = expm(Abar * dt)
        beta = cache[dt] @ beta
        out[k] = beta
        prev = t[k]
    return out


@pytest.fixture(scope="session")
def simulate():
    return simulate_truth


@pytest.fixture(scope="session")
def step():
    return step_response
