"""The 3-D post-flight isolator (``ins3d``) on the real Xsens DOT recordings (docs/ins3d_real.md).

A recording of ../shared/data/mimu_quadrotor (``<group>/path_N``: ``IMU_k.csv.gz`` at 120 Hz,
``GT.csv.gz`` RTK at 10 Hz) becomes the 3-D input contract in memory (``build_input``):

* **INS**: one unit's samples, its turn-on biases removed with a per-unit calibration learnt on
  the *other* recordings of the same flight day (``calibrate``, leave-one-out), mechanized by
  ``sim.strapdown.mechanize`` (second order, free vertical channel) from the RTK ground truth at
  the first sample: position, velocity (central difference) and attitude (compass heading,
  pitch, roll).
* **Frames**: the Xsens DOT sensor frame is x forward, y left, z up (+g on z at rest) -- the
  model's body frame; checked on the data: Acc_x ~ -g sin(nose-down pitch), Acc_y ~ -g sin(roll
  left-wing-down), and the units' own Euler_X/Y equal GT roll and minus GT pitch within ~2 deg.
  The GT angles are aerospace (heading clockwise from north, pitch nose up, roll right wing down):
  yaw_ENU = 90 deg - heading, pitch_REP103 = -pitch, roll = roll. The units are co-mounted with
  the airframe's nose along body x (the straight flights' track equals the GT heading to 1 deg).
* **Reference**: RTK North/East/Down differentiated by central differences (2 x 0.1 s), i.e. no
  latency, white position noise becomes an MA(2) velocity noise; Down is quantised to 0.1 m in the
  files, so the up row is far noisier than the horizontal ones (its variance is set accordingly).

Faults (``Fault``) are added to the unit's samples before the mechanization, so the real noise,
vibration and mounting errors stay.
"""
from __future__ import annotations

import gzip
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..bagio.ins3d_input import Ins3dInput, build_input
from ..core.earth import radii
from ..core.ins3d.data import with_height
from ..core.ins3d.grades import DEG_H, DEG_RTH, ImuGrade
from ..core.rotation import dcm_array
from .errors import EvalError
from .real3d_record import REFERENCE_GLITCHES, judge, record

RATE_HZ = 120.0
GT_DT = 0.1
LAT0_DEG = 32.77            # Haifa (the dataset's site; absolute position is not in the files)
GT_COLUMNS = ("time", "distance", "speed", "heading", "pitch", "roll", "height", "north", "east",
              "down")
#: the flight days, told apart by the units' time offsets (docs/voter_real.md)
DAYS = {"straight": [f"straight/path_{i}" for i in range(1, 5)],
        "vertical_a": [f"vertical/path_{i}" for i in range(1, 8)],
        "vertical_b": [f"vertical/path_{i}" for i in range(8, 15)]}
AXES = ("x", "y", "z")


def default_data_dir() -> Path:
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "mimu_quadrotor"


def day_of(name: str) -> str:
    for day, names in DAYS.items():
        if name in names:
            return day
    raise EvalError(f"{name}: not a recording of the mimu_quadrotor set")


@dataclass
class Recording:
    """One unit of one recording: IMU on a uniform 120-Hz grid (rad/s, m/s^2) and the GT."""

    name: str
    unit: int
    t: np.ndarray          # (N,) s
    gyro: np.ndarray       # (N, 3) rad/s body
    accel: np.ndarray      # (N, 3) m/s^2 body
    gt: dict[str, np.ndarray]
    dropped: int = 0       # IMU rows whose time did not increase (dropped, then resampled)


def read_gt(path: Path) -> dict[str, np.ndarray]:
    """The GT CSV as arrays (time s, speed m/s, heading/pitch/roll deg, north/east/down m)."""
    try:
        with gzip.open(path, "rt") as fh:
            header = fh.readline()
        with warnings.catch_warnings():     # an empty file: the check below says so
            warnings.simplefilter("ignore", UserWarning)
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, EOFError, ValueError) as exc:
        raise EvalError(f"{path}: cannot read the ground truth ({exc})") from None
    if len(header.split(",")) != len(GT_COLUMNS) or data.shape[1] != len(GT_COLUMNS) \
            or data.shape[0] < 5:
        raise EvalError(f"{path}: expected >= 5 rows of {len(GT_COLUMNS)} GT columns, header "
                        f"{header.strip()!r}")
    return {c: data[:, i] for i, c in enumerate(GT_COLUMNS)}


