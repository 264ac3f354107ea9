"""Shared, seeded test data of the redundancy tests: a small threshold table calibrated on the
IMU simulator, and simulated three-IMU bags (nominal and faulty)."""
from __future__ import annotations

from pathlib import Path

import pytest

from flight_fdi.core.voting_calib import calibrate
from flight_fdi.sim.imu import ImuSimConfig, nominal_window_means, parse_imu_fault, simulate_imus

RATE_HZ = 100.0
DURATION_S = 6.0
WINDOW = 50          # 0.5 s
CAL_FLIGHTS = 400
ALPHA = 0.001


def small_config(seed: int = 0, faults=()) -> ImuSimConfig:
    return ImuSimConfig(duration_s=DURATION_S, rate_hz=RATE_HZ, seed=seed, faults=tuple(faults))


@pytest.fixture(scope="session")
def small_calibration():
    """(t, window means (flights, K, 6, 3), Calibration) of 400 nominal 6-s flights."""
    cfg = small_config(seed=11)
    t, means = nominal_window_means(cfg, CAL_FLIGHTS, WINDOW, eval_every=2, batch_size=200)
    cal = calibrate(means, t, ALPHA, WINDOW, RATE_HZ, n_segments=8, min_segment_s=0.3,
                    smooth_s=0.2, duration_s=DURATION_S)
    return t, means, cal


@pytest.fixture(scope="session")
def table_file(small_calibration, tmp_path_factory):
    from flight_fdi.core.voting import save_table

    path = tmp_path_factory.mktemp("voter") / "thresholds.json"
    save_table(small_calibration[2].table, path)
    return path


MIMU = Path(__file__).parent / "data" / "mimu"


@pytest.fixture(scope="session")
def mimu_excerpt():
    """(stamp_ns (T,), P (T, 6, 3)) of the 15-s real excerpt (data/mimu, CC BY 4.0)."""
    import numpy as np

    from flight_fdi.cli.imu_csv import read_csv

    t, _ = read_csv(MIMU / "IMU_1.csv.gz")
    P = np.stack([read_csv(MIMU / f"IMU_{k}.csv.gz")[1] for k in (1, 2, 3)], axis=-1)
    return np.round((1.7e9 + t) * 1e9).astype(np.int64), P


def flight(seed: int, *faults: str):
    """A simulated 6-s flight (the test flights use seeds the calibration did not: run 0 of
    seed 101 ...)."""
    return simulate_imus(small_config(seed=seed, faults=[parse_imu_fault(f) for f in faults]))


@pytest.fixture(scope="session")
def sim():
    """The small simulation set-up: constants and the flight factory."""
    class Sim:
        pass

    s = Sim()
    s.RATE_HZ, s.DURATION_S, s.WINDOW, s.CAL_FLIGHTS, s.ALPHA = (RATE_HZ, DURATION_S, WINDOW,
                                                                CAL_FLIGHTS, ALPHA)
    s.flight = flight
    s.config = small_config
    return s
