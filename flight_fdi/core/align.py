"""Time alignment of the INS velocity to the reference stamps.

The reference (e.g. GNSS velocity at 10 Hz) and the INS (e.g. 50 Hz) are sampled at different
instants; the filter's measurement z = V_INS - V_ref needs the INS velocity *at the reference
stamp*. It is interpolated linearly between the two INS samples that bracket the stamp:

    v(t) = v_i + (v_{i+1} - v_i) (t - t_i) / (t_{i+1} - t_i),   t_i <= t < t_{i+1}

A stamp that coincides with an INS sample takes that sample. No value is produced (invalid) when
the bracketing samples are more than ``max_gap_s`` apart (a dropout: interpolating across it would
invent data), or when the stamp is outside the span of the INS samples (no extrapolation).

Two front ends apply that one rule (bracket ``t_i <= t < t_{i+1}``, an exact stamp takes the
sample, a bracket wider than ``max_gap_s`` gives nothing) with the one formula :func:`_lerp`:

* :func:`align_to_reference` -- a whole record (post-flight, bag replay), vectorised
  (:func:`interpolate_at`);
* :class:`StreamingAligner` -- a ROS node: INS samples arrive one at a time into a bounded buffer
  and each reference stamp is looked up when it arrives, with plain floats (a few microseconds:
  NumPy's per-call overhead on one element costs ~20 times more).
"""
from __future__ import annotations

import math
from bisect import bisect_right
from typing import Any

import numpy as np

from .errors import CoreError

__all__ = ["align_to_reference", "interpolate_at", "StreamingAligner",
           "OK", "BEFORE_SPAN", "AFTER_SPAN", "GAP"]

# per-stamp outcome codes of interpolate_at
OK = 0
BEFORE_SPAN = 1  # the stamp is earlier than the first INS sample
AFTER_SPAN = 2  # the stamp is later than the last INS sample
GAP = 3  # the bracketing INS samples are more than max_gap_s apart


def _check_gap(max_gap_s: Any) -> float:
    if isinstance(max_gap_s, bool) or not isinstance(max_gap_s, (int, float, np.integer,
                                                                   np.floating)):
        raise CoreError(f"max_gap_s must be a number, got {max_gap_s!r}")
    if not math.isfinite(max_gap_s) or max_gap_s <= 0:
        raise CoreError(f"max_gap_s must be a finite number > 0, got {max_gap_s!r}")
    return float(max_gap_s)


def _lerp(v0: Any, v1: Any, t0: Any, t1: Any, tq: Any) -> Any:
    """The interpolation formula (arrays or scalars: the same IEEE operations, the same bits)."""
    return v0 + (v1 - v0) * ((tq - t0) / (t1 - t0))


def interpolate_at(t_ins: np.ndarray, v_ins: np.ndarray, t_q: np.ndarray, max_gap_s: float):
    """The one interpolation algorithm (module docstring), on already validated arrays.

    t_ins (N,) strictly increasing; v_ins (N, ...) ; t_q (M,). Returns (code (M,) int8,
    values (M, ...) with NaN where code != OK).
    """
    N = t_ins.size
    M = t_q.size
    values = np.full((M,) + v_ins.shape[1:], np.nan)
    code = np.full(M, AFTER_SPAN, dtype=np.int8)
    if N == 0:
        return code, values
    i = np.searchsorted(t_ins, t_q, side="right") - 1  # t_ins[i] <= t_q < t_ins[i + 1]
    code[i < 0] = BEFORE_SPAN
    ic = np.clip(i, 0, N - 1)
    hit = (i >= 0) & (t_ins[ic] == t_q)
    inner = (i >= 0) & (i < N - 1) & ~hit
    code[hit] = OK
    values[hit] = v_ins[ic[hit]]
    lo = i[inner]
    t0, t1 = t_ins[lo], t_ins[lo + 1]
    gap = (t1 - t0) > max_gap_s
    sub = np.flatnonzero(inner)
    code[sub[gap]] = GAP
    ok = sub[~gap]
    lo, t0, t1 = lo[~gap], t0[~gap], t1[~gap]
    shape = (-1,) + (1,) * (v_ins.ndim - 1)
    values[ok] = _lerp(v_ins[lo], v_ins[lo + 1], t0.reshape(shape), t1.reshape(shape),
                       t_q[ok].reshape(shape))
    code[ok] = OK
    return code, values