def read_recording(data_dir: Path, name: str, unit: int) -> Recording:
    """IMU_``unit`` and GT of ``data_dir/name``; rows whose time does not increase are dropped
    and the samples interpolated onto the 1/120-s grid (the files' time is that grid)."""
    from ..cli.imu_csv import read_csv
    d = Path(data_dir) / name
    t, vals = read_csv(d / f"IMU_{unit}.csv.gz")
    keep = np.concatenate([[True], np.diff(t) > 0])
    keep &= np.maximum.accumulate(t) == t
    t, vals = t[keep], vals[keep]
    # the files' step is 0.008333 s (1/120 rounded): the grid keeps their sample count
    grid = t[0] + np.arange(int(round((t[-1] - t[0]) * RATE_HZ)) + 1) / RATE_HZ
    res = np.stack([np.interp(grid, t, vals[:, i]) for i in range(6)], axis=1)
    return Recording(name, unit, grid, res[:, :3], res[:, 3:], read_gt(d / "GT.csv.gz"),
                     int(np.sum(~keep)))


def gt_quaternions(gt: dict[str, np.ndarray]) -> np.ndarray:
    """(M, 4) q_b^n (ENU, body x forward / y left / z up) of the GT attitude."""
    from ..core.rotation import quat_from_euler_array
    heading = np.unwrap(np.radians(gt["heading"]))
    return quat_from_euler_array(np.pi / 2 - heading, -np.radians(gt["pitch"]),
                                 np.radians(gt["roll"]))


