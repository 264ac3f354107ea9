"""Window statistics of the triple-IMU voter as compiled kernels (numba), in textbook form.

Both work on 2-D arrays: rows = samples in time, columns = the (quantity, pair) series flattened;
the caller (:class:`flight_fdi.core.voter_core.VoterCore`) keeps the rows of earlier batches it
needs, so a flight pushed in batches of any size gives the same numbers as pushed at once.

* :func:`tail_means` -- the moving mean of the last ``width`` samples (fewer at the flight start),
  a running sum: S_j = S_(j-1) + x_j - x_(j-width). Used for the prefilter and the seed's window
  mean; equal to :func:`flight_fdi.core.voting.window_means` on the whole series.
* :func:`step_deviation` -- the **step detector** statistic: window mean of the last N samples
  minus the **baseline**, the mean of every earlier sample that was admitted to it:
  all samples of the learning phase, then each sample as it leaves the window, provided the
  column's quantity was healthy at the previous decision (a fault is never learnt). Until N
  samples have left the learning phase the window overlaps the baseline (the baseline is the
  learning phase, as the fixed-offset model). The baseline's noise falls as the flight goes on
  (it averages more and more of the flight) while a sudden step stays at full size in the
  window mean until it is admitted.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def tail_means(tail: np.ndarray, new: np.ndarray, width: int) -> np.ndarray:
    """Means of the last ``width`` rows at every row of ``new`` (m, C); ``tail`` (n, C) holds
    the rows just before it (all of them when fewer than width - 1: the flight start)."""
    n, m, C = tail.shape[0], new.shape[0], new.shape[1]
    out = np.empty((m, C))
    S = np.zeros(C)
    first = max(0, n - (width - 1))
    for r in range(first, n):                # the window before the first new row
        for c in range(C):
            S[c] += tail[r, c]
    count = n - first
    for j in range(m):
        for c in range(C):
            S[c] += new[j, c]
        count += 1
        if count > width:                    # the oldest sample leaves the window
            o = n + j - width                # its row in the tail + new sequence
            for c in range(C):
                S[c] -= tail[o, c] if o < n else new[o - n, c]
            count = width
        for c in range(C):
            out[j, c] = S[c] / count
    return out


@njit(cache=True)
def step_deviation(tail: np.ndarray, new: np.ndarray, start: int, width: int, n_learn: int,
                   lower: np.ndarray, upper: np.ndarray,
                   quantity: np.ndarray, b_sum: np.ndarray, b_count: np.ndarray,
                   healthy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Deviations (m, C) of the window mean from the baseline and their inside-bounds flags.

    ``tail`` (n, C): the last rows before ``new`` (at least ``width`` of them once there are),
    ``start``: the flight index of ``new[0]``; ``n_learn``: samples of the learning phase
    (all in the baseline, no decisions); ``lower``/``upper`` (m, C): the bounds;
    ``quantity`` (C,): the quantity index of each column. The state is updated in place:
    ``b_sum``/``b_count`` (C,) the baseline, ``healthy`` (Q,) the last decision's health.
    """
    n, m, C = tail.shape[0], new.shape[0], new.shape[1]
    W = tail_means(tail, new, width)
    dev = np.zeros((m, C))
    inside = np.ones((m, C), dtype=np.bool_)
    for j in range(m):
        i = start + j                            # flight index of this row
        out = i - width                          # the sample leaving the window now
        for c in range(C):
            if i < n_learn:                      # learning: every sample is baseline
                b_sum[c] += new[j, c]
                b_count[c] += 1.0
            elif out >= n_learn and healthy[quantity[c]]:
                o = n + j - width
                b_sum[c] += tail[o, c] if o < n else new[o - n, c]
                b_count[c] += 1.0
        if i < n_learn:
            continue
        for q in range(healthy.size):
            healthy[q] = True
        for c in range(C):
            b = b_sum[c] / b_count[c] if b_count[c] > 0 else 0.0
            dev[j, c] = W[j, c] - b
            inside[j, c] = lower[j, c] <= dev[j, c] <= upper[j, c]
            if not inside[j, c]:
                healthy[quantity[c]] = False
    return dev, inside


@njit(cache=True)
def cusum(e: np.ndarray, drift: np.ndarray, h: np.ndarray, dt: float, g_pos: np.ndarray,
          g_neg: np.ndarray, peak: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided CUSUM of the residuals ``e`` (m, C) for a mean shift (Page's test):

        g+_t = max(0, g+_(t-1) + (e_t - nu) dt),   g-_t = max(0, g-_(t-1) + (-e_t - nu) dt)

    ``drift`` nu (C,) and thresholds ``h`` (C,) per column (in the residual's unit x s);
    ``g_pos``/``g_neg``/``peak`` (C,) are the state, updated in place (``peak``: the largest
    g so far). Returns the signed statistic (m, C) (g+ if g+ >= g-, else -g-) and the flags
    max(g+, g-) <= h (inside: no alarm)."""
    m, C = e.shape
    g = np.empty((m, C))
    inside = np.ones((m, C), dtype=np.bool_)
    for j in range(m):
        for c in range(C):
            gp = max(0.0, g_pos[c] + (e[j, c] - drift[c]) * dt)
            gn = max(0.0, g_neg[c] + (-e[j, c] - drift[c]) * dt)
            g_pos[c], g_neg[c] = gp, gn
            top = max(gp, gn)
            g[j, c] = gp if gp >= gn else -gn
            if top > peak[c]:
                peak[c] = top
            inside[j, c] = top <= h[c]
    return g, inside
