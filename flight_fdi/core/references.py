"""Redundant references in the streaming filter: which reference has failed, and what the filter
does about it (SPEC section 2 "Redundant reference sensors", seed 001).

i references measure the same quantity (for the INS channel: the velocity, z_k = V_INS - V_ref,k);
each is one measurement row with the model's H row, and an update stacks the rows of the
references present at that stamp. Each row has its own gate, and :class:`ReferenceMonitor` keeps
the health of every reference:

* **per-row gate.** ``beta2_k = nu_k^2 / S_kk`` (nominal S = H P- H^T + R, the prediction of the
  filter, also while the row is excluded or inflated) against the one-row threshold
  ``gate.threshold(1)``.
* **isolation.** An exceedance is *attributed* to reference k only when the disagreement is its
  own: at least one other present, non-failed row passes its gate (a *witness*), and the
  difference between row k and the mean of the witnesses, ``d = a^T nu`` with
  ``a = e_k - mean(e_w)``, also exceeds the one-row threshold (``d^2 / a^T S a``; this
  difference does not depend on the state estimate). When every row disagrees with the
  prediction alike -- an INS fault, or an estimate pulled away by a reference fused in
  ``nominal`` mode -- no reference is blamed; the whole-sample gate and alarm report it.
* **persistence.** A reference is declared *failed* when ``gate.alarm_m`` of its last
  ``gate.alarm_n`` samples were attributed exceedances (the M-of-N rule of the alarm).
* **handling** (``ReferenceConfig.mode``): ``exclude`` -- AF, the row is struck out (E);
  ``known_anomaly`` -- KF2, its innovation covariance grows by ``C Gamma C^T`` with Gamma =
  ``anomaly_variance``; ``nominal`` -- nothing changes, the failure is only reported. In the two
  active modes a row whose exceedance is attributed at this update (a *suspect*, not yet failed)
  is handled the same way in that update, so a jump is kept out of the estimate from its first
  sample while the declaration waits for M of N.
* **readmission.** A failed reference is readmitted (healthy again, used normally) once its own
  gate has passed at every one of its samples for ``readmit_after_s`` seconds of stamps.
* **never all rows.** A failure is declared only against a witness, so the last non-failed
  reference is never declared failed: at least one reference is always healthy. An update may
  still carry only failed rows (the healthy reference's sample missing at that stamp): in
  ``exclude`` mode nothing is then fused -- the step is a prediction only (``fused`` False,
  ``rows_used`` empty), and the failed rows are still assessed (so a reference that heals while
  the others are silent is readmitted); ``known_anomaly`` fuses them inflated.

:class:`RedundantFilter` is a :class:`~.kalman.KalmanFilter` plus a :class:`ReferenceMonitor`:
``step(t, dt, z, R, present)`` predicts, assesses every present row against the prediction, and
updates with the failed (and suspect) rows handled by the mode. Its result says which rows were
failed and excluded/inflated, and the z, R, H actually fused (what a recording needs to re-run the
filter: the rows E keeps in ``exclude`` mode, the inflated R in ``known_anomaly`` mode).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .errors import CoreError
from .checks import check_dt
from .kalman import AlarmLogic, GateConfig, KalmanFilter, UpdateResult
from .models import LinearModel

#: what the filter does with a failed reference
REFERENCE_MODES = ("nominal", "known_anomaly", "exclude")


@dataclass(frozen=True)
class ReferenceConfig:
    """How failed references are handled.

    mode: ``"nominal"`` | ``"known_anomaly"`` (KF2) | ``"exclude"`` (AF), see the module doc.
    anomaly_variance: Gamma, the variance added to a failed row in ``known_anomaly`` mode
        (measurement units squared, e.g. m^2/s^2); a jump of size d calls for Gamma ~ d^2.
    readmit_after_s: a failed reference is readmitted after its own gate has passed for this
        long (seconds of stamps; 0 = at its first passing sample).
    """

    mode: str = "exclude"
    anomaly_variance: float = 1.0
    readmit_after_s: float = 5.0

    def __post_init__(self) -> None:
        if self.mode not in REFERENCE_MODES:
            raise CoreError(f"ReferenceConfig.mode must be one of {REFERENCE_MODES}, "
                            f"got {self.mode!r}")
        for name, lower_open in (("anomaly_variance", True), ("readmit_after_s", False)):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.number)) \
                    or not math.isfinite(v) or v < 0 or (lower_open and v == 0):
                op = "> 0" if lower_open else ">= 0"
                raise CoreError(f"ReferenceConfig.{name} must be a finite number {op}, got {v!r}")
            object.__setattr__(self, name, float(v))


@dataclass
class ReferenceHealth:
    """The health of one reference (times are stamps in seconds)."""

    name: str
    failed: bool = False
    failed_since: float | None = None    # stamp of the declaration of the current failure
    healthy_since: float | None = None   # while failed: start of the current passing streak
    failures: int = 0                    # failures declared
    readmissions: int = 0                # readmissions after a failure
    samples: int = 0                     # rows assessed
    attributed: int = 0                  # exceedances attributed to this reference
    last_t: float | None = None          # stamp of its last sample
    last_beta2: float = math.nan         # its last per-row beta^2
    window: AlarmLogic = field(default_factory=lambda: AlarmLogic(1, 1), repr=False)


@dataclass(frozen=True)
class ReferenceEvent:
    """A change of a reference's health: ``kind`` is ``"failed"`` or ``"readmitted"``."""

    kind: str
    reference: int
    name: str
    t: float
    beta2: float       # the row's beta^2 at that sample


