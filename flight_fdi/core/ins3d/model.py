"""The 3-D strapdown INS error-state model ``ins3d`` (phi-angle form, local-level ENU).

References: Titterton & Weston, *Strapdown Inertial Navigation Technology* (2nd ed.), ch. 12
(the phi-angle error equations); Groves, *Principles of GNSS, Inertial, and Multisensor
Integrated Navigation Systems* (2nd ed.), ch. 14 (local-navigation-frame error model). SPEC §8.

Conventions (the simulator's, docs/sim3d.md): navigation frame ENU (REP 103), body x forward,
y left, z up; C = C_b^n (body -> ENU). Attitude error phi (ENU, rad) with
C_INS = (I - [phi x]) C_true; velocity error dv = v_INS - v_true (ENU, m/s); position error
dp = p_INS - p_true in local metres (dp_E = (R_N + h) cos L dlon, dp_N = (R_M + h) dL,
dp_U = dh); accelerometer bias ba and gyro bias bg in **body** axes (m/s^2, rad/s).

State (``STATE_NAMES``; 12, or 15 with ``position=True``)::

    x = [dv_E dv_N dv_U | phi_E phi_N phi_U | ba_x ba_y ba_z | bg_x bg_y bg_z | dp_E dp_N dp_U]

Continuous dynamics, f = f^n the specific force in ENU, w_ie, w_en the Earth and transport
rates (``core.earth``), w_in = w_ie + w_en, D dv = dw_en(dv) the transport-rate error of a velocity
error, Np dp / Mp dp = the rate errors of a position error (dw_ie + dw_en resp. 2 dw_ie + dw_en)::

    dv'  = f x phi + C ba - (2 w_ie + w_en) x dv + v x (D dv + Mp dp) + dg(dh)
    phi' = -w_in x phi + D dv + Np dp - C bg
    ba'  = -ba / tau_a + w_a,     bg' = -bg / tau_g + w_g
    dp'  = dv + (transport of the local frame: terms in v / R, see ``fill_F``)

dg = (0, 0, -dg/dh dh) with the derivative of the simulator's normal gravity. In level flight
(f = (0, 0, g)) the east channel is dv_E' = -g phi_N + (C ba)_E: SPEC §1's V' = -g delta + a.

Bias model per grade (``grades.GRADES``, turn-on sigma0, Gauss-Markov sigma, tau): one
first-order Markov state per axis with the stationary variance sigma0^2 + sigma^2 and the
short-term wander of the GM part, q = 2 sigma^2 / tau, hence tau_c = tau (sigma0^2 + sigma^2) /
sigma^2 (a turn-on bias is a very slow Markov process, not a decaying one). Qc: VRW^2 on each
velocity axis, ARW^2 on each attitude axis (isotropic triads: C VRW^2 I C^T = VRW^2 I), q on the
biases, nothing on the position. Scale-factor and misalignment errors are not states.

Discretisation per step at the actual dt (``discretize``): Phi = I + F dt + (F dt)^2 / 2 (second
order series) and Qd = the Van Loan integral by its Taylor series to dt^3 (the trapezoidal
first-order form misses the dt^3 / 3 of the position from the velocity noise by 50 %); errors
against expm and Van Loan at the flight's step measured in test/ins3d/test_model.py
(docs/ins3d.md).

Vertical channel (``vertical``): ``free`` -- the equations above (unstable through dg, use with
``position=True``); ``damped`` -- dv_U is cut from the other states and modelled as a
first-order Markov state of its own (``tau_vertical_s``, ``sigma_vertical``), for an INS whose
height loop is not known: an unmodelled loop cannot pull the horizontal channels through the
Coriolis term; the vertical accelerometer bias enters only the horizontal channels (through C
when the aircraft banks). ``loop`` -- the INS's own third-order height loop on the aiding
height, with the height error dh, its integral and the aiding error as states after the core ones
(``core.ins3d.vertical``: equations, gains, known answer): a vertical accelerometer bias then
shows in dv_U as the loop's transient, seen by a vertical reference row (``rows=3``).

Measurement: z = v_INS - v_ref = H x + noise, H = [I 0 ...] on 2 (east, north) or 3 rows.
Optional (``latency=True``) last state: the reference latency tau (s, a constant): the reference
reports v(t - tau) ~ v(t) - a_n tau, so z = dv + a_n tau + noise, H's last column = a_n (the INS
acceleration over the Earth at the update, ``data.RefRows.a``). Optional
(``ref_markov=(sigma_h, sigma_v, tau)``) reference Markov noise states m (one per row, before
the latency): z = dv + m + ..., m' = -m / tau + w; the white R is then the published variance
minus sigma^2 (``filter.run_forward``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..earth import A, E2, GE, GF, GK, GM_RATIO, OMEGA_IE, gravity, radii
from .grades import G0 as GRAVITY0
from .defaults import VERTICAL
from .grades import GRADES, ImuGrade
from .vertical import VerticalLoop, fill_loop, loop_gains
from .sparse import mul_left
from ..errors import CoreError

LOOP_NAMES = ("dh", "int_dh", "b_aid")
STATE_NAMES = ("dv_e", "dv_n", "dv_u", "phi_e", "phi_n", "phi_u",
               "ba_x", "ba_y", "ba_z", "bg_x", "bg_y", "bg_z", "dp_e", "dp_n", "dp_u")
IV, IPHI, IBA, IBG, IP = 0, 3, 6, 9, 12
REF_MARKOV_NAMES = ("ref_m_e", "ref_m_n", "ref_m_u")


def _tau_c(sigma0: float, sigma: float, tau: float) -> tuple[float, float]:
    """(1/tau_c, q) of the bias state (module docstring); a pure constant has 1/tau_c = q = 0."""
    if sigma == 0.0:
        return 0.0, 0.0
    return sigma**2 / (tau * (sigma0**2 + sigma**2)), 2.0 * sigma**2 / tau


@dataclass(frozen=True)
class Ins3dModel:
    """The ins3d model's constant parameters (everything time-varying comes from NavSteps)."""

    grade: ImuGrade
    position: bool = False
    rows: int = 2
    vertical: str = "damped"
    tau_vertical_s: float = 100.0
    sigma_vertical: float = 0.2
    latency: bool = False
    latency_sigma_s: float = 0.05
    ref_markov: tuple[float, float, float] | None = None   # (sigma_h, sigma_v m/s, tau s)
    loop: VerticalLoop = VerticalLoop()      # the height loop of vertical="loop"
    #: the third row is a height reference (z = h_INS - h_ref, m: the height error ``ih``),
    #: not the vertical velocity
    height_row: bool = False
    #: the initial vertical velocity error's sigma (m/s) of a free or looped vertical channel
    #: (None: ``p0``'s v_sigma; a damped channel's is ``sigma_vertical``)
    v0_sigma_up: float | None = None

    def __post_init__(self) -> None:
        if self.rows not in (2, 3):
            raise CoreError(f"ins3d: the reference has 2 or 3 rows, got {self.rows!r}")
        if self.height_row and (self.rows != 3 or self.ih < 0):
            raise CoreError("ins3d: a height reference row needs rows=3 and a height state "
                            "(position=True or vertical='loop')")
        if self.vertical not in VERTICAL:
            raise CoreError(f"ins3d: vertical must be one of {', '.join(VERTICAL)}, "
                            f"got {self.vertical!r}")
        if self.ref_markov is not None and not (
                len(self.ref_markov) == 3 and all(math.isfinite(v) and v > 0
                                                  for v in self.ref_markov)):
            raise CoreError("ins3d: ref_markov must be (sigma_h, sigma_v, tau), all > 0")
        if not (math.isfinite(self.tau_vertical_s) and self.tau_vertical_s > 0
                and math.isfinite(self.sigma_vertical) and self.sigma_vertical > 0):
            raise CoreError("ins3d: the vertical channel's tau and sigma must be > 0")
        if self.v0_sigma_up is not None and not (math.isfinite(self.v0_sigma_up)
                                                 and self.v0_sigma_up > 0):
            raise CoreError("ins3d: v0_sigma_up must be > 0")

    @classmethod
    def from_grade(cls, name: str | ImuGrade, position: bool = False, rows: int = 2,
                   vertical: str = "damped", latency: bool = False,
                   ref_markov: tuple[float, float, float] | None = None,
                   loop: VerticalLoop | None = None, height_row: bool = False,
                   v0_sigma_up: float | None = None) -> "Ins3dModel":
        if isinstance(name, ImuGrade):
            grade = name
        elif name in GRADES:
            grade = GRADES[name]
        else:
            raise CoreError(f"ins3d: unknown IMU grade {name!r}; choose one of "
                            f"{', '.join(GRADES)}")
        return cls(grade, position, rows, vertical, latency=latency, ref_markov=ref_markov,
                   loop=loop or VerticalLoop(), height_row=height_row, v0_sigma_up=v0_sigma_up)

    @property
    def n(self) -> int:
        return self.im + self.n_markov + (1 if self.latency else 0)

    @property
    def n_loop(self) -> int:
        """Vertical-loop states after the core ones (dh, s, b; dh is dp_U with positions)."""
        if self.vertical != "loop":
            return 0
        return 2 if self.position else 3

    @property
    def ih(self) -> int:
        """Index of the height error dh (-1: none)."""
        if self.position:
            return IP + 2
        return 12 if self.vertical == "loop" else -1

    @property
    def im(self) -> int:
        """Index of the first reference Markov state (the count is ``n_markov``)."""
        return (15 if self.position else 12) + self.n_loop

    @property
    def n_markov(self) -> int:
        return self.rows if self.ref_markov is not None else 0

    @property
    def il(self) -> int:
        """Index of the latency state (-1: none)."""
        return self.n - 1 if self.latency else -1

    @property
    def hu(self) -> int:
        """The state the third row measures: dv_U, or the height error (``height_row``)."""
        return self.ih if self.height_row else IV + 2

    @property
    def row_states(self) -> tuple[int, int, int]:
        """The state each reference row (east, north, third) measures (the first ``rows``)."""
        return IV, IV + 1, self.hu

    def row_args(self) -> tuple[int, int, int, int]:
        """The kernels' row arguments (il, im, rows, hu): latency state (-1: none), first
        reference Markov state (0: none), rows, the third row's state (``scaled_H``)."""
        return self.il, self.im if self.n_markov else 0, self.rows, self.hu

    @property
    def names(self) -> tuple[str, ...]:
        core = STATE_NAMES[:15 if self.position else 12]
        return (core + LOOP_NAMES[3 - self.n_loop:] + REF_MARKOV_NAMES[:self.n_markov]
                + (("latency",) if self.latency else ()))

    def markov_sigma(self) -> np.ndarray:
        """(rows,) stationary sigma of the reference Markov states (zeros without them)."""
        if self.ref_markov is None:
            return np.zeros(self.rows)
        return np.array([self.ref_markov[0]] * 2 + [self.ref_markov[1]])[:self.rows]

    def bias_params(self) -> np.ndarray:
        """(4,) 1/tau_c and q of the accelerometer and the gyro biases."""
        g = self.grade
        ia, qa = _tau_c(g.accel_bias, g.accel_instability, g.accel_tau_s)
        ig, qg = _tau_c(g.gyro_bias, g.gyro_instability, g.gyro_tau_s)
        return np.array([ia, ig, qa, qg])

    def aid_params(self) -> tuple[float, float]:
        """(1/tau_c, q) of the aiding height error b (vertical loop)."""
        lp = self.loop
        return _tau_c(lp.bias, lp.instability, lp.aid_tau_s)

    def kernel_params(self) -> np.ndarray:
        """(14,) what ``fill_F`` needs: 1/tau_c of the accelerometer and gyro biases,
        1/tau of the damped vertical velocity error (0: not damped), 1 when the position
        states are present, 1/tau of the reference Markov states, their first index and their
        count; the loop gains k1, k2, k3 (k1 = 0: no loop), 1/tau_c of the aiding error, the
        indices of dh, s and b."""
        ia, ig, _, _ = self.bias_params()
        kp = np.zeros(14)
        kp[:7] = [ia, ig, 1.0 / self.tau_vertical_s if self.vertical == "damped" else 0.0,
                  1.0 if self.position else 0.0,
                  1.0 / self.ref_markov[2] if self.ref_markov else 0.0,
                  float(self.im), float(self.n_markov)]
        if self.vertical == "loop":
            i0 = self.im - self.n_loop
            kp[7:10] = self.loop.gains()
            kp[10] = self.aid_params()[0]
            kp[11:14] = [self.ih, self.im - 2, self.im - 1] if self.position else \
                [i0, i0 + 1, i0 + 2]
        return kp

    def qc(self) -> np.ndarray:
        """(n,) diagonal of the continuous process noise density."""
        _, _, qa, qg = self.bias_params()
        q = np.zeros(self.n)
        q[IV:IV + 3] = self.grade.vrw**2
        q[IPHI:IPHI + 3] = self.grade.arw**2
        q[IBA:IBA + 3] = qa
        q[IBG:IBG + 3] = qg
        if self.vertical == "damped":
            q[IV + 2] = 2.0 * self.sigma_vertical**2 / self.tau_vertical_s
        if self.vertical == "loop":       # white aiding height: density sigma_w^2 dt_aid
            k1, k2, _ = self.loop.gains()
            nw = self.loop.white**2 / self.loop.aid_rate_hz
            q[self.ih] += k1 * k1 * nw
            q[IV + 2] += k2 * k2 * nw
            q[self.im - 2] = nw
            q[self.im - 1] = self.aid_params()[1]
        if self.ref_markov:
            q[self.im:self.im + self.n_markov] = 2.0 * self.markov_sigma()**2 / self.ref_markov[2]
        return q

    def p0(self, phi_sigma: tuple[float, float, float] | None = None,
           v_sigma: float = 0.05, p_sigma: float = 5.0) -> np.ndarray:
        """(n,) initial variances: velocity v_sigma, attitude phi_sigma (default: levelling
        tilt from the accelerometer bias, heading from the grade: gyrocompassing or external),
        biases from the grade (sigma0^2 + sigma^2; body z accelerometer: + (scale g)^2),
        position p_sigma."""
        g = self.grade
        sa = math.hypot(g.accel_bias, g.accel_instability)
        sg = math.hypot(g.gyro_bias, g.gyro_instability)
        if phi_sigma is None:
            tilt = max(sa / 9.8, 1e-6)
            head = g.heading_sigma if g.heading_sigma > 0 else \
                max(sg / (OMEGA_IE * math.cos(math.radians(45.0))), 1e-5)
            phi_sigma = (tilt, tilt, head)
        p = np.empty(self.n)
        p[IV:IV + 3] = v_sigma**2
        if self.vertical == "damped":
            p[IV + 2] = self.sigma_vertical**2
        elif self.v0_sigma_up is not None:
            p[IV + 2] = self.v0_sigma_up**2
        p[IPHI:IPHI + 3] = np.square(phi_sigma)
        p[IBA:IBA + 3] = max(sa, 1e-7) ** 2
        # the body z accelerometer carries ~1 g: its scale-factor error (not a state) is a
        # constant bias of scale * g in cruise, seen by the vertical row (3 rows, loop)
        p[IBA + 2] += (g.accel_scale * GRAVITY0) ** 2
        p[IBG:IBG + 3] = max(sg, 1e-10) ** 2
        if self.position:
            p[IP:IP + 3] = p_sigma**2
        if self.vertical == "loop":       # the loop starts at the true height, s = 0
            lp = self.loop
            p[self.ih] = min(p_sigma, 1.0) ** 2 if not self.position else p[self.ih]
            p[self.im - 2] = 1.0
            p[self.im - 1] = max(lp.bias**2 + lp.instability**2, 1e-6)
        if self.ref_markov:
            p[self.im:self.im + self.n_markov] = self.markov_sigma()**2
        if self.latency:
            p[-1] = self.latency_sigma_s**2
        return p

    def p0_aligned(self, C0: np.ndarray, f_n0: np.ndarray, lat0: float,
                   independent: float = 0.1) -> np.ndarray:
        """(n, n) initial covariance of an INS aligned on the ground or in level flight: the
        levelled tilt cancels the horizontal accelerometer error, phi_N = b_E / f_U,
        phi_E = -b_N / f_U (b = C0 ba), and gyrocompassing (grades without an external
        heading) leaves phi_U = -eps_E / (Omega cos L) (eps = C0 bg) -- the correlations the
        simulator's ``consistent`` alignment has (``sim.imu3d.alignment_error``), with an
        ``independent`` fraction of each attitude sigma added as uncorrelated."""
        p = self.p0()
        n = self.n
        J = np.eye(n)                           # x0 = J w, w independent with variances p
        fu = float(f_n0[2])
        J[IPHI, IPHI] = J[IPHI + 1, IPHI + 1] = independent
        J[IPHI, IBA:IBA + 3] = -C0[1] / fu
        J[IPHI + 1, IBA:IBA + 3] = C0[0] / fu
        if self.grade.heading_sigma == 0.0:
            J[IPHI + 2, IPHI + 2] = independent
            J[IPHI + 2, IBG:IBG + 3] = -C0[0] / (OMEGA_IE * math.cos(lat0))
        return J @ np.diag(p) @ J.T

    def H(self, a_n: np.ndarray | None = None) -> np.ndarray:
        """The measurement matrix; with the latency state its column is the INS acceleration
        a_n at the update (the reference reports v(t - latency) ~ v(t) - a_n latency; a height
        row's entry is the vertical velocity)."""
        h = np.zeros((self.rows, self.n))
        h[np.arange(self.rows), self.row_states[:self.rows]] = 1.0
        if self.ref_markov:
            h[:, self.im:self.im + self.rows] = np.eye(self.rows)
        if self.latency:
            h[:, -1] = np.zeros(3)[:self.rows] if a_n is None else np.asarray(a_n)[:self.rows]
        return h


