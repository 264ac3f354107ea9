"""The campaign engine: one function over many seeded tasks, on Dask (``dask.distributed``).

Generic on purpose: a *task* is any picklable object that carries everything its result depends
on (a bag path and the options, a Monte Carlo case and its seed), and ``fn`` a module-level
function. The engine runs ``fn(task)`` for every task and yields ``(index, result, error)`` in
completion order; callers that need a fixed order sort by index. A result never depends on where
or in which order it ran, so a study gives the same records on 1, 2 or 200 workers.

Where the tasks run (:class:`EngineSpec`):

* ``scheduler="tcp://HOST:PORT"``: an existing Dask cluster (``dask scheduler`` /
  ``dask worker``); the workers must be able to import flight_fdi and see the input paths;
* otherwise a local cluster started here (embedded, nothing to start): ``workers`` worker
  *processes* of one thread each (default: one per core) -- the analysis holds the GIL, threads
  would not run it in parallel;
* ``inline``: in this process, a plain loop (the default for one local worker: a cluster of one
  would only add its start-up).

A task whose worker dies is run again on another worker by the scheduler (up to Dask's
``distributed.scheduler.allowed-failures`` times, then its error is ``KilledWorker``), so a lost
worker loses no task and each task yields once. Tasks are submitted in a sliding window
(a few per worker), so a study of 10^5 flights holds only that many futures; a long list of
tasks goes in chunks of consecutive tasks (up to 8 in one Dask task, the last ones single:
:func:`guided_chunks`), which cuts the engine's cost per task (a few ms of CPU) without changing
any outcome.
"""
from __future__ import annotations

import itertools
import logging
import os
import sys
import uuid
import warnings
from contextlib import ExitStack, closing
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Sequence, Sized


