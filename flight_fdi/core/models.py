"""Linear Gaussian state-space models: the INS channel (seed 000), the attitude axis (seed 003),
and models given as YAML data.

A model is continuous-time::

    x' = A x + B u + G xi,   E[G xi xi^T G^T] = Qc (spectral density)
    z  = H x + theta,        theta ~ N(0, R)

and is discretized exactly for the actual sample interval (``discretize``): Phi = expm(A dt),
Qd by Van Loan's method, Bd = int_0^dt expm(A s) ds B. Results are cached per dt. The estimation
kernels discretize with the compiled :mod:`flight_fdi.core.discretize` instead.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import CoreError

G0 = 9.80665  # m/s^2
EARTH_RADIUS = 6_371_000.0  # m
DEG_PER_HOUR = np.pi / 180.0 / 3600.0  # rad/s per deg/h


def _matrix(value: Any, shape: tuple[int, int] | None, what: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CoreError(f"{what}: not a numeric matrix ({exc})") from None
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1) if shape is None or shape[0] == 1 else arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise CoreError(f"{what}: expected a matrix, got an array of {arr.ndim} dimensions")
    if shape is not None and arr.shape != shape:
        raise CoreError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"{what}: contains NaN or Inf")
    return arr


def _check_psd(mat: np.ndarray, what: str, strict: bool = False) -> None:
    if not np.allclose(mat, mat.T, rtol=1e-9, atol=1e-300):
        raise CoreError(f"{what}: not symmetric")
    eig = np.linalg.eigvalsh(0.5 * (mat + mat.T))
    scale = max(float(np.max(np.abs(eig))), 1e-300)
    if strict and np.min(eig) <= 0:
        raise CoreError(f"{what}: not positive definite (smallest eigenvalue {np.min(eig):.3g})")
    if np.min(eig) < -1e-9 * scale:
        raise CoreError(f"{what}: not positive semidefinite "
                        f"(smallest eigenvalue {np.min(eig):.3g})")


@dataclass(frozen=True)
class ObservabilityReport:
    """Rank test and how weakly each state is observed over a span."""

    rank: int
    n: int
    span_s: float
    #: sqrt(P_post_kk / P0_kk) after fusing measurements over the span: 1 = nothing learned,
    #: close to 0 = well observed.
    std_ratio: tuple[float, ...]
    state_names: tuple[str, ...]

    @property
    def observable(self) -> bool:
        return self.rank == self.n

    def weak_states(self, threshold: float = 0.9) -> list[str]:
        return [nm for nm, r in zip(self.state_names, self.std_ratio) if r > threshold]

    def message(self) -> str:
        head = (f"observability rank {self.rank} of {self.n}: "
                + ("observable" if self.observable else "NOT observable"))
        parts = [f"{nm} {100 * (1 - r):.1f}% of prior std removed"
                 for nm, r in zip(self.state_names, self.std_ratio)]
        weak = self.weak_states()
        tail = (f"; weakly observable over {self.span_s:g} s: {', '.join(weak)}" if weak else "")
        return f"{head}; over {self.span_s:g} s: " + ", ".join(parts) + tail


@dataclass(frozen=True, eq=False)
class LinearModel:
    """A continuous-time linear Gaussian model with textbook names (A, B, Qc, H, R, P0)."""

    name: str
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    A: np.ndarray
    Qc: np.ndarray
    H: np.ndarray
    R: np.ndarray
    P0: np.ndarray
    B: np.ndarray | None = None
    #: typical standard deviation of each state, used to scale the filter's arithmetic
    scale: np.ndarray | None = None
    measurement_names: tuple[str, ...] = ("z",)
    params: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.state_names)
        if n == 0:
            raise CoreError(f"model {self.name!r}: no states")
        if len(self.state_units) != n:
            raise CoreError(f"model {self.name!r}: {n} state names but "
                            f"{len(self.state_units)} units")
        A = _matrix(self.A, (n, n), f"model {self.name!r}: A")
        Qc = _matrix(self.Qc, (n, n), f"model {self.name!r}: Qc")
        H = _matrix(self.H, None, f"model {self.name!r}: H")
        if H.shape[1] != n:
            raise CoreError(f"model {self.name!r}: H has {H.shape[1]} columns, the state has {n}")
        m = H.shape[0]
        R = _matrix(self.R, (m, m), f"model {self.name!r}: R")
        P0 = _matrix(self.P0, (n, n), f"model {self.name!r}: P0")
        _check_psd(Qc, f"model {self.name!r}: Qc")
        _check_psd(R, f"model {self.name!r}: R", strict=True)
        _check_psd(P0, f"model {self.name!r}: P0", strict=True)
        B = None if self.B is None else _matrix(self.B, None, f"model {self.name!r}: B")
        if B is not None and B.shape[0] != n:
            B = B.reshape(n, -1) if B.size % n == 0 else None
            if B is None:
                raise CoreError(f"model {self.name!r}: B must have {n} rows")
        scale = (np.sqrt(np.diag(P0)) if self.scale is None
                 else np.asarray(self.scale, dtype=float).reshape(-1))
        if scale.shape != (n,) or not np.all(np.isfinite(scale)) or np.any(scale <= 0):
            raise CoreError(f"model {self.name!r}: scale must be {n} positive numbers")
        names = tuple(self.measurement_names)
        if len(names) != m:
            names = tuple(f"z{i}" for i in range(m)) if m > 1 else ("z",)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "Qc", Qc)
        object.__setattr__(self, "H", H)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "P0", P0)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "scale", scale)
        object.__setattr__(self, "measurement_names", names)
        object.__setattr__(self, "state_names", tuple(self.state_names))
        object.__setattr__(self, "state_units", tuple(self.state_units))
        for arr in (A, Qc, H, R, P0, scale) + (() if B is None else (B,)):
            arr.setflags(write=False)
        object.__setattr__(self, "_cache", {})

    @property
    def n(self) -> int:
        return len(self.state_names)

    @property
    def m(self) -> int:
        return self.H.shape[0]

    def index(self, state_name: str) -> int:
        try:
            return self.state_names.index(state_name)
        except ValueError:
            raise CoreError(f"model {self.name!r} has no state {state_name!r}; "
                            f"states are {', '.join(self.state_names)}") from None

    def discretize(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Phi, Qd, Bd for a step of ``dt`` seconds, physical units: exact, by scipy's expm of
        Van Loan's matrices, cached per dt. (The filter's kernels run the
        compiled :func:`flight_fdi.core.discretize.van_loan` at every dt instead; the two agree to
        1e-12 of each state's scale, ``test/core/test_discretize.py``. This one stays for the
        simulator, whose sample bags are kept byte for byte, and for GLR's anchors.)"""
        if not np.isfinite(dt) or dt < 0:
            raise CoreError(f"discretize: dt must be finite and >= 0, got {dt!r}")
        key = float(dt)
        cache: dict = self._cache  # type: ignore[attr-defined]
        hit = cache.get(key)
        if hit is None:
            hit = _van_loan(self.A, self.Qc, self.B, key)
            if len(cache) > 512:
                cache.clear()
            cache[key] = hit
        return hit

    def observability(self, span_s: float, dt: float | None = None) -> ObservabilityReport:
        """Kalman rank test, and the std ratio of each state after fusing measurements
        every ``dt`` seconds (default span/1000) over ``span_s`` seconds, ignoring process noise."""
        n = self.n
        if not np.isfinite(span_s) or span_s <= 0:
            raise CoreError(f"observability: span must be > 0 s, got {span_s!r}")
        O = np.vstack([self.H @ np.linalg.matrix_power(self.A, k) for k in range(n)])
        T = np.diag(self.scale)
        rank = int(np.linalg.matrix_rank(O @ T))
        step = float(dt) if dt else span_s / 1000.0
        steps = max(1, int(round(span_s / step)))
        Phi, _, _ = self.discretize(step)
        Rinv = np.linalg.inv(self.R)
        # information about x(0) from z_k = H Phi^k x(0) + noise, in scaled coordinates
        W = np.zeros((n, n))
        M = T.copy()  # Phi^k T
        for _ in range(steps):
            M = Phi @ M
            HM = self.H @ M
            W += HM.T @ Rinv @ HM
        P0s = np.linalg.inv(T) @ self.P0 @ np.linalg.inv(T)
        post = np.linalg.inv(np.linalg.inv(P0s) + W)
        ratio = np.sqrt(np.clip(np.diag(post) / np.diag(P0s), 0.0, 1.0))
        return ObservabilityReport(rank, n, float(span_s), tuple(float(r) for r in ratio),
                                   self.state_names)

    def describe(self) -> dict:
        """Plain-data description (for ModelInfo messages and JSON)."""
        return {
            "name": self.name,
            "state_names": list(self.state_names),
            "state_units": list(self.state_units),
            "measurement_names": list(self.measurement_names),
            "A": self.A.tolist(), "Qc": self.Qc.tolist(), "H": self.H.tolist(),
            "R": self.R.tolist(), "P0": self.P0.tolist(),
            "B": None if self.B is None else self.B.tolist(),
            "scale": self.scale.tolist(),
            "params": dict(self.params),
        }

    def with_R(self, R: Any) -> "LinearModel":
        """The same model with another measurement covariance."""
        return LinearModel(self.name, self.state_names, self.state_units, self.A, self.Qc, self.H,
                           R, self.P0, self.B, self.scale, self.measurement_names, self.params)


