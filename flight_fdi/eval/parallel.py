"""``parallel_map``: a list of seeded items through one module-level function on the campaign
engine (:mod:`flight_fdi.campaign.engine`) -- the map every study of this package runs on
(``montecarlo``, ``attitude study``; a new model's study calls it the same way)."""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from .errors import EvalError


def parallel_map(fn: Callable[[Any], dict], items: Sequence[Any], jobs: int = 1,
                 progress: bool = False, desc: str = "montecarlo",
                 on_result: Callable[[dict], None] | None = None, scheduler: str | None = None,
                 info: dict | None = None, warm: Callable[[], Any] | None = None) -> list[dict]:
    """``[fn(item) for item in items]`` on the campaign engine (results in completion order),
    with an optional tqdm progress bar on stderr: in this process when ``jobs`` is 1, else on a
    local Dask cluster of ``jobs`` worker processes, or on the existing cluster at
    ``scheduler`` (tcp://HOST:PORT). ``fn`` must be a module-level function and each item carry
    its own seed: the results do not depend on where they ran. The first item that raises stops
    the map (the others are cancelled) and its exception is raised here. ``info``, when given,
    receives ``engine`` (where it ran) and ``workers``. ``warm`` (a module-level function) runs
    on every Dask worker as it joins, e.g. :func:`flight_fdi.campaign.worker.warm_analysis`."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise EvalError(f"jobs must be an integer >= 1, got {jobs!r}")
    from flight_fdi.campaign.engine import Engine, EngineError, EngineSpec

    try:
        spec = EngineSpec(workers=max(1, min(int(jobs), len(items))), scheduler=scheduler)
    except EngineError as exc:
        raise EvalError(str(exc)) from None
    out: list[dict] = []

    def arrived(_i: int, rec: dict, err: BaseException | None) -> None:
        if err is not None:
            raise err
        out.append(rec)
        if on_result is not None:
            on_result(rec)

    with Engine(spec, warm=warm) as engine:
        if scheduler is not None:
            engine.wait_for_workers(1)
        if info is not None:
            info.update(engine=engine.describe(), workers=engine.worker_count())
        engine.run(fn, items, progress=progress, desc=desc, unit="flight", on_outcome=arrived)
    return out
