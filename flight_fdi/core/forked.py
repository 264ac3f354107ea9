"""Run one function in a forked child process, beside the caller (a second core for a Python loop).

The backward information filter and the forward filter are both Python loops, so threads cannot
run them side by side (the GIL); a forked child can, and it shares the parent's inputs without
copying them. The child sends its result back pickled through a pipe and exits with
``os._exit`` (no atexit handlers, no flushing of the parent's buffers). The arrays of the result
travel out of band (pickle protocol 5): each is written straight from its memory and read
straight into one page-aligned block of the parent, where the unpickled arrays live (no copy
into a bytes object on either side, none out of it; ~0.05-0.1 s less for the 22 MB of a
3-hour flight, docs/performance.md).

Forking is only safe from a process that has a single thread (a lock held by another thread at
the fork stays held forever in the child), so :func:`fork_call` runs the function in the caller
when the process has other threads, or when the platform cannot fork -- same result, no second
core. An exception in the child is raised again in the parent by :meth:`ForkedCall.result`.
"""
from __future__ import annotations

import io
import mmap
import os
import pickle
import signal
import struct
import threading
from typing import Any, Callable

from .errors import CoreError

#: the pipe's capacity asked for (Linux; fewer switches between the two processes)
_PIPE_SIZE = 1 << 20
#: offsets of the out-of-band buffers in the parent's block (a numpy array stays aligned)
_ALIGN = 64
_COUNT = struct.Struct("<QQ")  # (length of the pickle, number of out-of-band buffers)


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
        try:
            import fcntl

            fcntl.fcntl(w, fcntl.F_SETPIPE_SZ, _PIPE_SIZE)
        except (ImportError, AttributeError, OSError):
            pass  # (the default capacity: slower, same result)
        pid = os.fork()
        if pid == 0:  # the child: compute, send, exit without running any of the parent's code
            code = 1
            try:
                os.close(r)
                try:
                    _send(w, (True, fn(*args, **kwargs)))
                except BaseException as exc:  # noqa: BLE001 - sent to the parent
                    try:
                        _send(w, (False, exc))
                    except Exception:
                        _send(w, (False, CoreError(f"{type(exc).__name__}: {exc}")))
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
        """The function's return value (waits for the child's result); its exception is raised
        here. The child, exiting once its result is sent, is reaped here if it is already gone,
        else when the context ends (:meth:`cancel`): its exit does not delay the caller."""
        if not self._done:
            try:
                received = _receive(self._fd)
            except BaseException:  # e.g. KeyboardInterrupt: do not wait for the child
                self.cancel()
                raise
            if received is None:
                self._close()
                raise CoreError("the forked worker ended without a result (killed?)")
            self._close(wait=False)
            ok, value = received
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

    def _close(self, wait: bool = True) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        if self._pid is not None and os.waitpid(self._pid, 0 if wait else os.WNOHANG)[0]:
            self._pid = None

    def __enter__(self) -> "ForkedCall":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.cancel()


def _send(fd: int, obj: Any) -> None:
    """Write ``obj`` to ``fd``: the counts, the buffers' sizes, the pickle, then each out-of-band
    buffer from its own memory. Only a complete message is written (pickling fails first)."""
    buffers: list[pickle.PickleBuffer] = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    views = [b.raw() for b in buffers]
    _write_all(fd, _COUNT.pack(len(head), len(views))
               + struct.pack(f"<{len(views)}Q", *(v.nbytes for v in views)) + head)
    for view in views:
        _write_all(fd, view)


def _write_all(fd: int, data) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _receive(fd: int) -> Any:
    """What :func:`_send` wrote to the other end of ``fd``, or None when it ended early. The
    out-of-band buffers are read into one page-aligned, writable block; the unpickled arrays are
    views of it."""
    f = io.FileIO(fd, closefd=False)
    counts = _read_exactly(f, bytearray(_COUNT.size))
    if counts is None:
        return None
    n_head, n_buffers = _COUNT.unpack(counts)
    sizes = _read_exactly(f, bytearray(8 * n_buffers))
    head = _read_exactly(f, bytearray(n_head))
    if sizes is None or head is None:
        return None
    sizes = struct.unpack(f"<{n_buffers}Q", sizes)
    offsets, total = [], 0
    for size in sizes:
        offsets.append(total)
        total += -(-size // _ALIGN) * _ALIGN
    block = memoryview(mmap.mmap(-1, max(total, 1)))
    buffers = [block[o:o + size] for o, size in zip(offsets, sizes)]
    for buf in buffers:
        if _read_exactly(f, buf) is None:
            return None
    return pickle.loads(head, buffers=buffers)


def _read_exactly(f: io.FileIO, buf):
    """Fill ``buf`` from ``f``; ``buf``, or None at the end of the stream before it is full."""
    view, got = memoryview(buf), 0
    while got < len(view):
        n = f.readinto(view[got:])
        if not n:
            return None
        got += n
    return buf


def fork_call(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> ForkedCall:
    """Start ``fn(*args, **kwargs)`` in a forked child when that is safe (see the module doc),
    else run it now; use as a context manager so that the child never outlives the caller."""
    return ForkedCall(fn, args, kwargs)