@dataclass(frozen=True)
class Assessment:
    """The monitor's verdict on the rows of one update (arrays in the order of ``present``)."""

    row_beta2: np.ndarray   # nu_k^2 / S_kk
    exceeded: np.ndarray    # the row's own gate exceeded
    attributed: np.ndarray  # the exceedance was attributed to the row (isolated)
    failed: np.ndarray      # the reference is failed (after this sample)
    handled: np.ndarray     # excluded / inflated in this update (failed or suspect; never in
    #                         nominal mode)
    events: tuple[ReferenceEvent, ...]


class ReferenceMonitor:
    """Per-reference failure identification and readmission (see the module docstring)."""

    def __init__(self, names: Sequence[str], gate: GateConfig = GateConfig(),
                 config: ReferenceConfig = ReferenceConfig()) -> None:
        names = [str(nm) for nm in names]
        if not names:
            raise CoreError("ReferenceMonitor: at least one reference is needed")
        if len(set(names)) != len(names):
            raise CoreError(f"ReferenceMonitor: reference names must be unique, got {names}")
        if not isinstance(gate, GateConfig):
            raise CoreError(f"gate must be a GateConfig, got {type(gate).__name__}")
        if not isinstance(config, ReferenceConfig):
            raise CoreError(f"config must be a ReferenceConfig, got {type(config).__name__}")
        self.names = tuple(names)
        self.gate = gate
        self.config = config
        self.threshold = gate.threshold(1)
        self.refs = [ReferenceHealth(nm, window=AlarmLogic(gate.alarm_m, gate.alarm_n))
                     for nm in names]
        self._last_t: float | None = None

    def __len__(self) -> int:
        return len(self.refs)

    def reset(self) -> None:
        """Every reference healthy again, windows cleared (a filter restart); counts are kept."""
        for ref in self.refs:
            ref.failed = False
            ref.failed_since = ref.healthy_since = None
            ref.window.reset()
        self._last_t = None

    def failed_references(self) -> list[int]:
        return [i for i, ref in enumerate(self.refs) if ref.failed]

    def check_present(self, present: Any) -> tuple[int, ...]:
        """Validated reference indices of the rows of an update (unique, increasing)."""
        try:
            rows = [int(i) for i in np.asarray(present).reshape(-1)]
        except (TypeError, ValueError):
            raise CoreError(f"present must be reference indices, got {present!r}") from None
        if not rows:
            raise CoreError("an update needs at least one reference row")
        if any(b <= a for a, b in zip(rows, rows[1:])) or rows[0] < 0 or rows[-1] >= len(self):
            raise CoreError(f"present must be increasing reference indices in 0..{len(self) - 1}, "
                            f"got {rows}")
        return tuple(rows)

    def assess(self, t: float, present: Sequence[int], nu: Any, S: Any) -> Assessment:
        """Assess the rows of one update: ``nu`` and ``S`` (nominal, H P- H^T + R) of the rows
        of the references ``present`` against the prediction. Updates the health of those
        references and returns the verdict, including which rows to exclude/inflate now."""
        t = float(t)
        if not math.isfinite(t):
            raise CoreError(f"stamp t must be finite, got {t!r}")
        if self._last_t is not None and t < self._last_t:
            raise CoreError(f"stamp t = {t!r} is older than the previous one ({self._last_t!r}); "
                            "reset the monitor when the time line jumps back")
        rows = self.check_present(present)
        p = len(rows)
        nu = np.asarray(nu, dtype=float).reshape(-1)
        S = np.asarray(S, dtype=float)
        if nu.shape != (p,) or S.shape != (p, p) or not (np.all(np.isfinite(nu))
                                                         and np.all(np.isfinite(S))):
            raise CoreError(f"assess: nu ({p},) and S ({p}, {p}) must be finite")
        d = np.diag(S)
        if np.any(d <= 0):
            raise CoreError("assess: a diagonal element of S is not positive")
        with np.errstate(over="ignore"):
            rb = nu * nu / d
        if not np.all(np.isfinite(rb)):
            raise CoreError(f"assess: a row's beta2 nu^2 / S overflows float64 (innovation "
                            f"{nu.tolist()}): the measurement is not a plausible value")
        self._last_t = t
        thr = self.threshold
        exceeded = rb > thr
        was_failed = np.array([self.refs[i].failed for i in rows])
        witnesses = np.flatnonzero(~was_failed & ~exceeded)
        attributed = np.zeros(p, dtype=bool)
        if witnesses.size:
            for j in np.flatnonzero(exceeded & ~was_failed):
                a = np.zeros(p)
                a[j] = 1.0
                a[witnesses] -= 1.0 / witnesses.size
                var = float(a.dot(S).dot(a))
                # (a nu)^2 / var > thr, without squaring a huge innovation
                attributed[j] = var > 0 and abs(float(a.dot(nu))) > math.sqrt(thr * var)
        events = []
        handled = np.zeros(p, dtype=bool)
        for j, i in enumerate(rows):
            ref = self.refs[i]
            ref.samples += 1
            ref.last_t = t
            ref.last_beta2 = float(rb[j])
            if ref.failed:
                if exceeded[j]:
                    ref.healthy_since = None
                else:
                    if ref.healthy_since is None:
                        ref.healthy_since = t
                    if t - ref.healthy_since >= self.config.readmit_after_s:
                        ref.failed = False
                        ref.failed_since = ref.healthy_since = None
                        ref.readmissions += 1
                        ref.window.reset()
                        events.append(ReferenceEvent("readmitted", i, ref.name, t, float(rb[j])))
            else:
                ref.attributed += int(attributed[j])
                ref.window.push(bool(attributed[j]))
                if ref.window.active:
                    ref.failed = True
                    ref.failed_since = t
                    ref.healthy_since = None
                    ref.failures += 1
                    events.append(ReferenceEvent("failed", i, ref.name, t, float(rb[j])))
            handled[j] = ref.failed or bool(attributed[j])
        failed = np.array([self.refs[i].failed for i in rows])
        if self.config.mode == "nominal":
            handled[:] = False
        return Assessment(row_beta2=rb, exceeded=exceeded, attributed=attributed, failed=failed,
                          handled=handled, events=tuple(events))


