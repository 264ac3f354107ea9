"""The second GLR pass (glr module docstring, "Is the fault explained?"): the signature of the
fitted fault, removed from the innovations, and every hypothesis tested again *given* it.
Built on the same compiled recursion (:mod:`.glr_kernel`, through :mod:`.glr_system`)."""
from __future__ import annotations

import numpy as np

from .glr_system import NONE, Filter, each_system


def residual_pass(systems: dict, flt: Filter, raw: dict, best: str, k0: int,
                  threads: int = 1) -> dict:
    """Remove the fitted fault (``best``, onset k0) from the innovations and test what is left:
    for every hypothesis h2 and onset, the GLR of h2 *given* the first fault (both fitted
    jointly): with n_i, d_ij the inner products of the first pass and n2' the numerator on the
    residual, l2 = n2'^2 / (d22 - d12^2 / d11), chi2(1) for each onset when one fault explains
    the data (d12 comes from n2 - n2' = mu1 d12). ``threads``: see :func:`.each_system`."""
    num1, den1, _ = raw[best]
    mu1 = num1[k0] / den1[k0]
    rho = systems[best].signature(flt, k0, best)
    rest = flt.with_innovations(flt.w - mu1 * np.einsum("kij,kj->ki", flt.Sinv, rho))
    top = {"hypothesis": NONE, "onset_index": None, "onset_t": None, "statistic": 0.0}
    nums = each_system(lambda system: system.num(rest), systems, threads)
    for name in systems:
        n2r = nums[name]
        n2, d22, _ = raw[name]
        d12 = (n2 - n2r) / mu1 if mu1 != 0.0 else np.zeros_like(n2)
        cond = d22 - d12 ** 2 / den1[k0]
        ok = cond > 1e-6 * np.maximum(d22, 1e-300)
        l2 = np.zeros_like(n2)
        l2[ok] = n2r[ok] ** 2 / cond[ok]
        k = int(np.argmax(l2))
        if l2[k] > top["statistic"]:
            top = {"hypothesis": name, "onset_index": k, "onset_t": float(flt.t[k]),
                   "statistic": float(l2[k])}
    return top