#: what the local cluster's nannies put in a worker's environment before it starts: Dask's
#: default (one thread per BLAS pool: a worker is one core) *without* its
#: ``MALLOC_TRIM_THRESHOLD_=65536``. That setting also freezes glibc's mmap threshold at 128 kB,
#: so every array above it -- most of a flight's arrays -- is a fresh mmap whose pages fault in
#: on first touch (:func:`.worker.restore_malloc` undoes it on workers started by
#: ``dask worker``): measured ~27 000 page faults and ~0.05 s of system CPU per 1000-s flight
#: (0.1 s of CPU in all), +37 % wall time per flight against a plain loop (docs/scaling.md)
WORKER_ENVIRON = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}
#: settings of the local cluster's scheduler, nannies and workers (given to the worker processes
#: they start): the environment above, and fewer event-loop wake-ups beside a task that holds
#: the GIL for a whole flight -- each one takes the GIL from the task, which costs most on a
#: machine busy with other work
QUIET_WORKERS = {"distributed.worker.profile.enabled": False,  # samples stacks every 10 ms
                 "distributed.admin.tick.interval": "500ms",
                 "distributed.admin.system-monitor.interval": "2s",
                 "distributed.admin.system-monitor.gil.enabled": False,
                 "distributed.worker.memory.monitor-interval": "1s",
                 # tasks of about equal cost fed in a window: nothing to steal or to move
                 "distributed.scheduler.work-stealing": False,
                 "distributed.scheduler.active-memory-manager.start": False,
                 "distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}


#: automatic chunks (:func:`guided_chunks`): at most this many tasks in one Dask task, and at
#: most 1/CHUNK_SHARE of what each worker thread has left
MAX_CHUNK = 8
CHUNK_SHARE = 4


class EngineError(RuntimeError):
    """The engine cannot start or reach its cluster (one sentence for the user)."""


#: wall time the embedded local cluster adds to a batch, from its start to its close: the
#: scheduler, one nanny and worker process per core, each worker's warm-up (imports, compiled
#: kernels from numba's cache). Measured on the 2-core machine (load 3.5-4.5): start 3.2-3.9 s,
#: close 0.8-1.2 s (docs/scaling.md, "How many workers by default")
CLUSTER_COST_S = 4.0


def auto_workers(tasks: int, work_s: float, cores: int | None = None) -> int:
    """The workers of a batch whose worker count was not given: one per core (``cores``, None:
    :func:`default_workers`) and at most one per task; 1 -- this process, no cluster -- when
    spreading ``work_s`` (the tasks' estimated serial wall time) over them would save less than
    the cluster costs (:data:`CLUSTER_COST_S`): ``work_s * (1 - 1/w) < CLUSTER_COST_S``."""
    w = min(cores or default_workers(), max(int(tasks), 1))
    if w < 2 or work_s * (1.0 - 1.0 / w) < CLUSTER_COST_S:
        return 1
    return w


def default_workers() -> int:
    """Worker processes of the embedded local cluster: one per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class EngineSpec:
    """Where tasks run: ``scheduler`` (an existing cluster), else a local cluster of ``workers``
    processes (None: :func:`default_workers`), or ``inline`` in this process (None: inline when
    there is no scheduler and one worker)."""

    workers: int | None = None
    scheduler: str | None = None
    inline: bool | None = None

    def __post_init__(self) -> None:
        w = self.workers
        if w is not None and (isinstance(w, bool) or not isinstance(w, int) or w < 1):
            raise EngineError(f"workers must be an integer >= 1, got {w!r}")
        if self.scheduler is not None:
            if not isinstance(self.scheduler, str) or "://" not in self.scheduler:
                raise EngineError(f"scheduler must be an address like tcp://HOST:PORT, got "
                                  f"{self.scheduler!r}")
            if self.inline:
                raise EngineError("inline and scheduler exclude each other")

    @property
    def runs_inline(self) -> bool:
        if self.inline is not None:
            return bool(self.inline)
        return self.scheduler is None and (self.workers or default_workers()) == 1


#: (index, result, error): error is None, or the exception ``fn`` raised / the engine's
#: (e.g. distributed.KilledWorker when the task killed every worker it ran on)
Outcome = tuple[int, Any, BaseException | None]


class Engine:
    """A started engine (use as a context manager: the local cluster and the client are closed
    on exit, whatever happened)::

        with Engine(EngineSpec(workers=2)) as engine:
            for i, result, error in engine.run(fn, tasks, progress=True):
                ...
    """

    def __init__(self, spec: EngineSpec | None = None,
                 warm: Callable[[], Any] | None = None) -> None:
        self.spec = spec or EngineSpec()
        self.warm = warm  # run once on every worker when it joins (imports, compiled code)
        self.client = None
        self._stack = ExitStack()
        self._imported: set[str] = set()

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> "Engine":
        if self.spec.runs_inline:
            return self
        try:
            self._start()
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self._stack.close()
        self.client = None

    def _start(self) -> None:
        import dask
        from distributed import Client, LocalCluster

        if self.spec.scheduler is not None:
            try:
                self.client = self._stack.enter_context(
                    Client(self.spec.scheduler, timeout=_connect_timeout()))
            except OSError as exc:
                raise EngineError(f"cannot reach the Dask scheduler at {self.spec.scheduler}: "
                                  f"{exc}") from None
            self._setup_workers()
            return
        workers = self.spec.workers or default_workers()
        with warnings.catch_warnings(), dask.config.set(QUIET_WORKERS):
            # no dashboard; the scheduler's small HTTP server takes a free port when 8787 is
            # taken (another cluster on this machine) and would say so. Logs: critical only
            # (workers' shutdown chatter is not for the user; task errors come back as outcomes)
            warnings.filterwarnings("ignore", message="Port .* is already in use")
            cluster = self._stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=None, silence_logs=logging.CRITICAL))
        self.client = self._stack.enter_context(Client(cluster))
        self._setup_workers()

    def _setup_workers(self) -> None:
        """Every worker, now and joining later (a restarted one too), runs :class:`WorkerSetup`
        before its first task."""
        name = "flight-fdi-worker-setup"
        if self.warm is not None:
            name += f"-{self.warm.__module__}.{self.warm.__qualname__}"
        from .worker import WorkerSetup

        try:
            self.client.register_plugin(WorkerSetup(self.warm), name=name)
        except Exception as exc:
            raise EngineError(f"cannot set up the Dask workers ({type(exc).__name__}: {exc}); "
                              "start them in an environment with flight_fdi installed") from None

    # ------------------------------------------------------------------ facts
    @property
    def kind(self) -> str:
        if self.client is None:
            return "inline"
        return "cluster" if self.spec.scheduler else "local"

    def worker_count(self) -> int:
        """Workers now connected (1 inline)."""
        if self.client is None:
            return 1
        return len(self.client.scheduler_info(n_workers=-1)["workers"])

    def wait_for_workers(self, n: int = 1, timeout: float = 60.0) -> None:
        if self.client is None:
            return
        try:
            self.client.wait_for_workers(n, timeout=timeout)
        except TimeoutError:
            raise EngineError(f"the Dask cluster at {self.client.scheduler.address} has "
                              f"{self.worker_count()} worker(s) after {timeout:g} s, expected "
                              f">= {n}") from None

    def describe(self) -> str:
        if self.client is None:
            return "this process (no cluster)"
        n = self.worker_count()
        where = (f"the Dask cluster at {self.spec.scheduler}" if self.spec.scheduler
                 else "a local Dask cluster")
        return f"{where} ({n} worker{'s' if n != 1 else ''})"

    # ------------------------------------------------------------------ running
    def run(self, fn: Callable[[Any], Any], tasks: Sequence[Any], *, progress: bool = False,
            desc: str = "tasks", unit: str = "task",
            on_outcome: Callable[[int, Any, BaseException | None], None] | None = None,
            window: int | None = None, chunk: int | None = None) -> list[Outcome]:
        """Run ``fn`` on every task; the outcomes in completion order (``on_outcome`` is called
        with each as it arrives, e.g. to write it to disk). A tqdm bar on stderr with
        ``progress``. ``window`` and ``chunk``: see :meth:`iter`."""
        from tqdm import tqdm

        out: list[Outcome] = []
        errors = 0
        outcomes = self.iter(fn, tasks, window=window, chunk=chunk)
        with closing(outcomes), tqdm(total=len(tasks), desc=desc, unit=unit,
                                     disable=not progress, file=sys.stderr,
                                     dynamic_ncols=True) as bar:
            for outcome in outcomes:  # closing(): a raising on_outcome cancels the rest now
                out.append(outcome)
                if on_outcome is not None:
                    on_outcome(*outcome)
                if outcome[2] is not None:
                    errors += 1
                    bar.set_postfix(errors=errors, refresh=False)
                bar.update(1)
        return out

    def iter(self, fn: Callable[[Any], Any], tasks: Iterable[Any], window: int | None = None,
             chunk: int | None = None) -> Iterator[Outcome]:
        """``(index, result, error)`` of ``fn(task)`` as each completes. On Dask, ``chunk``
        consecutive tasks make one Dask task (None: :func:`guided_chunks` for a list of tasks --
        large chunks first, single tasks at the end --, 1 for an iterator) and at most
        ``window`` Dask tasks are submitted at a time (None: 4 per worker thread, at least 8)."""
        if self.client is None:
            yield from _iter_inline(fn, tasks)
            return
        threads = self._threads()
        if chunk is not None:
            sizes: Iterator[int] = itertools.repeat(chunk)
        elif isinstance(tasks, Sized):
            sizes = guided_chunks(len(tasks), threads)
        else:
            sizes = itertools.repeat(1)
        if window is None:
            window = max(8, 4 * threads)
        yield from self._iter_dask(fn, tasks, window, sizes)

    def _iter_dask(self, fn: Callable[[Any], Any], tasks: Iterable[Any], window: int,
                   sizes: Iterator[int]) -> Iterator[Outcome]:
        from distributed import as_completed

        client = self.client
        self._check_import(fn)
        name = getattr(fn, "__name__", "task")
        prefix = f"{name}-{uuid.uuid4().hex[:12]}"
        todo = _chunks(enumerate(tasks), sizes)
        index: dict[str, tuple[list[int], bool]] = {}  # key -> (task indices, chunked)
        live: dict[str, Any] = {}  # key -> future not yet yielded
        pending = as_completed()

        def submit_next() -> bool:
            part = next(todo, None)
            if part is None:
                return False
            first = part[0][0]
            if len(part) == 1:
                fut = client.submit(fn, part[0][1], key=f"{prefix}-{first}", pure=False)
            else:
                fut = client.submit(_run_chunk, fn, [t for _, t in part],
                                    key=f"{prefix}-{first}+{len(part)}", pure=False)
            index[fut.key] = ([i for i, _ in part], len(part) > 1)
            live[fut.key] = fut
            pending.add(fut)
            return True

        try:
            for _ in range(window):
                if not submit_next():
                    break
            for fut in pending:
                indices, chunked = index.pop(fut.key)
                live.pop(fut.key, None)
                outcomes = _outcomes_of(fut, indices, chunked)
                fut.release()
                submit_next()
                yield from outcomes
        finally:
            if live:  # stopped early (an error or the caller's break): nothing left running
                client.cancel(list(live.values()))
            pending.clear()

    def _check_import(self, fn: Callable[[Any], Any]) -> None:
        """Fail now, with the reason, when a worker cannot import ``fn``'s module (a worker
        that cannot unpickle a task never returns it)."""
        module = getattr(fn, "__module__", None)
        if not module or module == "__main__" or module in self._imported:
            return
        errors = {w: e for w, e in self.client.run(_import_error, module).items() if e}
        if errors:
            worker, why = next(iter(sorted(errors.items())))
            raise EngineError(f"{len(errors)} Dask worker(s) cannot import {module} (e.g. "
                              f"{worker}: {why}); start the workers in an environment with "
                              "flight_fdi installed")
        self._imported.add(module)

    def _threads(self) -> int:
        info = self.client.scheduler_info(n_workers=-1)["workers"]
        return sum(int(w.get("nthreads", 1)) for w in info.values()) or 1


def guided_chunks(n: int, threads: int) -> Iterator[int]:
    """Sizes of the chunks of ``n`` tasks on ``threads`` worker threads (guided
    self-scheduling): each chunk is at most 1/:data:`CHUNK_SHARE` of what each thread has left
    and at most :data:`MAX_CHUNK` tasks, so the first chunks are large (each Dask task costs a
    few ms of CPU in the scheduler, the client and the worker's event loop: ~10 % of a 0.1-s
    flight when every flight is one Dask task) and the last ones single tasks (the workers end
    together). 50 tasks on 1 thread: 16 Dask tasks; on 2 threads: 25; 10 000 on 2: ~1260."""
    left = n
    while left > 0:
        size = max(1, min(MAX_CHUNK, left // (CHUNK_SHARE * max(1, threads))))
        left -= size
        yield size


def _chunks(items: Iterator[Any], sizes: Iterator[int]) -> Iterator[list[Any]]:
    for size in sizes:
        part = list(itertools.islice(items, size))
        if not part:
            return
        yield part


def _run_chunk(fn: Callable[[Any], Any], tasks: list[Any]) -> list[tuple[Any, Exception | None]]:
    """On a worker: ``fn`` on each task of a chunk, each one's exception kept apart."""
    out: list[tuple[Any, Exception | None]] = []
    for task in tasks:
        try:
            out.append((fn(task), None))
        except Exception as exc:
            out.append((None, exc))
    return out