def _van_loan(A: np.ndarray, Qc: np.ndarray, B: np.ndarray | None, dt: float):
    n = A.shape[0]
    if dt == 0.0:
        Bd = None if B is None else np.zeros_like(B)
        return np.eye(n), np.zeros((n, n)), Bd
    from scipy.linalg import expm  # (lazy: ~0.15 s of a fresh analyze, which never calls it)

    # Van Loan (1978): expm([[-A, Qc], [0, A^T]] dt) = [[., Phi^-1 Qd], [0, Phi^T]]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = Qc
    M[n:, n:] = A.T
    E = expm(M * dt)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    Qd = 0.5 * (Qd + Qd.T)
    Bd = None
    if B is not None:
        p = B.shape[1]
        C = np.zeros((n + p, n + p))
        C[:n, :n] = A
        C[:n, n:] = B
        Bd = expm(C * dt)[:n, n:]
    for arr in (Phi, Qd) + (() if Bd is None else (Bd,)):
        arr.setflags(write=False)
    return Phi, Qd, Bd


INS_STATES = ("velocity_error", "tilt", "accel_bias", "gyro_drift")
INS_UNITS = ("m/s", "rad", "m/s^2", "rad/s")


def ins_channel(g: float = G0, earth_radius: float = EARTH_RADIUS,
                tau_a: float = 3600.0, tau_w: float = 3600.0,
                sigma_a: float = 1e-3, sigma_w_deg_h: float = 0.01,
                sigma_ref: float = 0.1, sigma_v0: float = 0.1,
                sigma_tilt0: float = 1e-4) -> LinearModel:
    """The single-channel INS error model of seed 000 (SPEC section 1).

    x = [dV, tilt, da, dw]; dV' = -g tilt + da; tilt' = dV/R + dw; da, dw first-order Gauss-Markov
    with correlation times tau_a, tau_w and stationary stds sigma_a, sigma_w; z = dV + noise.
    """
    for nm, val in (("g", g), ("earth_radius", earth_radius), ("tau_a", tau_a), ("tau_w", tau_w),
                    ("sigma_a", sigma_a), ("sigma_w_deg_h", sigma_w_deg_h),
                    ("sigma_ref", sigma_ref), ("sigma_v0", sigma_v0), ("sigma_tilt0", sigma_tilt0)):
        if not np.isfinite(val) or val <= 0:
            raise CoreError(f"ins_channel: {nm} must be a positive number, got {val!r}")
    sigma_w = sigma_w_deg_h * DEG_PER_HOUR
    A = np.array([[0.0, -g, 1.0, 0.0],
                  [1.0 / earth_radius, 0.0, 0.0, 1.0],
                  [0.0, 0.0, -1.0 / tau_a, 0.0],
                  [0.0, 0.0, 0.0, -1.0 / tau_w]])
    Qc = np.diag([0.0, 0.0, 2.0 * sigma_a**2 / tau_a, 2.0 * sigma_w**2 / tau_w])
    P0 = np.diag([sigma_v0**2, sigma_tilt0**2, sigma_a**2, sigma_w**2])
    return LinearModel(
        name="ins_channel", state_names=INS_STATES, state_units=INS_UNITS,
        A=A, Qc=Qc, H=np.array([[1.0, 0.0, 0.0, 0.0]]), R=np.array([[sigma_ref**2]]), P0=P0,
        measurement_names=("velocity",),
        params={"g": g, "earth_radius": earth_radius, "tau_a": tau_a, "tau_w": tau_w,
                "sigma_a": sigma_a, "sigma_w_deg_h": sigma_w_deg_h, "sigma_ref": sigma_ref,
                "sigma_v0": sigma_v0, "sigma_tilt0": sigma_tilt0})