def gt_enu(gt: dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([gt["east"], gt["north"], -gt["down"]], axis=1)


def gt_velocity(gt: dict[str, np.ndarray], half: int = 1, every: int = 1
                ) -> tuple[np.ndarray, np.ndarray]:
    """(t, v ENU) by central differences of the RTK positions over +-``half`` samples (the mean
    velocity over that span, stamped at its centre: no latency), at every ``every``-th sample."""
    p, t = gt_enu(gt), gt["time"]
    m = half
    v = (p[2 * m:] - p[:-2 * m]) / (t[2 * m:] - t[:-2 * m])[:, None]
    return t[m:-m][::every], v[::every]


def _body_rates(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(M-1, 3) mean body rates over each GT interval from consecutive attitudes:
    log(q_k^-1 q_k+1) / dt (``rotation.attitude_error_array`` gives -log(a b^-1))."""
    from ..core.rotation import attitude_error_array
    conj = np.array([1.0, -1.0, -1.0, -1.0])
    return -attitude_error_array(q[:-1] * conj, q[1:] * conj) / np.diff(t)[:, None]


def recording_biases(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """(gyro bias rad/s, accel bias m/s^2) of this unit on this recording against the GT: the
    mean measured rate minus the mean GT body rate, the mean specific force minus the GT's
    C_n^b (a - g) (a from the RTK positions), over the GT span. Used only to calibrate *other*
    recordings (``calibrate``) and to describe the units."""
    gt = rec.gt
    q = gt_quaternions(gt)
    tg = gt["time"]
    w_true = _body_rates(q, tg).mean(axis=0)
    span = (rec.t >= tg[0]) & (rec.t <= tg[-1])
    b_g = rec.gyro[span].mean(axis=0) - w_true
    tv, v = gt_velocity(gt)
    a = (v[2:] - v[:-2]) / (tv[2:] - tv[:-2])[:, None]
    from ..core.earth import gravity
    g = gravity(math.radians(LAT0_DEG), 0.0)
    C = dcm_array(q[2:-2])                          # C_b^n at the acceleration stamps
    f_true = np.einsum("kji,kj->ki", C, a + np.array([0.0, 0.0, g]))
    f_meas = np.stack([np.interp(tv[1:-1], rec.t, rec.accel[:, i]) for i in range(3)], axis=1)
    return b_g, (f_meas - f_true).mean(axis=0)


@dataclass
class Calibration:
    """Per unit and day: the turn-on biases removed before mechanization (leave-one-out)."""

    biases: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def for_recording(self, name: str, unit: int) -> tuple[np.ndarray, np.ndarray]:
        """Median over the other recordings of ``name``'s day (never ``name`` itself)."""
        others = [r for r in DAYS[day_of(name)] if r != name and (r, unit) in self.biases]
        if not others:
            return np.zeros(3), np.zeros(3)
        bg = np.median([self.biases[(r, unit)][0] for r in others], axis=0)
        ba = np.median([self.biases[(r, unit)][1] for r in others], axis=0)
        return bg, ba

    def residuals(self) -> tuple[np.ndarray, np.ndarray]:
        """(gyro, accel) per (recording, unit) minus its leave-one-out calibration, (n, 3)."""
        rg, ra = [], []
        for (name, unit), (bg, ba) in sorted(self.biases.items()):
            cg, ca = self.for_recording(name, unit)
            rg.append(bg - cg)
            ra.append(ba - ca)
        return np.array(rg), np.array(ra)


def calibrate(data_dir: Path, names: list[str], units: list[int]) -> Calibration:
    cal = Calibration()
    for name in names:
        for u in units:
            cal.biases[(name, u)] = recording_biases(read_recording(data_dir, name, u))
    return cal


def xsens_grade(gyro_bias: float = 400 * DEG_H, accel_bias: float = 0.5,
                arw: float = 3.0 * DEG_RTH, vrw: float = 0.02) -> ImuGrade:
    """A grade for the calibrated Xsens DOT units: residual turn-on biases (1 sigma, the spread of
    the leave-one-out residuals, docs/ins3d_real.md), the vibration as white noise (ARW, VRW
    from the 120-Hz sample spread between co-mounted units), 1-deg compass heading."""
    return ImuGrade("xsens_dot", gyro_bias=gyro_bias, gyro_instability=30 * DEG_H,
                    gyro_tau_s=300.0, arw=arw, gyro_scale=5e-3,
                    gyro_misalign=1e-2, accel_bias=accel_bias, accel_instability=0.02,
                    accel_tau_s=300.0, vrw=vrw, accel_scale=5e-3, accel_misalign=1e-2,
                    heading_sigma=math.radians(2.0))


@dataclass(frozen=True)
class Fault:
    """A bias step added to the unit's samples from ``onset_s`` (s from the recording's start):
    sensor ``accelerometer`` (m/s^2) or ``gyro`` (rad/s), body ``axis`` x/y/z."""

    sensor: str
    axis: str
    magnitude: float
    onset_s: float

    def apply(self, rec: Recording) -> Recording:
        i = AXES.index(self.axis)
        on = rec.t - rec.t[0] >= self.onset_s
        gyro, accel = rec.gyro.copy(), rec.accel.copy()
        (accel if self.sensor == "accelerometer" else gyro)[on, i] += self.magnitude
        return Recording(rec.name, rec.unit, rec.t, gyro, accel, rec.gt, rec.dropped)


@dataclass(frozen=True)
class Contract:
    """Settings of the contract built from a recording."""

    imu_rate_hz: float = 40.0
    ref_half: int = 5              # GT samples each side of the central difference (0.5 s)
    ref_every: int = 10            # one reference per 10 GT samples (1 Hz, disjoint spans)
    #: compare like with like: the reference (a mean over its span) gets the INS's own
    #: v(t) - mean over the span added (the shape of the velocity within the span, from the INS)
    ref_ins_shape: bool = True
    ref_sigma_h: float = 0.06      # m/s, horizontal RTK-differenced velocity noise (1 sigma)
    ref_sigma_u: float = 0.10      # m/s, up: Down quantised to 0.1 m in the files
    #: a height reference row: the files' barometric height (Down, 0.1-m steps) at the
    #: reference stamps, white with this sigma (m); None: no height row
    height_sigma: float | None = None


def initial_state(gt: dict[str, np.ndarray]):
    """(lat, lon, h, v ENU, q) at the first GT sample: position from NED about the site,
    velocity from a quadratic fit of the first five positions, attitude from the GT angles."""
    p, t = gt_enu(gt)[:5], gt["time"][:5] - gt["time"][0]
    v0 = np.polyfit(t, p, 2)[1]
    lat0 = math.radians(LAT0_DEG)
    r_n, r_m = radii(lat0)
    lat = lat0 + p[0, 1] / r_m
    lon = p[0, 0] / (r_n * math.cos(lat0))
    return lat, lon, float(p[0, 2]), v0, gt_quaternions(gt)[0]


def mechanize_recording(rec: Recording, bg: np.ndarray, ba: np.ndarray):
    """The free-inertial solution of the unit (biases bg, ba removed) from the GT's first sample
    (the IMU grid is cut to start there): (t, NavSolution, f, w) with f, w the compensated means
    per 1/120-s interval."""
    from ..sim.strapdown import mechanize
    t0 = rec.gt["time"][0]
    i0 = int(np.searchsorted(rec.t, t0 - 1e-9))
    t = rec.t[i0:]
    w = rec.gyro[i0 + 1:] - bg          # sample k+1 = the mean over (t_k, t_k+1]
    f = rec.accel[i0 + 1:] - ba
    dt = 1.0 / RATE_HZ
    nav = mechanize(w * dt, f * dt, dt, initial_state(rec.gt))
    return t, nav, f, w


def _span_shape(t: np.ndarray, v: np.ndarray, tc: np.ndarray, half: float) -> np.ndarray:
    """(M, 3) v(tc) - the mean of v over [tc - half, tc + half] (trapezoid, v sampled at t)."""
    cum = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None],
                                                 axis=0)])
    lo, hi = np.clip(tc - half, t[0], t[-1]), np.clip(tc + half, t[0], t[-1])
    integ = np.stack([np.interp(hi, t, cum[:, i]) - np.interp(lo, t, cum[:, i])
                      for i in range(3)], axis=1)
    now = np.stack([np.interp(tc, t, v[:, i]) for i in range(3)], axis=1)
    return now - integ / np.maximum(hi - lo, 1e-9)[:, None]