def _outcomes_of(fut: Any, indices: list[int], chunked: bool) -> list[Outcome]:
    """The outcomes of a finished (or failed) Dask task of ``indices``."""
    if fut.status == "finished":
        try:
            value = fut.result()
        except Exception as exc:  # lost between the status and the fetch
            return [(i, None, exc) for i in indices]
        if not chunked:
            return [(indices[0], value, None)]
        return [(i, res, err) for i, (res, err) in zip(indices, value)]
    exc = fut.exception()  # fn raised (unchunked), or the task was lost (KilledWorker)
    return [(i, None, exc) for i in indices]


def _iter_inline(fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Outcome]:
    for i, task in enumerate(tasks):
        try:
            result = fn(task)
        except Exception as exc:
            yield i, None, exc
        else:
            yield i, result, None


def _import_error(module: str) -> str | None:
    """On a worker: why ``module`` cannot be imported (None: it can)."""
    import importlib

    try:
        importlib.import_module(module)
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"
    return None


def _connect_timeout() -> float:
    return float(os.environ.get("FLIGHT_FDI_DASK_TIMEOUT", "30"))


def run_tasks(fn: Callable[[Any], Any], tasks: Sequence[Any], spec: EngineSpec | None = None,
              **kwargs: Any) -> list[Outcome]:
    """Start an engine, :meth:`Engine.run` the tasks, stop it."""
    with Engine(spec) as engine:
        return engine.run(fn, tasks, **kwargs)