ATTITUDE_STATES = ("angle", "rate", "disturbance")
ATTITUDE_UNITS = ("rad", "rad/s", "rad/s^2")


def attitude_axis(m_c: float = 0.01, sigma_md_walk: float = 1e-7, sigma_angle: float = 1e-4,
                  sigma_rate: float | None = None, sigma_angle0: float = 1e-2,
                  sigma_rate0: float = 1e-3, sigma_md0: float = 1e-4) -> LinearModel:
    """The spacecraft attitude axis of seed 003 (SPEC section 7).

    x = [angle, rate, disturbance]; angle' = rate; rate' = m_c u + m_d; m_d' = small noise.
    z = angle (and rate when ``sigma_rate`` is given).
    """
    for nm, val in (("m_c", m_c), ("sigma_md_walk", sigma_md_walk), ("sigma_angle", sigma_angle),
                    ("sigma_angle0", sigma_angle0), ("sigma_rate0", sigma_rate0),
                    ("sigma_md0", sigma_md0)) + (
                        (("sigma_rate", sigma_rate),) if sigma_rate else ()):
        if not np.isfinite(val) or val <= 0:
            raise CoreError(f"attitude_axis: {nm} must be a positive number, got {val!r}")
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    B = np.array([[0.0], [m_c], [0.0]])
    Qc = np.diag([0.0, 0.0, sigma_md_walk**2])
    if sigma_rate:
        H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        R = np.diag([sigma_angle**2, sigma_rate**2])
        names: tuple[str, ...] = ("angle", "rate")
    else:
        H = np.array([[1.0, 0.0, 0.0]])
        R = np.array([[sigma_angle**2]])
        names = ("angle",)
    return LinearModel(
        name="attitude_axis", state_names=ATTITUDE_STATES, state_units=ATTITUDE_UNITS,
        A=A, Qc=Qc, H=H, R=R, P0=np.diag([sigma_angle0**2, sigma_rate0**2, sigma_md0**2]), B=B,
        measurement_names=names,
        params={"m_c": m_c, "sigma_md_walk": sigma_md_walk, "sigma_angle": sigma_angle,
                "sigma_rate": sigma_rate or 0.0, "sigma_angle0": sigma_angle0,
                "sigma_rate0": sigma_rate0, "sigma_md0": sigma_md0})


