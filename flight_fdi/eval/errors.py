"""The one error type of the evaluation and report packages."""
from flight_fdi.core.errors import CoreError


class EvalError(CoreError):
    """Invalid study or report setting, or unusable input to an evaluation.

    A subclass of :class:`~flight_fdi.core.errors.CoreError`, so the command line prints it as
    one line like every other user error.
    """
