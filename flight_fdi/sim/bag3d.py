"""Writing a 3-D simulated flight as a rosbag2 bag: the input contract of the 3-D estimator.

Frames (REP 103): navigation ``enu`` (x East, y North, z Up), body ``base_link`` (x forward,
y left, z up), GNSS antenna ``gnss``. Header stamps are the times the values belong to (the
GNSS stamp is the receiver's, late by its latency); bag receive time = header stamp.

==================  ==========================================  =============================
topic               type                                        content
==================  ==========================================  =============================
/ins/velocity       geometry_msgs/TwistStamped (``enu``)        INS velocity v_E, v_N, v_U in
                                                                twist.linear; angular 0
/ins/imu            sensor_msgs/Imu (``base_link``)             orientation = INS attitude
                                                                q_b^n (body -> ENU); angular_
                                                                velocity, linear_acceleration
                                                                = the measured body rate and
                                                                specific force (gravity
                                                                included as an accelerometer
                                                                senses it: ~ +9.8 on z when
                                                                level), *mean over the interval
                                                                since the previous message*;
                                                                covariances 0 (unknown)
/ins/fix            sensor_msgs/NavSatFix (``base_link``)       INS latitude, longitude (deg),
                                                                ellipsoidal height (m);
                                                                covariance type UNKNOWN
/reference/velocity geometry_msgs/TwistWithCovarianceStamped    GNSS velocity, ENU; covariance
                    (``enu``)                                   diagonal [0, 7, 14] = white^2 +
                                                                markov^2, angular 1e6
/reference/fix      sensor_msgs/NavSatFix (``gnss``)            GNSS position, ENU covariance
                                                                (DIAGONAL_KNOWN)
/sim/truth          flight_fdi_msgs/FilterState, channel        named truth values (TRUTH_NAMES)
                    ``truth3d``
/sim/fault          std_msgs/String (transient local, once)     JSON: ``Flight3D.description``
(optional, e.g.     sensor_msgs/FluidPressure (``baro``), or    the height reference
/reference/baro)    NavSatFix / PointStamped                    (``height_series``): a second
                                                                barometer's ISA pressure, or
                                                                its height as altitude / z
==================  ==========================================  =============================

/ins/velocity, /ins/imu, /ins/fix and /sim/truth are decimations of the INS states (the rates
must divide the mechanization rate); the IMU message at state k averages the increments of the
intervals since the previous message, so the sum of rate x interval over the messages is the
total increment.
"""
from __future__ import annotations

import json
import math

import numpy as np

from flight_fdi.bagio.ins3d_payloads import (BODY_FRAME, ENU_FRAME, UNMEASURED_VARIANCE,
                                             imu_payloads, ins_fix_payloads, velocity_payloads)

from .errors import SimError
from .imu3d import AXES
from .ins3d import Flight3D
from .rotation import attitude_error_array

EPOCH_S = 1_700_000_000
_NS = 1_000_000_000
GNSS_FRAME = "gnss"
BARO_FRAME = "baro"
FILTER_STATE = "flight_fdi_msgs/msg/FilterState"
STRING = "std_msgs/msg/String"
TOPICS = {"ins_velocity": "/ins/velocity", "ins_imu": "/ins/imu", "ins_fix": "/ins/fix",
          "ref_velocity": "/reference/velocity", "ref_fix": "/reference/fix",
          "truth": "/sim/truth", "fault": "/sim/fault"}
TRUTH_CHANNEL = "truth3d"
#: /sim/truth state_names: true position (rad, m), velocity (ENU m/s), attitude (q_b^n, w x y
#: z), accelerometer and gyro bias (body; turn-on + Gauss-Markov), the fault errors the
#: catalogue added, the total systematic instrument error ((S + M) r + bias + fault), and the
#: INS errors: velocity v_INS - v_true (ENU) and attitude phi (C_INS = (I - [phi x]) C_true)
TRUTH_NAMES = (["lat", "lon", "h", "v_e", "v_n", "v_u", "q_w", "q_x", "q_y", "q_z"]
               + [f"{s}_{a}" for s in ("accel_bias", "gyro_bias", "accel_fault", "gyro_fault",
                                        "accel_error", "gyro_error") for a in AXES]
               + ["dv_e", "dv_n", "dv_u", "phi_e", "phi_n", "phi_u"])

def _every(rate_hz: float, base_hz: float, what: str) -> int:
    k = base_hz / rate_hz
    if rate_hz <= 0 or abs(k - round(k)) > 1e-9 * k or round(k) < 1:
        raise SimError(f"the {what} rate ({rate_hz:g} Hz) must divide the mechanization rate "
                       f"({base_hz:g} Hz)")
    return int(round(k))