def model_from_dict(data: Mapping[str, Any], source: str = "model") -> LinearModel:
    """Build a model from plain data (the YAML schema documented in config/model_example.yaml).

    Keys: name, states (list of {name, unit}), A, H, R, P0, and either Qc or G (then Qc = G G^T);
    optional: B, scale, measurements (list of names).
    """
    if not isinstance(data, Mapping):
        raise CoreError(f"{source}: expected a mapping at the top level")
    # "redundancy" belongs to core.redundancy (criticality analysis) and is not part of the model
    unknown = set(data) - {"name", "states", "A", "Qc", "G", "H", "R", "P0", "B", "scale",
                           "measurements", "params", "redundancy"}
    if unknown:
        raise CoreError(f"{source}: unknown keys {sorted(unknown)}")
    for key in ("states", "A", "H", "R", "P0"):
        if key not in data:
            raise CoreError(f"{source}: missing key {key!r}")
    states = data["states"]
    if not isinstance(states, Sequence) or not states:
        raise CoreError(f"{source}: 'states' must be a non-empty list of {{name, unit}}")
    try:
        names = tuple(str(s["name"]) for s in states)
        units = tuple(str(s.get("unit", "")) for s in states)
    except (TypeError, KeyError):
        raise CoreError(f"{source}: each state needs a 'name' (and a 'unit')") from None
    n = len(names)
    if ("Qc" in data) == ("G" in data):
        raise CoreError(f"{source}: give exactly one of 'Qc' and 'G'")
    if "Qc" in data:
        Qc = _matrix(data["Qc"], (n, n), f"{source}: Qc")
    else:
        G = _matrix(data["G"], None, f"{source}: G")
        if G.shape[0] != n:
            G = G.reshape(n, -1) if G.size % n == 0 else G
        if G.shape[0] != n:
            raise CoreError(f"{source}: G must have {n} rows")
        Qc = G @ G.T
    meas = data.get("measurements")
    return LinearModel(
        name=str(data.get("name", source)), state_names=names, state_units=units,
        A=data["A"], Qc=Qc, H=data["H"], R=data["R"], P0=data["P0"], B=data.get("B"),
        scale=data.get("scale"),
        measurement_names=tuple(meas) if meas else ("z",),
        params={str(k): float(v) for k, v in dict(data.get("params") or {}).items()})


def read_yaml(path: str | Path) -> Any:
    """The data of a YAML file (model files); CoreError naming the file when it cannot be read."""
    import yaml  # PyYAML ships with the ROS wheels; imported lazily to keep the core light

    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise CoreError(f"model file {p}: {exc.strerror or exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CoreError(f"model file {p}: not valid YAML ({exc})") from None


def load_model(path: str | Path) -> LinearModel:
    """Load a model YAML file."""
    return model_from_dict(read_yaml(path), source=str(path))


BUILTIN_MODELS = {"ins_channel": ins_channel, "attitude_axis": attitude_axis}


def get_model(name_or_path: str, **params: float) -> LinearModel:
    """A built-in model by name (with parameter overrides) or a YAML file by path."""
    if name_or_path in BUILTIN_MODELS:
        try:
            return BUILTIN_MODELS[name_or_path](**params)
        except TypeError as exc:
            raise CoreError(f"model {name_or_path}: {exc}") from None
    if name_or_path.endswith((".yaml", ".yml")) or "/" in name_or_path:
        if params:
            raise CoreError("parameter overrides apply only to built-in models")
        return load_model(name_or_path)
    raise CoreError(f"unknown model {name_or_path!r}; built-in models are "
                    f"{', '.join(BUILTIN_MODELS)}, or give a path to a YAML file")