def contract_arrays(rec: Recording, bg: np.ndarray, ba: np.ndarray,
                    cfg: Contract = Contract(),
                    reference_of: Recording | None = None) -> dict[str, np.ndarray]:
    """The four contract topics of ``rec`` as arrays (``build_input``'s arguments + lon).
    ``reference_of``: the recording whose INS gives the reference's shape within its span
    (``Contract.ref_ins_shape``; default ``rec``). A fault run passes the recording before the
    fault: the reference is then the same as on the nominal run -- a reference does not see
    the IMU under test (with the faulty INS's shape it would carry the fault's curvature)."""
    t, nav, f, w = mechanize_recording(rec, bg, ba)
    every = int(round(RATE_HZ / cfg.imu_rate_hz))
    m = (t.size - 1) // every
    idx = every * np.arange(0, m + 1)
    fm = np.vstack([f[:1], f[:m * every].reshape(m, every, 3).mean(axis=1)])
    wm = np.vstack([w[:1], w[:m * every].reshape(m, every, 3).mean(axis=1)])
    tr, vr = gt_velocity(rec.gt, cfg.ref_half, cfg.ref_every)
    inside = (tr > t[idx[0]]) & (tr <= t[idx[-1]])
    if cfg.ref_ins_shape:
        t_s, nav_s = (t, nav) if reference_of is None else \
            mechanize_recording(reference_of, bg, ba)[:2]
        vr = vr + _span_shape(t_s, nav_s.v, tr, cfg.ref_half * GT_DT)
    r = np.array([cfg.ref_sigma_h**2, cfg.ref_sigma_h**2, cfg.ref_sigma_u**2])
    out = {"t_imu": t[idx], "q": nav.q[idx], "f_b": fm, "w_b": wm, "t_vel": t[idx],
           "v": nav.v[idx], "t_fix": t[idx], "lat": nav.lat[idx], "h": nav.h[idx],
           "t_ref": tr[inside], "v_ref": vr[inside],
           "r_ref": np.broadcast_to(r, vr[inside].shape), "lon": nav.lon[idx]}
    if cfg.height_sigma is not None:
        out["h_ref"] = np.interp(tr[inside], rec.gt["time"], -rec.gt["down"])
    return out


