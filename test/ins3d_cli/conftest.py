"""A short 3-D contract bag (simulated once per session; ~400 s, the first turn at ~303 s)."""
from __future__ import annotations

import pytest

from flight_fdi.cli.main import main


@pytest.fixture(scope="session")
def bag3d(tmp_path_factory):
    out = tmp_path_factory.mktemp("ins3d") / "gyro_x"
    assert main(["simulate", str(out), "--model", "ins3d", "--duration", "400", "--seed", "2",
                 "--fault", "gyro:step:t=150,mag=3deg/h,axis=x"]) == 0
    return out
