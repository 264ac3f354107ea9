"""The one error type of the simulator."""


class SimError(ValueError):
    """Invalid simulator parameter, flight profile or fault specification."""
