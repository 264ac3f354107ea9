"""Run one function in a forked child process, beside the caller (a second core for a Python loop).

The backward information filter and the forward filter are both Python loops, so threads cannot
run them side by side (the GIL); a forked child can, and it shares the parent's inputs without
copying them. The child sends its result back pickled through a pipe and exits with
``os._exit`` (no atexit handlers, no flushing of the parent's buffers).

Forking is only safe from a process that has a single thread (a lock held by another thread at
the fork stays held forever in the child), so :func:`fork_call` runs the function in the caller
when the process has other threads, or when the platform cannot fork -- same result, no second
core. An exception in the child is raised again in the parent by :meth:`ForkedCall.result`.
"""
from __future__ import annotations

import os
import pickle
import signal
import threading
from typing import Any, Callable

from .errors import CoreError

_CHUNK = 1 << 20


def can_fork() -> bool:
    """True when :func:`fork_call` would really fork (os.fork exists, one thread running)."""
    return hasattr(os, "fork") and threading.active_count() == 1


class ForkedCall:
    """A call running in a forked child (``forked``), or already done in the caller."""

    def __init__(self, fn: Callable[..., Any], args: tuple, kwargs: dict,
                 fork: bool = True) -> None:
        self._pid: int | None = None
        self._fd: int | None = None
        self._done = False
        self._value: Any = None
        self._error: BaseException | None = None
        self.forked = fork and can_fork()
        if not self.forked:
            self._run_here(fn, args, kwargs)
            return
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # the child: compute, send, exit without running any of the parent's code
            code = 1
            try:
                os.close(r)
                try:
                    payload = pickle.dumps((True, fn(*args, **kwargs)), protocol=5)
                except BaseException as exc:  # noqa: BLE001 - sent to the parent
                    try:
                        payload = pickle.dumps((False, exc), protocol=5)
                    except Exception:
                        payload = pickle.dumps((False, CoreError(
                            f"{type(exc).__name__}: {exc}")), protocol=5)
                view = memoryview(payload)
                while view:
                    view = view[os.write(w, view):]
                code = 0
            finally:
                os._exit(code)
        os.close(w)
        self._pid, self._fd = pid, r

    def _run_here(self, fn: Callable[..., Any], args: tuple, kwargs: dict) -> None:
        try:
            self._value = fn(*args, **kwargs)
        except Exception as exc:
            self._error = exc
        self._done = True

    def result(self) -> Any:
        """The function's return value (waits for the child); its exception is raised here."""
        if not self._done:
            chunks = []
            try:
                while True:
                    chunk = os.read(self._fd, _CHUNK)
                    if not chunk:
                        break
                    chunks.append(chunk)
            except BaseException:  # e.g. KeyboardInterrupt: do not wait for the child
                self.cancel()
                raise
            self._close()
            try:
                ok, value = pickle.loads(b"".join(chunks))
            except Exception:
                raise CoreError("the forked worker ended without a result (killed?)") from None
            if ok:
                self._value = value
            else:
                self._error = value
            self._done = True
        if self._error is not None:
            raise self._error
        return self._value

    def cancel(self) -> None:
        """Stop the child if it is still running (safe to call at any time, and again)."""
        if self._pid is not None:
            try:
                os.kill(self._pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self._close()

    def _close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        if self._pid is not None:
            os.waitpid(self._pid, 0)
            self._pid = None

    def __enter__(self) -> "ForkedCall":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.cancel()


def fork_call(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> ForkedCall:
    """Start ``fn(*args, **kwargs)`` in a forked child when that is safe (see the module doc),
    else run it now; use as a context manager so that the child never outlives the caller."""
    return ForkedCall(fn, args, kwargs)
