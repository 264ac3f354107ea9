"""Flight simulator with the fault catalogue (numpy only; no rclpy).

``simulate(SimConfig(...))`` runs one seeded flight of the seed-000 INS error model with
injected faults; ``write_bag`` stores it as a rosbag2 bag (see ``flight_fdi.sim.ins``).

The 3-D strapdown simulator (``ins3d``, ``bag3d``; trajectory, strapdown, imu3d, gnss, earth,
rotation; numba) is imported from its modules, not here, so that ``import flight_fdi.sim``
stays light (docs/sim3d.md).
"""
from .errors import SimError
from .faults import FaultSpec, parse_fault
from .ins import SimConfig, SimulatedFlight, propagate, simulate, simulate_to_bag, write_bag
from .profile import FlightProfile

__all__ = ["FaultSpec", "FlightProfile", "SimConfig", "SimError", "SimulatedFlight", "parse_fault",
           "propagate", "simulate", "simulate_to_bag", "write_bag"]
