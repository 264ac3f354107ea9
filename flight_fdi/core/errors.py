"""The one error type of the estimation core."""


class CoreError(ValueError):
    """Invalid model, parameter or data given to the estimation core."""