def build_contract(rec: Recording, bg: np.ndarray, ba: np.ndarray,
                   cfg: Contract = Contract(),
                   reference_of: Recording | None = None) -> Ins3dInput:
    """The four contract topics of ``rec`` in memory (``bagio.ins3d_input.build_input``;
    ``reference_of``: ``contract_arrays``)."""
    a = contract_arrays(rec, bg, ba, cfg, reference_of)
    a.pop("lon")
    h_ref = a.pop("h_ref", None)
    inp = build_input(**a)
    if h_ref is not None:            # the third row: the barometric height (m)
        inp.refs = with_height(inp.refs, a["t_fix"], a["h"], a["v"][:, 2], h_ref,
                               cfg.height_sigma**2)
    return inp


#: the height reference topic of a contract bag with ``Contract.height_sigma``
HEIGHT_TOPIC = "/reference/height"


def write_contract_bag(rec: Recording, bg: np.ndarray, ba: np.ndarray, path: str | Path,
                       cfg: Contract | None = None, epoch_s: int = 1_700_000_000,
                       overwrite: bool = False, settings: "Settings | None" = None,
                       reference_of: Recording | None = None) -> dict[str, int]:
    """The same contract as a bag (the topics and frames of ``sim.bag3d``): the user-facing path.
    Its metadata ``flight_fdi.sim3d`` says ``vertical: free`` (the INS) and, in its
    ``error_model`` block (``error_model_of``), how ``settings`` (default ``Settings()``) models
    this INS and reference -- what ``flight-fdi analyze/run --model ins3d`` then use
    (``bagio.ins3d_input.error_model_options``). ``cfg``: the contract (default
    ``settings.contract``); with ``Contract.height_sigma`` also ``HEIGHT_TOPIC``: the GT height
    ``build_contract`` interpolates, as NavSatFix (Up variance height_sigma^2; the GT's latitude
    and longitude, unmeasured) for ``--height-topic`` (datum ``absolute``: the INS starts at the
    GT's height). ``reference_of``: ``contract_arrays``'. Returns message counts."""
    import json

    from ..bagio import cdr
    from ..bagio.ins3d_payloads import (height_payloads, imu_payloads, ins_fix_payloads,
                                        velocity_payloads)
    from ..bagio.writer import open_writer
    settings = settings or Settings()
    cfg = cfg or settings.contract
    a = contract_arrays(rec, bg, ba, cfg, reference_of)

    def ns(t):
        return epoch_s * 1_000_000_000 + np.round(np.asarray(t) * 1e9).astype(np.int64)
    s_imu, s_ref = ns(a["t_imu"]), ns(a["t_ref"])
    ins_kind, ins_v = velocity_payloads(s_imu, a["v"])
    ref_kind, ref_v = velocity_payloads(s_ref, a["v_ref"], a["r_ref"][0])
    series = [
        ("/ins/imu", cdr.IMU, s_imu, imu_payloads(s_imu, a["q"], a["w_b"], a["f_b"])),
        ("/ins/velocity", ins_kind, s_imu, ins_v),
        ("/ins/fix", cdr.NAVSATFIX, s_imu, ins_fix_payloads(s_imu, a["lat"], a["lon"], a["h"])),
        ("/reference/velocity", ref_kind, s_ref, ref_v)]
    contract = {"imu_rate_hz": cfg.imu_rate_hz, "ref_half": cfg.ref_half,
                "ref_every": cfg.ref_every, "ref_ins_shape": cfg.ref_ins_shape}
    if cfg.height_sigma is not None:   # the GT's barometric height at its own 10-Hz stamps
        enu, lat0, s_gt = gt_enu(rec.gt), math.radians(LAT0_DEG), ns(rec.gt["time"])
        r_n, r_m = radii(lat0)
        series.append((HEIGHT_TOPIC, cdr.NAVSATFIX, s_gt, height_payloads(
            cdr.NAVSATFIX, s_gt, "baro", enu[:, 2], cfg.height_sigma**2,
            lat0 + enu[:, 1] / r_m, enu[:, 0] / (r_n * math.cos(lat0)))))
        contract.update(height_sigma=cfg.height_sigma, height_topic=HEIGHT_TOPIC)
    doc = json.dumps({"vertical": "free", "source": f"mimu_quadrotor {rec.name} IMU_{rec.unit}",
                      "contract": contract, "error_model": error_model_of(settings)},
                     sort_keys=True)
    with open_writer(Path(path), storage="mcap", overwrite=overwrite) as bag:
        bag.set_metadata("flight_fdi.sim3d", doc)
        bag.write_series(series)
        return dict(bag.counts)


