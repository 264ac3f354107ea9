"""The WGS-84 Earth model lives in :mod:`flight_fdi.core.earth` (the simulator and the ins3d
error model share it); this module keeps the simulator's names."""
from ..core.earth import (A, E2, GE, GF, GK, GM_RATIO, OMEGA_IE, gravity, nav_rates, radii,
                          schuler_period)

__all__ = ["A", "E2", "GE", "GF", "GK", "GM_RATIO", "OMEGA_IE", "gravity", "nav_rates", "radii",
           "schuler_period"]
