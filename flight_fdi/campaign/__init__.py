"""Campaign scale: many flights (a fleet's bags, a Monte Carlo study) on one engine.

``engine``: one function over many seeded tasks on Dask (an embedded local cluster by default,
or an existing cluster); ``batch``: ``flight-fdi batch`` (discover bags, analyse each like
``flight-fdi analyze``, resumable, one result JSON per flight); ``summary``: one table row per
flight; ``fleet``: the fleet HTML page.
"""
from .engine import Engine, EngineError, EngineSpec, default_workers, run_tasks

__all__ = ["Engine", "EngineError", "EngineSpec", "default_workers", "run_tasks"]