def error_model_of(settings: "Settings") -> dict:
    """The bag description's ``error_model`` block of ``settings`` (``analyze``'s model options:
    vertical channel, latency state, no reference Markov noise, the prior)."""
    return {"vertical": settings.vertical, "latency": bool(settings.latency),
            "reference_markov": None if settings.ref_markov is None else
            [float(v) for v in settings.ref_markov],
            "initial_attitude": "levelled" if settings.aligned_prior else "independent"}


@dataclass(frozen=True)
class Settings:
    """The analysis of a real recording: the contract, the grade's residual turn-on biases (1
    sigma) and ``analyze_ins3d``'s options (free vertical channel: the flights last <= 37 s)."""

    contract: Contract = Contract()
    #: residual turn-on biases after the leave-one-out calibration, 1 sigma: gyro ~ the largest
    #: axis rms (404 deg/h), accelerometer above the rms (0.09-0.30 m/s^2) since single
    #: recordings reach ~1 m/s^2 on z (chosen on the nominal results, docs/ins3d_real.md)
    gyro_bias_deg_h: float = 400.0
    accel_bias: float = 0.5
    arw_deg_rt_h: float = 3.0      # tools/ins3d_real_eval.py compares 3, 10 and 60
    vrw: float = 0.02              # m/s/sqrt(s)
    rows: int = 2                  # east, north: the files' Down is the DJI height, not RTK
    vertical: str = "free"
    latency: bool = True
    fisher_window: int = 5         # the seed method on ~10-37 reference updates
    min_valid_steps: int = 5
    #: the model's relative signature error on these flights (rad; ``glr3d.settle``): the
    #: 95 % quantile, over the fault runs of the fit days (straight, vertical 1-7) whose true
    #: sensor and axis is the best or the runner-up, of the angle the true signature is off
    #: the data beyond noise (``real3d_error.model_error_angle``; tools/ins3d_real_eval.py,
    #: seed 1). None: the grade's misalignment. Session 15: 0.000 of 293 runs (max 0.42), so
    #: None; it was 0.33 (q95 0.336 / 0.264) while the fault runs' reference carried the
    #: faulty INS's shape (``nominal_reference``) -- the allowance had measured that.
    signature_error: float | None = None
    #: True (default): a fault run's reference is the nominal run's (``contract_arrays``'
    #: ``reference_of``); False: built with the faulty INS's shape (before session 15)
    nominal_reference: bool = True
    #: False (default): independent initial states -- the contract's attitude is the ground
    #: truth's, not levelled on the unit's accelerometer; True: the initial covariance of a
    #: levelled INS (``Ins3dModel.p0_aligned``: the tilt cancels the horizontal accelerometer
    #: bias), the default before
    aligned_prior: bool = False
    #: the initial vertical velocity error's sigma (m/s; None: the horizontal 0.05): the first
    #: GT velocity is a fit to 0.1-m height steps (errors up to ~1 m/s against the height)
    v0_sigma_up: float | None = None
    #: the reference's Markov noise (sigma_h m/s, sigma_v, tau s; sigma_v in m for a height row,
    #: ``Ins3dModel.ref_markov``); None: white
    ref_markov: tuple[float, float, float] | None = None

    @property
    def height(self) -> bool:
        """A height reference row (``Contract.height_sigma``): 3 rows, the position states."""
        return self.contract.height_sigma is not None

    def grade(self) -> ImuGrade:
        return xsens_grade(self.gyro_bias_deg_h * DEG_H, self.accel_bias,
                           self.arw_deg_rt_h * DEG_RTH, self.vrw)

    def diagnosis(self):
        """The seed method's rules (``DiagnosisConfig``) for these short flights."""
        from ..core.diagnosis import DiagnosisConfig
        return DiagnosisConfig(fisher_window=self.fisher_window,
                               min_valid_steps=self.min_valid_steps)