@njit(cache=True)
def dgravity_dh(lat, h):
    """d g / d h of ``core.earth.gravity`` (1/s^2, negative)."""
    s2 = math.sin(lat) ** 2
    g0 = GE * (1.0 + GK * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (6.0 * h / (A * A) - (2.0 / A) * (1.0 + GF + GM_RATIO - 2.0 * GF * s2))


@njit(cache=True)
def _cross_into(F, r0, c0, a0, a1, a2, s):
    """F[r0:r0+3, c0:c0+3] += s [a x] (the skew matrix of a)."""
    F[r0, c0 + 1] += -s * a2
    F[r0, c0 + 2] += s * a1
    F[r0 + 1, c0] += s * a2
    F[r0 + 1, c0 + 2] += -s * a0
    F[r0 + 2, c0] += -s * a1
    F[r0 + 2, c0 + 1] += s * a0


@njit(cache=True)
def fill_F(F, C, f_n, v, lat, h, bias):
    """Fill the (n, n) F (n = 12, 15, +1 latency: a constant) of one step;
    ``bias`` = Ins3dModel.kernel_params()."""
    F[:, :] = 0.0
    r_n, r_m = radii(lat)
    rn = r_n + h
    rm = r_m + h
    sl, cl = math.sin(lat), math.cos(lat)
    tl = sl / cl
    ve, vn, vu = v[0], v[1], v[2]
    wie_n, wie_u = OMEGA_IE * cl, OMEGA_IE * sl
    wen_e, wen_n, wen_u = -vn / rm, ve / rn, ve * tl / rn
    # D = d w_en / d dv (rows E, N, U of w_en; columns dv_E, dv_N)
    d10, d01, d20 = 1.0 / rn, -1.0 / rm, tl / rn
    # velocity rows
    _cross_into(F, IV, IPHI, f_n[0], f_n[1], f_n[2], 1.0)                    # f x phi
    _cross_into(F, IV, IV, 2.0 * 0.0 + wen_e, 2.0 * wie_n + wen_n, 2.0 * wie_u + wen_u, -1.0)
    # + [v x] D dv : [v x] columns applied to D
    for j in range(2):
        de = d01 if j == 1 else 0.0
        dn = d10 if j == 0 else 0.0
        du = d20 if j == 0 else 0.0
        F[IV, IV + j] += vn * du - vu * dn
        F[IV + 1, IV + j] += vu * de - ve * du
        F[IV + 2, IV + j] += ve * dn - vn * de
    for i in range(3):
        for j in range(3):
            F[IV + i, IBA + j] = C[i, j]
            F[IPHI + i, IBG + j] = -C[i, j]
    # attitude rows
    _cross_into(F, IPHI, IPHI, wen_e, wie_n + wen_n, wie_u + wen_u, -1.0)   # -w_in x phi
    F[IPHI, IV + 1] += d01
    F[IPHI + 1, IV] += d10
    F[IPHI + 2, IV] += d20
    # biases
    for i in range(3):
        F[IBA + i, IBA + i] = -bias[0]
        F[IBG + i, IBG + i] = -bias[1]
    pos = bias[3] > 0.0
    if pos:
        _fill_position(F, ve, vn, vu, lat, h, rn, rm, sl, cl, tl)
    if bias[2] > 0.0:          # damped vertical channel: dv_U a Markov state of its own
        F[IV + 2, :] = 0.0
        F[:, IV + 2] = 0.0
        F[IV + 2, IV + 2] = -bias[2]
        if pos:
            F[IP + 2, IV + 2] = 1.0
            F[IV + 2, IP + 2] = 0.0
    if bias[7] > 0.0:
        fill_loop(F, bias, IV + 2, -dgravity_dh(lat, h), pos)
    im = int(bias[5])
    for i in range(int(bias[6])):  # reference Markov noise states
        F[im + i, im + i] = -bias[4]


@njit(cache=True)
def _fill_position(F, ve, vn, vu, lat, h, rn, rm, sl, cl, tl):
    """The position columns and rows of F (15-state model)."""
    # rate errors per metre of north position (dL = dp_N / rm) and of height
    ie_n_n, ie_u_n = -OMEGA_IE * sl / rm, OMEGA_IE * cl / rm        # d w_ie / d dp_N
    en_u_n = ve / (cl * cl) / rn / rm                               # d w_en,U / d dp_N
    en_e_u, en_n_u, en_u_u = vn / (rm * rm), -ve / (rn * rn), -ve * tl / (rn * rn)
    # Np (attitude) = d w_ie + d w_en; Mp (velocity) = 2 d w_ie + d w_en
    F[IPHI + 1, IP + 1] += ie_n_n
    F[IPHI + 2, IP + 1] += ie_u_n + en_u_n
    F[IPHI, IP + 2] += en_e_u
    F[IPHI + 1, IP + 2] += en_n_u
    F[IPHI + 2, IP + 2] += en_u_u
    m = np.zeros((3, 2))       # Mp columns for dp_N, dp_U
    m[1, 0], m[2, 0] = 2.0 * ie_n_n, 2.0 * ie_u_n + en_u_n
    m[0, 1], m[1, 1], m[2, 1] = en_e_u, en_n_u, en_u_u
    for j in range(2):
        c = IP + 1 + j
        F[IV, c] += vn * m[2, j] - vu * m[1, j]
        F[IV + 1, c] += vu * m[0, j] - ve * m[2, j]
        F[IV + 2, c] += ve * m[1, j] - vn * m[0, j]
    F[IV + 2, IP + 2] += -dgravity_dh(lat, h)                       # dg_U = -dg/dh dh
    for i in range(3):
        F[IP + i, IV + i] = 1.0
    F[IP, IP] = -vn * tl / rm + vu / rn
    F[IP, IP + 1] = ve * tl / rm
    F[IP, IP + 2] = -ve / rn
    F[IP + 1, IP + 1] = vu / rm
    F[IP + 1, IP + 2] = -vn / rm


@njit(cache=True)
def square(F, F2):
    """F2 = F F, skipping the zeros of F (about a quarter of its entries are nonzero)."""
    F2[:, :] = 0.0
    mul_left(F, F, F2, False)


@njit(cache=True)
def transition(F, dt, Phi, F2):
    """Phi = I + F dt + (F dt)^2 / 2 alone (``discretize`` without Qd); F2 = F F (scratch)."""
    n = F.shape[0]
    square(F, F2)
    h = 0.5 * dt * dt
    for i in range(n):
        for j in range(n):
            Phi[i, j] = F[i, j] * dt + F2[i, j] * h
        Phi[i, i] += 1.0


@njit(cache=True)
def discretize(F, dt, qc, Phi, Qd):
    """Phi = I + F dt + (F dt)^2 / 2 and the Van Loan integral Qd = int_0^dt e^(Fs) Qc
    e^(F's) ds by its Taylor series to dt^3 (Qc = diag(qc), A = F Qc):
    Qd = Qc dt + (A + A') dt^2 / 2 + (F A + (F A)' + 2 A F') dt^3 / 6, with F A = F^2 Qc and
    (A F')_ij = sum_k F_ik qc_k F_jk; the products skip the zeros of F."""
    n = F.shape[0]
    F2 = np.empty((n, n))
    transition(F, dt, Phi, F2)
    AF = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            a = F[i, k] * qc[k]
            if a != 0.0:
                for j in range(n):
                    AF[i, j] += a * F[j, k]
    c2 = 0.5 * dt * dt
    c3 = dt * dt * dt / 6.0
    for i in range(n):
        for j in range(i, n):
            q = (F[i, j] * qc[j] + F[j, i] * qc[i]) * c2 \
                + (F2[i, j] * qc[j] + F2[j, i] * qc[i] + 2.0 * AF[i, j]) * c3
            if i == j:
                q += qc[i] * dt
            Qd[i, j] = q
            Qd[j, i] = q


@njit(cache=True)
def _propagate(x0, C, f_n, v, lat, h, dt, bias, u_a, u_g, override, out):
    """out[k] = x_k; x_k+1 = Phi_k x_k. With ``override`` the bias states are replaced by the
    given body errors u_a, u_g (K, 3) of each step before it is taken (known-input test)."""
    n = x0.size
    F = np.empty((n, n))
    Phi = np.empty((n, n))
    Qd = np.empty((n, n))
    qc = np.zeros(n)
    x = x0.copy()
    out[0] = x
    for k in range(dt.size):
        if override:
            x[IBA:IBA + 3] = u_a[k]
            x[IBG:IBG + 3] = u_g[k]
        fill_F(F, C[k], f_n[k], v[k], lat[k], h[k], bias)
        discretize(F, dt[k], qc, Phi, Qd)
        x = Phi @ x
        out[k + 1] = x


def propagate(model: Ins3dModel, steps, x0: np.ndarray, u_a: np.ndarray | None = None,
              u_g: np.ndarray | None = None) -> np.ndarray:
    """(K+1, n) noise-free propagation of x0 through the steps; with u_a, u_g (K, 3) the bias
    states are the given body-axis errors of each step (the true sensor errors in tests)."""
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (model.n,):
        raise CoreError(f"propagate: x0 must have {model.n} elements")
    k = len(steps)
    override = u_a is not None
    ua = np.zeros((k, 3)) if u_a is None else np.ascontiguousarray(u_a, dtype=float)
    ug = np.zeros((k, 3)) if u_g is None else np.ascontiguousarray(u_g, dtype=float)
    out = np.empty((k + 1, model.n))
    _propagate(x0, steps.C, steps.f_n, steps.v, steps.lat, steps.h, steps.dt,
               model.kernel_params(), ua, ug, override, out)
    return out


def F_matrix(model: Ins3dModel, steps, k: int) -> np.ndarray:
    """The continuous F of step k (for tests and reports)."""
    F = np.empty((model.n, model.n))
    fill_F(F, steps.C[k], steps.f_n[k], steps.v[k], float(steps.lat[k]), float(steps.h[k]),
           model.kernel_params())
    return F


__all__ = ["IBA", "IBG", "IP", "IPHI", "IV", "Ins3dModel", "LOOP_NAMES", "STATE_NAMES",
           "VerticalLoop", "loop_gains", "discretize", "square",
           "transition",
           "dgravity_dh", "fill_F", "F_matrix", "gravity", "propagate"]