def truth_matrix(flight: Flight3D, index: np.ndarray | None = None) -> np.ndarray:
    """(len(index), len(TRUTH_NAMES)) the truth at INS states ``index`` (default all); the
    instrument errors are those of the interval starting at the state (the last state repeats
    the last interval)."""
    nav = flight.truth.nav
    k = np.arange(nav.lat.size) if index is None else np.asarray(index)
    ki = np.minimum(k, flight.gyro.rate.shape[0] - 1)
    dt = flight.dt
    cols = [nav.lat[k, None], nav.lon[k, None], nav.h[k, None], nav.v[k], nav.q[k],
            flight.accel.bias[ki], flight.gyro.bias[ki], flight.accel.fault[ki],
            flight.gyro.fault[ki], flight.accel.systematic(flight.ideal_dv[ki] / dt, ki),
            flight.gyro.systematic(flight.ideal_dtheta[ki] / dt, ki),
            flight.ins.v[k] - nav.v[k], attitude_error_array(flight.ins.q[k], nav.q[k])]
    return np.concatenate(cols, axis=1)


def _truth_payloads(x: np.ndarray, stamps: np.ndarray, dt_truth: float) -> list[bytes]:
    """FilterState messages (channel ``truth3d``, state_names TRUTH_NAMES, x rows) for a series,
    serialized by the project's CDR codec (``bagio.cdr.message``, equal to rosbags' output)."""
    from flight_fdi.bagio.cdr import message

    sec, nsec = np.divmod(np.asarray(stamps, dtype=np.int64), _NS)
    names = list(TRUTH_NAMES)
    return [message.encode_filter_state(s, ns, ENU_FRAME, TRUTH_CHANNEL, names, row, (), (), (),
                                        (), (), 0.0 if k == 0 else dt_truth, False, False, False)
            for k, (s, ns, row) in enumerate(zip(sec.tolist(), nsec.tolist(), x.tolist()))]