@dataclass(frozen=True)
class ReferenceResult:
    """One update of a :class:`RedundantFilter` (rows in the order of ``present``)."""

    update: UpdateResult            # nu, S, row_beta2 (nominal, every row); beta2 over rows used
    present: tuple[int, ...]        # reference index of each row
    names: tuple[str, ...]          # reference name of each row
    row_failed: np.ndarray          # the reference is failed
    row_excluded: np.ndarray        # struck out (exclude) or inflated (known_anomaly) now
    z_used: np.ndarray              # what was fused: (k,) ...
    R_used: np.ndarray              # (k, k) -- known_anomaly: with Gamma on the inflated rows
    H_used: np.ndarray              # (k, n)
    events: tuple[ReferenceEvent, ...]


class RedundantFilter:
    """A streaming Kalman filter over i redundant references of one measurement (see the module
    docstring). ``model`` must have one measurement row; each reference contributes that row."""

    def __init__(self, model: LinearModel, names: Sequence[str],
                 gate: GateConfig = GateConfig(), config: ReferenceConfig = ReferenceConfig(),
                 x0: Any = None, P0: Any = None) -> None:
        self.kf = KalmanFilter(model, gate, x0, P0)
        if model.m != 1:
            raise CoreError(f"RedundantFilter: model {model.name!r} has {model.m} measurement "
                            "rows; each reference must be one row (m = 1)")
        self.model = model
        self.config = config
        self.monitor = ReferenceMonitor(names, gate, config)
        self._h = np.asarray(model.H, dtype=float).reshape(1, -1)

    @property
    def names(self) -> tuple[str, ...]:
        return self.monitor.names

    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    def accuracy(self, D: Any = None) -> float:
        """J = tr(D P) (``KalmanFilter.accuracy``)."""
        return self.kf.accuracy(D)

    def reset(self, x0: Any = None, P0: Any = None) -> None:
        """The filter back to its prior and every reference healthy (counts are kept)."""
        self.kf.reset(x0, P0)
        self.monitor.reset()

    def step(self, t: float, dt: float, z: Any, R: Any, present: Any = None,
             u: Any = None) -> ReferenceResult:
        """Predict over ``dt``, then update at stamp ``t`` with the rows ``z`` (one value per
        present reference) and their variances ``R`` (one per row, or a k x k covariance).
        ``present``: reference indices of the rows (default: all, in order). The input is
        validated before anything changes; a numerical failure (S not positive definite) raises
        CoreError and restores x and P (the health assessment of that sample is kept)."""
        rows = tuple(range(len(self.monitor))) if present is None else \
            self.monitor.check_present(present)
        k = len(rows)
        H = np.repeat(self._h, k, axis=0)
        Rm = np.asarray(R, dtype=float)
        if Rm.ndim <= 1 and Rm.size == k:
            Rm = np.diag(Rm.reshape(-1))
        kf = self.kf
        # validated once, before any change (the private steps below take validated input)
        zv, Rm, Hs, HsT = kf._measurement(z, Rm, H)
        dt = check_dt(dt)
        with kf.transaction():
            kf.predict(dt, u)
            nu, S = kf._innovation(zv, Rm, Hs, HsT)
            verdict = self.monitor.assess(t, rows, nu, S)
            res = kf._update_checked(zv, Rm, Hs, HsT, np.flatnonzero(verdict.handled),
                                     self.config.mode, self.config.anomaly_variance)
        if res.rows_used is None:
            z_used, R_used, H_used = zv, Rm, H
        else:
            used = list(res.rows_used)
            R_all = Rm if res.R_used is None else res.R_used
            z_used, R_used, H_used = zv[used], R_all[np.ix_(used, used)], H[used]
        return ReferenceResult(
            update=res, present=rows, names=tuple(self.names[i] for i in rows),
            row_failed=verdict.failed, row_excluded=verdict.handled, z_used=z_used,
            R_used=R_used, H_used=H_used, events=verdict.events)
