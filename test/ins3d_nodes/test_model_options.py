"""The model options of filter_node's ins3d mode (``ins3d_vertical``, ``ins3d_latency``,
``ins3d_reference_markov``, ``ins3d_aligned_prior``): their defaults are ``analyze_ins3d``'s (a
bag without a description block runs as before), a bag description's ``error_model`` block
becomes them, the recording carries them (ModelInfo ``model.*``) and the smoother reads them
back; a bad value is refused at start."""
from __future__ import annotations

import inspect

import pytest

from flight_fdi.bagio.ins3d_input import error_model_options
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.grade_file import CustomGrade, diagnosis_config_of, grade_from_dict
from flight_fdi.nodes.errors import ParameterError
from flight_fdi.nodes.ins3d_mode import build_model, model_options, option_parameters
from flight_fdi.nodes.ins3d_pipeline import ACK_WINDOW, ack_window, filter_parameters3d
from flight_fdi.nodes.ins3d_recording import (grade_params, option_params, recorded_grade,
                                              recorded_options)
from flight_fdi.nodes.params import check_value, spec_table

REAL = {"vertical": "free", "latency": True, "reference_markov": None,
        "initial_attitude": "independent"}


def _defaults():
    from flight_fdi.nodes.filter_node import _DEFAULTS

    return _DEFAULTS


def test_the_defaults_are_the_analysis_defaults():
    d = _defaults()
    sig = inspect.signature(analyze_ins3d).parameters
    opts = model_options(d)
    assert opts == {k: sig[k].default for k in ("vertical", "latency", "ref_markov",
                                                "aligned_prior")}
    # a bag without a description block: no parameter set, the filter as before
    assert error_model_options(None) == {} == error_model_options({"vertical": "baro"})
    assert option_parameters({}) == {}
    from flight_fdi.core.gate import GateConfig
    names = {"ins_imu": "/i", "ins_velocity": "/v", "ins_fix": "/f", "ref_velocity": "/r"}
    assert filter_parameters3d(names, "mems", 2, GateConfig(), {}) \
        == filter_parameters3d(names, "mems", 2, GateConfig())


def test_a_description_block_becomes_the_node_model():
    d = _defaults()
    params = option_parameters(error_model_options({"error_model": REAL}))
    assert params == {"ins3d_vertical": "free", "ins3d_latency": True,
                      "ins3d_reference_markov": [0.0, 0.0, 0.0], "ins3d_aligned_prior": False}
    for k, v in params.items():
        assert check_value(spec_table_of()[k], v) is None, k
    m = build_model({**d, **params, "model": "ins3d", "ins3d_rows": 2}, d)
    assert (m.vertical, m.latency, m.ref_markov, m.rows) == ("free", True, None, 2)
    assert m.n == 12 + 1                     # no loop, no Markov states, the latency
    assert model_options({**d, **params}) == error_model_options({"error_model": REAL})


def spec_table_of():
    from flight_fdi.nodes.ins3d_mode import INS3D_PARAMS

    return spec_table(INS3D_PARAMS)


@pytest.mark.parametrize("options", [
    error_model_options({"error_model": REAL}),
    {"vertical": "damped", "latency": False, "ref_markov": (0.01, 0.02, 10.0),
     "aligned_prior": True},
])
def test_the_options_round_trip_through_the_model_info(options):
    full = {**model_options(_defaults()), **options}
    names, values = option_params(full)
    assert all(n.startswith("model.") for n in names) and len(set(names)) == len(names)
    params = {"rows": 2.0, "t0_sec": 1.0, "t0_nanosec": 0.0, **dict(zip(names, values))}
    assert recorded_options(params) == full
    assert recorded_options({"rows": 3.0, "t0_sec": 1.0}) == {}     # a recording before


def test_the_seed_settings_of_a_grade_file_round_trip():
    g = grade_from_dict({"name": "short", "base": "mems", "seed_fisher_window": 6,
                         "seed_min_valid_steps": 7, "seed_episode_probability": 1e-4})
    cfg = diagnosis_config_of(g)
    assert (cfg.fisher_window, cfg.min_valid_steps, cfg.episode_probability) == (6, 7, 1e-4)
    names, values = grade_params(g)
    back = recorded_grade("ins3d/short", dict(zip(names, values)))
    assert isinstance(back, CustomGrade) and back == g and diagnosis_config_of(back) == cfg
    plain = grade_from_dict({"name": "plain", "base": "mems"})
    assert diagnosis_config_of(plain) == diagnosis_config_of(
        recorded_grade("ins3d/plain", dict(zip(*grade_params(plain)))))
    assert "fisher_window" not in plain.numbers()