def _imu_values(flight: Flight3D, every: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(state indices, mean rate, mean specific force) of messages at states every, 2 every..."""
    n_int = flight.gyro.rate.shape[0]
    m = n_int // every
    idx = every * np.arange(1, m + 1)
    w = flight.gyro.rate[:m * every].reshape(m, every, 3).mean(axis=1)
    f = flight.accel.rate[:m * every].reshape(m, every, 3).mean(axis=1)
    return idx, w, f


def encode_topics(flight: Flight3D, velocity_rate_hz: float, imu_rate_hz: float,
                  fix_rate_hz: float, truth_rate_hz: float, epoch_s: int = EPOCH_S
                  ) -> list[tuple[str, str, np.ndarray, list[bytes]]]:
    """(topic, type, receive times ns, payloads) per topic, for ``BagWriter.write_series``."""
    from flight_fdi.bagio import cdr

    base = flight.config.trajectory.rate_hz
    n = flight.t.size
    stamp = epoch_s * _NS + np.round(flight.t * _NS).astype(np.int64)
    series = []
    k = _every(truth_rate_hz, base, "truth")
    idx = np.arange(0, n, k)
    series.append((TOPICS["truth"], FILTER_STATE, stamp[idx],
                   _truth_payloads(truth_matrix(flight, idx), stamp[idx], 1.0 / truth_rate_hz)))
    g = flight.gnss
    g_stamp = epoch_s * _NS + np.round(g.t * _NS).astype(np.int64)
    kind, payloads = velocity_payloads(g_stamp, g.v, g.vel_var)
    series.append((TOPICS["ref_velocity"], kind, g_stamp, payloads))
    llh = np.stack([np.degrees(g.lat), np.degrees(g.lon), g.h], axis=1)
    series.append((TOPICS["ref_fix"], cdr.NAVSATFIX, g_stamp,
                   cdr.encode_navsatfix(g_stamp, GNSS_FRAME, 0, 1, llh,
                                        np.diag(g.pos_var).reshape(9), 2)))
    k = _every(fix_rate_hz, base, "INS fix")
    idx = np.arange(0, n, k)
    ins = flight.ins
    series.append((TOPICS["ins_fix"], cdr.NAVSATFIX, stamp[idx],
                   ins_fix_payloads(stamp[idx], ins.lat[idx], ins.lon[idx], ins.h[idx])))
    idx, w, f = _imu_values(flight, _every(imu_rate_hz, base, "IMU"))
    series.append((TOPICS["ins_imu"], cdr.IMU, stamp[idx],
                   imu_payloads(stamp[idx], ins.q[idx], w, f)))
    k = _every(velocity_rate_hz, base, "INS velocity")
    idx = np.arange(0, n, k)
    kind, payloads = velocity_payloads(stamp[idx], ins.v[idx])
    series.append((TOPICS["ins_velocity"], kind, stamp[idx], payloads))
    return series


def height_series(flight: Flight3D, topic: str, msgtype: str, rate_hz: float,
                  epoch_s: int = EPOCH_S) -> tuple[str, str, np.ndarray, list[bytes]]:
    """The height reference topic (``Sim3DConfig.height_reference``'s heights every 1/rate s,
    frame ``baro``; ``ins3d_payloads.height_payloads``: FluidPressure, NavSatFix or
    PointStamped) with the published variance white^2 + instability^2 (not for PointStamped)."""
    from flight_fdi.bagio.ins3d_payloads import height_payloads

    cfg = flight.config.height_reference
    if flight.height_ref is None or cfg is None:
        raise SimError(f"a height topic ({topic}) needs a simulated height reference "
                       "(Sim3DConfig.height_reference)")
    idx = np.arange(0, flight.t.size, _every(rate_hz, flight.config.trajectory.rate_hz,
                                             "height reference"))
    stamp = epoch_s * _NS + np.round(flight.t[idx] * _NS).astype(np.int64)
    nav = flight.truth.nav
    return (topic, msgtype, stamp,
            height_payloads(msgtype, stamp, BARO_FRAME, flight.height_ref[idx],
                            cfg.white**2 + cfg.instability**2, nav.lat[idx], nav.lon[idx]))


def write_bag3d(flight: Flight3D, path: str, velocity_rate_hz: float = 20.0,
                imu_rate_hz: float = 20.0, fix_rate_hz: float = 5.0, truth_rate_hz: float = 1.0,
                epoch_s: int = EPOCH_S, storage: str = "mcap", compression: str = "zstd",
                overwrite: bool = False, height_topic: str | None = None,
                height_type: str = "sensor_msgs/msg/FluidPressure",
                height_rate_hz: float = 10.0) -> dict[str, int]:
    """Write the flight (topics in the module docstring); returns the message count per topic.
    ``height_topic``: also the height reference (``height_series``) on that topic."""
    from flight_fdi.bagio.typestore import get_typestore
    from flight_fdi.bagio.writer import open_writer

    if not isinstance(epoch_s, (int, np.integer)) or not 0 <= epoch_s < 2**31 - 10**6 or \
            epoch_s + flight.config.trajectory.duration_s >= 2**31:
        raise SimError(f"epoch must be whole seconds in [0, 2^31) with the flight ending before "
                       f"2038, got {epoch_s!r}")
    for name, rate in (("velocity", velocity_rate_hz), ("IMU", imu_rate_hz),
                       ("fix", fix_rate_hz), ("truth", truth_rate_hz)):
        if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise SimError(f"the {name} rate must be a positive number, got {rate!r}")
    series = encode_topics(flight, velocity_rate_hz, imu_rate_hz, fix_rate_hz, truth_rate_hz,
                           epoch_s)
    desc = flight.description()
    desc["topics"] = {"velocity_rate_hz": velocity_rate_hz, "imu_rate_hz": imu_rate_hz,
                      "fix_rate_hz": fix_rate_hz, "truth_rate_hz": truth_rate_hz,
                      "epoch_s": int(epoch_s)}
    if height_topic is not None:
        if height_topic in TOPICS.values():
            raise SimError(f"the height topic {height_topic} is already a topic of the bag")
        series.append(height_series(flight, height_topic, height_type, height_rate_hz, epoch_s))
        desc["topics"].update({"height_topic": height_topic, "height_type": height_type,
                               "height_rate_hz": height_rate_hz})
    doc = json.dumps(desc, sort_keys=True)
    payload = bytes(get_typestore().serialize_cdr(get_typestore().types[STRING](data=doc),
                                                  STRING))
    with open_writer(path, storage=storage, compression=compression, overwrite=overwrite) as bag:
        bag.add_topic(TOPICS["fault"], STRING, qos="transient_local")
        bag.set_metadata("flight_fdi.sim3d", doc)
        bag.write_series([(TOPICS["fault"], STRING, np.array([epoch_s * _NS]), [payload])]
                         + series)
        return dict(bag.counts)