def align_to_reference(t_ins: Any, v_ins: Any, t_ref: Any, max_gap_s: float = 0.5):
    """INS velocity linearly interpolated at every reference stamp.

    t_ins: (N,) finite, strictly increasing seconds; v_ins: (N,) or (N, d) finite;
    t_ref: (M,) finite seconds (any order). Returns ``(valid (M,) bool, v_at_ref (M,) or (M, d))``
    with NaN where not valid (gap wider than ``max_gap_s`` or outside the INS span).
    Bad input raises :class:`CoreError` -- the caller filters bad messages first and counts them.
    """
    gap = _check_gap(max_gap_s)
    try:
        t = np.asarray(t_ins, dtype=float)
        v = np.asarray(v_ins, dtype=float)
        tq = np.asarray(t_ref, dtype=float)
    except (TypeError, ValueError):
        raise CoreError("align_to_reference: t_ins, v_ins and t_ref must be numeric") from None
    if t.ndim != 1:
        raise CoreError(f"align_to_reference: t_ins must be 1-D, got shape {t.shape}")
    if tq.ndim != 1:
        raise CoreError(f"align_to_reference: t_ref must be 1-D, got shape {tq.shape}")
    if v.ndim not in (1, 2) or v.shape[0] != t.size:
        raise CoreError(f"align_to_reference: v_ins must have shape ({t.size},) or ({t.size}, d), "
                        f"got {v.shape}")
    for name, arr in (("t_ins", t), ("v_ins", v), ("t_ref", tq)):
        if not np.all(np.isfinite(arr)):
            bad = np.flatnonzero(~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1))
            raise CoreError(f"align_to_reference: {name} contains NaN or Inf "
                            f"({bad.size} entries, first at index {int(bad[0])})")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise CoreError(f"align_to_reference: t_ins must be strictly increasing; "
                        f"t_ins[{k + 1}] = {t[k + 1]!r} follows {t[k]!r}")
    code, values = interpolate_at(t, v, tq, gap)
    return code == OK, values


# reasons reported by StreamingAligner.last_reason
REASON_OK = "ok"
REASON_EMPTY = "empty"  # no INS sample yet
REASON_WAITING = "waiting"  # the INS sample after the stamp has not arrived yet
REASON_GAP = "gap"  # the bracketing INS samples are (or will be) more than max_gap_s apart
REASON_TOO_OLD = "too_old"  # the stamp is older than the buffer (or than the first INS sample)


