"""Independent array computations at once, where a core is free (``together``), or one started early (``ahead``);
many of one kind spread over the cores (``in_threads``).

Most of a check's time is numpy's, scipy's and libigl's work on whole arrays, which runs outside Python's lock:
two checks that do not depend on each other (a garment's crossings and its close pairs against a body that does
not move) take about the time of the longer one on two cores. The helper threads are few (the cores but one) and
shared by the whole process; a call that finds none free runs its work in the caller's thread, so checks that
already run side by side (poses fitted in threads, a catalogue's workers) do not multiply the threads.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

#: Helper threads for ``together`` (the cores but one, at most 3; none on one core).
HELPERS = max(0, min(3, (os.cpu_count() or 1) - 1))
#: Threads of ``in_threads`` (the cores, at most 4).
WORKERS = max(1, min(4, os.cpu_count() or 1))

_free = threading.BoundedSemaphore(HELPERS) if HELPERS else None
_pool = None
_pool_lock = threading.Lock()


def _helpers():
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(HELPERS, thread_name_prefix="garment-check")
        return _pool


def together(*calls):
    """Each call's result, in order: ``[call() for call in calls]``, the first calls on helper threads while
    helpers are free, the last (and any that found none) in the caller's thread.

    The calls must not depend on each other's effects. An exception in any is raised here, after every call has
    ended.
    """
    futures = [_helpers().submit(_released, call) if _free is not None and _free.acquire(blocking=False) else None
               for call in calls[:-1]] + [None]
    results, error = [None] * len(calls), None
    # The caller's own share first (the last call and those no helper took), then what the helpers give back:
    # every call ends before an error is raised.
    for i, (call, future) in enumerate(zip(calls, futures)):
        if future is None:
            try:
                results[i] = call()
            except BaseException as e:
                error = error or e
    for i, future in enumerate(futures):
        if future is not None:
            try:
                results[i] = future.result()
            except BaseException as e:
                error = error or e
    if error is not None:
        raise error
    return results


class Ahead:
    """A call started early on a helper thread where one is free (``ahead``), for its result later."""

    def __init__(self, call):
        self._call = call
        self._future = (_helpers().submit(_released, call) if _free is not None and _free.acquire(blocking=False)
                        else None)
        self._value, self._done = None, False

    def result(self):
        """The call's result: waited for where a helper took it, else computed now in the caller's thread (once)."""
        if self._future is not None:
            return self._future.result()
        if not self._done:
            self._value, self._done = self._call(), True
        return self._value


def ahead(call) -> Ahead:
    """Start ``call`` on a helper thread where one is free, while the caller goes on with work that does not touch
    what the call makes; ``.result()`` before using it. Where no helper is free the call runs at ``.result()``."""
    return Ahead(call)


def _released(call):
    try:
        return call()
    finally:
        _free.release()


def in_threads(fn, items, workers=None):
    """``[fn(x) for x in items]``, ``workers`` at once (default ``WORKERS``) in threads of their own: for many
    computations of one kind that are numpy's, scipy's and libigl's work on whole arrays (outside Python's lock),
    such as the counts of many poses or the self-checks of many shapes of one body."""
    workers = WORKERS if workers is None else max(1, int(workers))
    if workers == 1 or len(items) < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(workers, len(items)), thread_name_prefix="in-threads") as pool:
        return list(pool.map(fn, items))
