"""A node's set-up in its constructor: a node whose set-up fails is destroyed.

    super().__init__(name, **kwargs)
    with destroyed_on_failure(self):
        self._setup()

An invalid parameter (ParameterError, one line naming it) or any other error during the
set-up destroys the half-built node -- its publishers, timers, services, and what its own
``destroy_node`` releases (a bag player's open bag, a recorder's bag) -- before the error
propagates unchanged. One helper for the pipeline's nodes (bag_player, filter_node,
recorder_node, smoother_node, voter_node).
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator


@contextmanager
def destroyed_on_failure(node: Any) -> Iterator[None]:
    """Destroy ``node`` when the ``with`` block raises, then re-raise (see the module)."""
    try:
        yield
    except BaseException:
        node.destroy_node()
        raise


__all__ = ["destroyed_on_failure"]