def analyze(rec: Recording, bg: np.ndarray, ba: np.ndarray, settings: Settings = Settings(),
            reference_of: Recording | None = None):
    """``analyze_ins3d`` of the contract built from ``rec`` (biases bg, ba removed; the
    reference's shape from ``reference_of``'s INS: ``contract_arrays``); the model
    options through the bag description's ``error_model`` block (``error_model_of``, read back
    by ``bagio.ins3d_input.error_model_options``), as ``flight-fdi analyze`` on the bag."""
    from ..bagio.ins3d_input import ERROR_MODEL, error_model_options
    from ..core.ins3d.analysis import analyze_ins3d
    inp = build_contract(rec, bg, ba, settings.contract, reference_of)
    options = error_model_options({ERROR_MODEL: error_model_of(settings)}, "real3d.Settings")
    height = {"rows": 3, "position": True, "height_row": True} if settings.height else \
        {"rows": settings.rows}
    return analyze_ins3d(inp.steps, inp.refs, grade=settings.grade(),
                         diagnosis=settings.diagnosis(), signature_error=settings.signature_error,
                         v0_sigma_up=settings.v0_sigma_up, **height, **options)


def fault_runs(data_dir: Path, cal: Calibration, names: list[str], units: list[int],
               sensor: str, axis: str, magnitude: float, seed: int,
               settings: Settings = Settings(), margin_s: tuple[float, float] = (3.0, 5.0)):
    """One run per recording x unit with a step of |``magnitude``| (random sign) on ``sensor``
    ``axis`` at a random onset in [margin0, T - margin1] s (seeded per run), the reference the
    nominal run's (``Settings.nominal_reference``); yields (name, unit, Fault, record,
    outcome)."""
    for i, name in enumerate(names):
        for unit in units:
            rng = np.random.default_rng([seed, i, unit, AXES.index(axis),
                                         0 if sensor == "accelerometer" else 1])
            rec = read_recording(data_dir, name, unit)
            dur = rec.gt["time"][-1] - rec.gt["time"][0]
            onset = float(rng.uniform(margin_s[0], dur - margin_s[1]))
            mag = float(magnitude * rng.choice([-1.0, 1.0]))
            fault = Fault(sensor, axis, mag, onset)
            bg, ba = cal.for_recording(name, unit)
            ref = rec if settings.nominal_reference else None
            out = record(analyze(fault.apply(rec), bg, ba, settings, reference_of=ref))
            yield name, unit, fault, out, judge(out, fault, REFERENCE_GLITCHES.get(name, ()))


def names_in(data_dir: Path) -> list[str]:
    return [n for day in DAYS.values() for n in day if (Path(data_dir) / n / "GT.csv.gz").exists()]


__all__ = ["AXES", "Calibration", "Contract", "DAYS", "Fault", "Recording", "Settings", "analyze",
           "build_contract", "calibrate", "contract_arrays", "day_of", "default_data_dir",
           "error_model_of", "fault_runs", "gt_quaternions", "gt_velocity", "initial_state",
           "judge", "mechanize_recording", "names_in", "read_gt", "read_recording", "record",
           "recording_biases", "REFERENCE_GLITCHES", "write_contract_bag", "xsens_grade"]
