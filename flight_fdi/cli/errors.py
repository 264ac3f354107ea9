"""The one error type of the command line layer."""


class CliError(RuntimeError):
    """A command cannot do what was asked; the message is shown to the user as one line."""