class StreamingAligner:
    """Interpolate the INS at reference stamps from a bounded buffer of recent INS samples.

    ``add_ins(t, v)`` appends a sample (v a number or a vector of fixed length); stamps must be
    strictly increasing (CoreError otherwise; the buffer is unchanged, so the caller can count and
    skip the message). Samples older than ``buffer_s`` before the newest one are dropped, except the
    one just before that horizon (needed to bracket stamps right at it); at most ``max_samples``
    are kept whatever the rate.

    ``at(t_ref)`` returns the interpolated value, or None; ``last_reason`` then tells why:
    ``"waiting"`` (try again when newer INS samples have arrived), ``"gap"`` (never valid: the
    bracketing samples are, or will be, more than ``max_gap_s`` apart), ``"too_old"``,
    ``"empty"``. Once an INS sample at or after ``t_ref`` has arrived, and while ``t_ref`` is
    within ``buffer_s`` of the newest sample, the answer equals :func:`align_to_reference` on the
    same samples (bit for bit: it is the same code).
    """

    def __init__(self, max_gap_s: float = 0.5, buffer_s: float = 2.0,
                 max_samples: int = 100_000) -> None:
        self.max_gap_s = _check_gap(max_gap_s)
        if isinstance(buffer_s, bool) or not isinstance(buffer_s, (int, float, np.integer,
                                                                   np.floating)) \
                or not math.isfinite(buffer_s) or buffer_s <= 0:
            raise CoreError(f"buffer_s must be a finite number > 0, got {buffer_s!r}")
        if isinstance(max_samples, bool) or not isinstance(max_samples, (int, np.integer)) \
                or max_samples < 2:
            raise CoreError(f"max_samples must be an integer >= 2, got {max_samples!r}")
        self.buffer_s = float(buffer_s)
        self.max_samples = int(max_samples)
        self.last_reason = REASON_EMPTY
        # live samples are [_lo:] of two Python lists (stamps as floats, values as float or
        # read-only (d,) arrays); the dropped head is cut off once it is as long as the rest
        self._t: list[float] = []
        self._v: list[Any] = []
        self._shape: tuple | None = None
        self._lo = 0

    def __len__(self) -> int:
        return len(self._t) - self._lo

    @property
    def newest_t(self) -> float | None:
        return self._t[-1] if len(self._t) > self._lo else None

    @property
    def oldest_t(self) -> float | None:
        return self._t[self._lo] if len(self._t) > self._lo else None

    def add_ins(self, t: float, v: Any) -> None:
        """Append one INS sample (stamp ``t`` seconds, value ``v``)."""
        try:
            tf = float(t)
            if isinstance(v, float):
                vv: Any = v
                shape: tuple = ()
                finite = math.isfinite(v)
            else:
                arr = np.array(v, dtype=float)
                shape = arr.shape
                finite = bool(np.isfinite(arr).all())
                vv = float(arr) if arr.ndim == 0 else arr
        except (TypeError, ValueError):
            raise CoreError(f"add_ins: stamp and value must be numeric, got {t!r}, {v!r}") from None
        if not math.isfinite(tf):
            raise CoreError(f"add_ins: stamp must be finite, got {t!r}")
        if len(shape) > 1 or not finite:
            raise CoreError(f"add_ins: value must be a finite number or vector, got {v!r}")
        if self._shape is not None and shape != self._shape:
            raise CoreError(f"add_ins: value has shape {shape}, earlier samples {self._shape}")
        ts = self._t
        if len(ts) > self._lo and tf <= ts[-1]:
            raise CoreError(f"add_ins: stamps must be strictly increasing; {tf!r} follows "
                            f"{ts[-1]!r}")
        if isinstance(vv, np.ndarray):
            vv.flags.writeable = False
        self._shape = shape
        ts.append(tf)
        self._v.append(vv)
        # drop what is older than the horizon, keeping the last sample before it
        horizon = tf - self.buffer_s
        lo, hi = self._lo, len(ts)
        while lo + 1 < hi and ts[lo + 1] <= horizon:
            lo += 1
        self._lo = max(lo, hi - self.max_samples)
        if self._lo >= 1024 and 2 * self._lo >= hi:
            del ts[:self._lo]
            del self._v[:self._lo]
            self._lo = 0

    def at(self, t_ref: float):
        """INS value at ``t_ref`` or None (see ``last_reason``)."""
        try:
            tq = float(t_ref)
        except (TypeError, ValueError):
            raise CoreError(f"at: stamp must be a number, got {t_ref!r}") from None
        if not math.isfinite(tq):
            raise CoreError(f"at: stamp must be finite, got {t_ref!r}")
        ts, lo = self._t, self._lo
        hi = len(ts)
        if hi == lo:
            self.last_reason = REASON_EMPTY
            return None
        i = bisect_right(ts, tq, lo, hi) - 1  # ts[i] <= tq < ts[i + 1], as in interpolate_at
        if i < lo:
            self.last_reason = REASON_TOO_OLD
            return None
        if ts[i] == tq:
            self.last_reason = REASON_OK
            return self._v[i]
        if i == hi - 1:
            # the next sample comes after t_ref: once the stamp is further than max_gap_s from
            # the newest sample, no future sample can give a valid bracket
            self.last_reason = REASON_GAP if tq - ts[-1] > self.max_gap_s else REASON_WAITING
            return None
        t0, t1 = ts[i], ts[i + 1]
        if (t1 - t0) > self.max_gap_s:
            self.last_reason = REASON_GAP
            return None
        self.last_reason = REASON_OK
        return _lerp(self._v[i], self._v[i + 1], t0, t1, tq)
