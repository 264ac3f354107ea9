"""The simulator's height reference (``Sim3DConfig.height_reference``, ``simulate --model ins3d
--baro-topic``): a second barometer, independent of the INS's, with a turn-on offset, a
Gauss-Markov error, white noise and a drift (``gnss.HEIGHT_REFERENCE``) -- richer than the
analysis' model of it; written as FluidPressure (ISA), NavSatFix or PointStamped and read back
as the heights simulated; the INS flight itself unchanged by it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from flight_fdi.bagio import cdr
from flight_fdi.bagio.height_input import HeightSpec
from flight_fdi.bagio.ins3d_input import read_ins3d
from flight_fdi.cli.main import main
from flight_fdi.sim.bag3d import write_bag3d
from flight_fdi.sim.errors import SimError
from flight_fdi.sim.gnss import HEIGHT_REFERENCE, BaroConfig
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig


def _flight(height=None, seed=6, duration=60.0):
    return simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(duration_s=duration, seed=seed),
                                  seed=seed, height_reference=height))


def test_the_height_reference_leaves_the_flight_as_it_was_and_has_its_errors():
    plain = _flight()
    fl = _flight(dataclasses.replace(HEIGHT_REFERENCE, drift_mps=0.05))
    for a, b in ((plain.ins.h, fl.ins.h), (plain.gnss.v, fl.gnss.v),
                 (plain.accel.rate, fl.accel.rate), (plain.aid_h, fl.aid_h)):
        np.testing.assert_array_equal(a, b)
    assert plain.height_ref is None and "height_reference" not in plain.description()
    assert fl.description()["height_reference"]["drift_mps"] == 0.05
    err = fl.height_ref - fl.truth.nav.h
    # the drift (3 m over 60 s) and the turn-on offset, beyond the 0.3-m Markov and white noise
    slope, offset = np.polyfit(fl.t, err, 1)
    assert slope == pytest.approx(0.05, abs=0.01)
    assert abs(offset) > 1.0 and np.std(err - slope * fl.t - offset) < 0.6
    # another seed: another offset (a turn-on bias, 10 m sigma)
    assert abs(np.polyfit(fl.t, _flight(HEIGHT_REFERENCE, seed=7).height_ref
                          - fl.truth.nav.h, 1)[1] - offset) > 0.5
    with pytest.raises(SimError, match="baro tau s must be > 0"):
        BaroConfig(tau_s=0.0)
    with pytest.raises(SimError, match="baro white must be a number >= 0"):
        BaroConfig(white=-1.0)


@pytest.mark.parametrize("kind", [cdr.FLUID_PRESSURE, cdr.NAVSATFIX, cdr.POINT_STAMPED])
def test_the_height_topic_reads_back_as_simulated(kind, tmp_path):
    fl = _flight(HEIGHT_REFERENCE)
    bag = tmp_path / "b"
    counts = write_bag3d(fl, str(bag), height_topic="/reference/baro", height_type=kind,
                         height_rate_hz=10.0)
    assert counts["/reference/baro"] == 601
    inp = read_ins3d(bag, height=HeightSpec("/reference/baro", datum="absolute"))
    # the reference stamps are the baro's (both 10 Hz from 0 s): the row is h_INS - h_baro
    t_fix, h_fix = fl.t[::20], fl.ins.h[::20]
    k = np.round(inp.refs.t * 100).astype(int)
    np.testing.assert_allclose(inp.refs.z[:, 2], np.interp(inp.refs.t, t_fix, h_fix)
                               - fl.height_ref[k], atol=1e-6)
    published = HEIGHT_REFERENCE.white**2 + HEIGHT_REFERENCE.instability**2
    want = HeightSpec("/x").variance() if kind == cdr.POINT_STAMPED else published
    np.testing.assert_allclose(inp.refs.r[:, 2], want, rtol=1e-9)


def test_the_simulate_command_writes_the_height_topic(tmp_path, capsys):
    out = tmp_path / "b"
    assert main(["simulate", str(out), "--model", "ins3d", "--duration", "30", "--seed", "1",
                 "--baro-topic", "/alt", "--baro-type", "point", "--baro-rate", "20",
                 "--baro", "drift_mps=0.1"]) == 0
    assert "601 /alt" in capsys.readouterr().out
    assert main(["simulate", str(tmp_path / "c"), "--model", "ins3d", "--duration", "30",
                 "--baro", "white=0.2"]) == 1
    assert capsys.readouterr().err.strip() == \
        "flight-fdi simulate: error: --baro needs --baro-topic"
    assert main(["simulate", str(tmp_path / "d"), "--model", "ins3d", "--duration", "30",
                 "--baro-topic", "/alt", "--baro", "tau_s=-2"]) == 1
    assert "baro tau s must be a number >= 0" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "e"), "--baro-topic", "/alt"]) == 1
    assert "--baro-topic apply to --model ins3d only" in capsys.readouterr().err
