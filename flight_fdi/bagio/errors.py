"""The one error type of the bag input/output layer."""


class BagError(RuntimeError):
    """A bag that cannot be opened, written or read as asked (one clear sentence)."""
