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

from ..earth import OMEGA_IE, gravity
from .grades import G0 as GRAVITY0
from .defaults import VERTICAL
from .grades import GRADES, ImuGrade
from .vertical import VerticalLoop, loop_gains
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
    #: (sigma_h, sigma_v m/s, tau s[, tau of the third row s]): the third row's own tau when
    #: it is a height reference (sigma_v then in m), else all rows' tau
    ref_markov: tuple[float, ...] | None = None
    loop: VerticalLoop = VerticalLoop()      # the height loop of vertical="loop"
    #: the third row is a height reference (z = h_INS - h_ref, m: the height error ``ih``),
    #: not the vertical velocity
    height_row: bool = False
    #: the initial vertical velocity error's sigma (m/s) of a free or looped vertical channel
    #: (None: ``p0``'s v_sigma; a damped channel's is ``sigma_vertical``)
    v0_sigma_up: float | None = None
    #: the initial height error's sigma (m; None: ``p0``'s position sigma, or the loop's): a
    #: height reference offset to the INS height at its first sample (``bagio.height_input``,
    #: datum "first") knows it to that reference's own error
    h0_sigma: float | None = None

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
                len(self.ref_markov) in (3, 4) and all(math.isfinite(v) and v > 0
                                                       for v in self.ref_markov)):
            raise CoreError("ins3d: ref_markov must be (sigma_h, sigma_v, tau[, tau_third]), "
                            "all > 0")
        if not (math.isfinite(self.tau_vertical_s) and self.tau_vertical_s > 0
                and math.isfinite(self.sigma_vertical) and self.sigma_vertical > 0):
            raise CoreError("ins3d: the vertical channel's tau and sigma must be > 0")
        if self.v0_sigma_up is not None and not (math.isfinite(self.v0_sigma_up)
                                                 and self.v0_sigma_up > 0):
            raise CoreError("ins3d: v0_sigma_up must be > 0")
        if self.h0_sigma is not None and not (math.isfinite(self.h0_sigma) and self.h0_sigma > 0
                                              and self.ih >= 0):
            raise CoreError("ins3d: h0_sigma must be > 0, with a height state")

    @classmethod
    def from_grade(cls, name: str | ImuGrade, position: bool = False, rows: int = 2,
                   vertical: str = "damped", latency: bool = False,
                   ref_markov: tuple[float, float, float] | None = None,
                   loop: VerticalLoop | None = None, height_row: bool = False,
                   v0_sigma_up: float | None = None,
                   h0_sigma: float | None = None) -> "Ins3dModel":
        if isinstance(name, ImuGrade):
            grade = name
        elif name in GRADES:
            grade = GRADES[name]
        else:
            raise CoreError(f"ins3d: unknown IMU grade {name!r}; choose one of "
                            f"{', '.join(GRADES)}")
        return cls(grade, position, rows, vertical, latency=latency, ref_markov=ref_markov,
                   loop=loop or VerticalLoop(), height_row=height_row, v0_sigma_up=v0_sigma_up,
                   h0_sigma=h0_sigma)

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

    def markov_tau(self) -> np.ndarray:
        """(rows,) time constants of the reference Markov states (s; ones without them)."""
        if self.ref_markov is None:
            return np.ones(self.rows)
        tau = self.ref_markov[2]
        return np.array([tau, tau, self.ref_markov[-1]])[:self.rows]

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
        """(15,) what ``fill_F`` needs: 1/tau_c of the accelerometer and gyro biases,
        1/tau of the damped vertical velocity error (0: not damped), 1 when the position
        states are present, 1/tau of the horizontal reference Markov states, their first index
        and their count; the loop gains k1, k2, k3 (k1 = 0: no loop), 1/tau_c of the aiding
        error, the indices of dh, s and b; 1/tau of the third row's Markov state."""
        ia, ig, _, _ = self.bias_params()
        kp = np.zeros(15)
        inv = 1.0 / self.markov_tau() if self.ref_markov else np.zeros(3)
        kp[:7] = [ia, ig, 1.0 / self.tau_vertical_s if self.vertical == "damped" else 0.0,
                  1.0 if self.position else 0.0, inv[0], float(self.im), float(self.n_markov)]
        kp[14] = inv[-1]
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
            q[self.im:self.im + self.n_markov] = 2.0 * self.markov_sigma()**2 / self.markov_tau()
        return q

    def p0(self, phi_sigma: tuple[float, float, float] | None = None,
           v_sigma: float = 0.05, p_sigma: float = 5.0) -> np.ndarray:
        """(n,) initial variances: velocity v_sigma, attitude phi_sigma (default: levelling
        tilt from the accelerometer bias, heading from the grade: gyrocompassing or external),
        biases from the grade (sigma0^2 + sigma^2; body z accelerometer: + (scale g)^2),
        position p_sigma (the height: ``h0_sigma`` when given)."""
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
        if self.h0_sigma is not None:
            p[self.ih] = self.h0_sigma**2
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


__all__ = ["IBA", "IBG", "IP", "IPHI", "IV", "Ins3dModel", "LOOP_NAMES", "STATE_NAMES",
           "VerticalLoop", "gravity", "loop_gains"]
