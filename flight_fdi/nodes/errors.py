"""The one error type of the ROS node layer."""


class ParameterError(ValueError):
    """A node parameter is invalid. The message names the parameter, the bad value and what is
    allowed; a node given an invalid parameter stops at start-up with this message."""