@pytest.mark.parametrize("params, needle", [
    ({"ins3d_reference_markov": [0.02, 0.0, 30.0]}, "'ins3d_reference_markov'"),
    ({"ins3d_reference_markov": [0.02, 0.03]}, "'ins3d_reference_markov'"),
])
def test_a_bad_option_is_refused_at_start(params, needle):
    d = _defaults()
    with pytest.raises(ParameterError, match=needle):
        build_model({**d, **params, "model": "ins3d"}, d)


def test_the_declared_ranges_refuse_bad_values():
    t = spec_table_of()
    assert check_value(t["ins3d_vertical"], "upside") is not None
    assert check_value(t["ins3d_reference_markov"], [-0.1, 0.1, 1.0]) is not None
    assert check_value(t["ins3d_vertical"], "free") is None


def test_the_player_window_covers_a_sparse_reference():
    """The sample bags (10-Hz reference against 45 INS messages a second) keep ACK_WINDOW; the
    real recordings' 1-Hz reference against 3 x 40-Hz INS topics gets two periods + margin."""
    sample = {"/ins/velocity": 36001, "/ins/imu": 36000, "/ins/fix": 9001,
              "/reference/velocity": 18001}
    assert ack_window(sample, "/reference/velocity") == ACK_WINDOW
    real = {"/ins/velocity": 600, "/ins/imu": 600, "/ins/fix": 600, "/reference/velocity": 14}
    assert ack_window(real, "/reference/velocity") == 2 * 129 + 45
    assert ack_window({}, "/reference/velocity") == ACK_WINDOW


def test_a_replay_never_ends_its_record_on_an_idle_pause():
    """The pipeline flushes at the end of its bag itself; its filter's idle flush is off, so a
    replay starved of CPU for longer than the node's default 2 s is not split in two records."""
    from flight_fdi.core.gate import GateConfig
    from flight_fdi.nodes.ins3d_mode import INS3D_PARAMS
    names = {"ins_imu": "/i", "ins_velocity": "/v", "ins_fix": "/f", "ref_velocity": "/r"}
    spec = next(s for s in INS3D_PARAMS if s.name == "ins3d_end_idle_s")
    assert spec.default > 0
    assert filter_parameters3d(names, "mems", 2, GateConfig())["ins3d_end_idle_s"] == 0.0


def test_the_height_parameters_become_the_node_model_and_round_trip():
    """``ins3d_height_topic`` (and its options, defaults setting (i)): 3 rows, the third the
    height, the position states, v0 1 m/s, the velocity reference's Markov sigma with the
    height's; ``height_parameters`` of the spec give it back; the recording carries the options
    and the datum's prior (``model.height_row``, ``model.v0_sigma_up``, ``model.h0_sigma``)."""
    from flight_fdi.bagio.height_input import HeightSpec
    from flight_fdi.nodes.ins3d_mode import height_parameters, height_spec
    d = _defaults()
    values = {**d, "model": "ins3d", "ins3d_height_topic": "/baro"}
    m = build_model(values, d)
    assert (m.rows, m.height_row, m.position, m.v0_sigma_up) == (3, True, True, 1.0)
    assert m.ref_markov == (0.02, 0.4, 30.0, 5.0) and m.h0_sigma is None   # each row its tau
    spec = HeightSpec("/b", sigma=0.2, markov=None, datum="absolute", v0_sigma_up=0.3)
    params = height_parameters(spec, "sensor_msgs/msg/NavSatFix")
    for k, v in params.items():
        assert check_value(spec_table_of()[k], v) is None, k
    assert height_spec({**d, **params}) == spec
    full = {**model_options(values), "h0_sigma": 0.35}
    names, vals = option_params(full)
    back = recorded_options({"rows": 3.0, **dict(zip(names, vals))})
    assert back == {**full, "position": True, "height_row": True}
    no_h0 = recorded_options(dict(zip(*option_params({**full, "h0_sigma": None}))))
    assert no_h0["h0_sigma"] is None


@pytest.mark.parametrize("params, needle", [
    ({"ins3d_rows": 2}, "'ins3d_rows': got 2; allowed: 3 with ins3d_height_topic"),
    ({"ins3d_height_markov": [0.4, 0.0]}, "'ins3d_height_markov'"),
    ({"ins3d_height_markov": [0.4]}, "'ins3d_height_markov'"),
    ({"ins3d_height_topic": "/ins/fix"}, "five distinct topics"),
])
def test_a_bad_height_parameter_is_refused_at_start(params, needle):
    d = _defaults()
    with pytest.raises(ParameterError, match=needle):
        build_model({**d, "model": "ins3d", "ins3d_height_topic": "/baro", **params}, d)
    t = spec_table_of()
    assert check_value(t["ins3d_height_type"], "std_msgs/msg/Float64") is not None
    assert check_value(t["ins3d_height_datum"], "geoid") is not None
    assert check_value(t["ins3d_height_sigma"], 0.0) is not None
