"""Short simulated 3-D flights shared by the ins3d tests (seconds to simulate), and the bundled
sample bags' decoded inputs (decoded once per session; ~0.1 s per 1800-s bag since the whole-series decode)."""
from __future__ import annotations

import copy
import dataclasses
import functools
from pathlib import Path

import pytest

from flight_fdi.bagio.ins3d_input import Ins3dInput, read_ins3d
from flight_fdi.sim.faults import FaultSpec3D, parse_fault
from flight_fdi.sim.gnss import GnssConfig
from flight_fdi.sim.imu3d import GRADES
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig

BAGS = Path(__file__).resolve().parents[2] / "bags"


@functools.lru_cache(maxsize=8)
def flight(profile: str = "cruise_turns", duration_s: float = 1500.0, grade: str = "tactical",
           vertical: str = "free", seed: int = 1, ideal_gnss: bool = False,
           noise: bool = True, scale: bool = True, faults: tuple[str, ...] = ()):
    """A seeded flight; ``noise=False`` zeroes the white noise (ARW, VRW) of the grade,
    ``scale=False`` its scale-factor and misalignment errors (not states of the model)."""
    g = GRADES[grade] if noise else dataclasses.replace(GRADES[grade], arw=0.0, vrw=0.0)
    if not scale:
        g = dataclasses.replace(g, gyro_scale=0.0, gyro_misalign=0.0, accel_scale=0.0,
                                accel_misalign=0.0)
    gnss = GnssConfig(vel_markov_h=0.0, vel_markov_v=0.0, latency_s=0.0) if ideal_gnss \
        else GnssConfig()
    cfg = Sim3DConfig(TrajectoryConfig(profile=profile, duration_s=duration_s, rate_hz=100.0),
                      grade=g, vertical=vertical, seed=seed, gnss=gnss,
                      faults=tuple(parse_fault(f, FaultSpec3D) for f in faults))
    return simulate3d(cfg)


@pytest.fixture
def sim_flight():
    return flight


@functools.lru_cache(maxsize=3)
def _decoded(name: str) -> Ins3dInput:
    return read_ins3d(BAGS / name)


def sample_input(name: str) -> Ins3dInput:
    """``read_ins3d`` of the bundled sample bag ``bags/<name>``, decoded once per session; each
    call gets its own copy (no test sees another's changes)."""
    return copy.deepcopy(_decoded(name))
