"""What each flight_fdi_msgs message must carry (the issue's required content).

Both the rclpy round trip and the rosbags round trip check the built/registered types against
this list, so removing a field from a ``msg_defs/msg/*.msg`` file fails the tests.
"""

REQUIRED_FIELDS = {
    "Innovation": ["header", "channel", "innovation", "innovation_covariance", "beta2",
                   "gate_threshold", "gate_exceeded", "alarm_state", "row_beta2", "row_excluded"],
    "FilterState": ["header", "channel", "state_names", "x", "p", "z", "r", "h", "dt", "fused",
                    "gated"],
    "ModelInfo": ["model_name", "state_names", "state_units", "a", "qc", "h", "r"],
    "FaultLocalization": ["verdict", "element", "onset_s", "end_s", "magnitude", "j_peak", "gamma2",
                          "f_peak", "eta2", "exceed_fraction", "dof", "glr_hypothesis",
                          "glr_onset_s", "glr_magnitude", "glr_statistic", "glr_threshold",
                          "headline", "isolation", "sensor", "axis", "kind", "unit",
                          "turn_on_sensor", "turn_on_axis", "turn_on_magnitude",
                          "turn_on_magnitude_eng", "turn_on_unit_eng", "turn_on_prior_sigmas"],
    "SmoothedState": ["x_smoothed", "v", "v_tilde", "delta_d", "j", "j_terms", "f"],
    "VoteStatus": ["epsilon", "epsilon_sum", "isolated_imu", "selected_imu"],
}


def msg_file_fields(path) -> list[str]:
    """Field names declared in a .msg file (constants and comments left out)."""
    names = []
    for line in open(path, encoding="utf-8"):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        _type, rest = line.split(None, 1)
        if "=" in rest:  # a constant: TYPE NAME=VALUE
            continue
        names.append(rest.split()[0])
    return names
