"""Independent tasks run in order: in-process, in local processes, or on a Dask cluster.

One executor for every job that fans out (grid batches, margin searches): results come back in
the order of the tasks, at most a window of them in flight, and ``poll()`` is called about twice
a second while a result is awaited (for progress that counts work done outside the results).
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Generator, Iterable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import wait as futures_wait
from contextlib import ExitStack, suppress
from typing import Any

from dvfc.analysis.output import remember_interrupts, worker_task

POLL_SECONDS = 0.5
"""How often ``poll()`` is called while a result is awaited."""


def _unless_interrupted(function: Callable, *arguments: Any) -> Any:
    """``function(*arguments)`` in a worker process as a :func:`~dvfc.analysis.output.worker_task`: a task queued
    before an interruption is not started, and Ctrl-C stops a running one within its step."""
    with worker_task():
        return function(*arguments)


def _interrupt_workers(pool: ProcessPoolExecutor) -> bool:
    """SIGINT to each of ``pool``'s worker processes (when the iterator stops early: Ctrl-C, or its consumer done
    with it), so that their tasks stop within a step instead of running to their end before the pool shuts down;
    False (the exception propagates)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        with suppress(ProcessLookupError):
            os.kill(process.pid, signal.SIGINT)
    return False


def run_tasks(
    function: Callable,
    arguments: Iterable[tuple],
    workers: int = 1,
    scheduler: str | None = None,
    poll: Callable[[], None] | None = None,
    shared: object = None,
) -> Generator:
    """``function(*a)`` for each ``a`` of ``arguments`` (``function(shared, *a)`` when ``shared``
    is given: sent to each worker once on a cluster), results in order. ``workers = 1`` without
    ``scheduler``: in this process; ``scheduler``: a Dask scheduler's address, or ``"local"`` for
    a LocalCluster of ``workers`` processes. At most ``2 x workers`` tasks are in flight; the pool
    or cluster is closed when the iterator is exhausted or closed."""
    poll = poll or (lambda: None)
    lead = () if shared is None else (shared,)
    if scheduler is None and workers <= 1:
        for a in arguments:
            yield function(*lead, *a)
            poll()
        return
    with ExitStack() as stack:
        if scheduler is not None:
            from distributed import Client, LocalCluster
            from distributed import wait as dask_wait

            if scheduler == "local":
                cluster = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True)
                stack.callback(cluster.close)
                client = Client(cluster)
            else:
                client = Client(scheduler)
            stack.callback(client.close)
            window = 2 * max(1, len(client.scheduler_info()["workers"]))
            lead = () if shared is None else (client.scatter(shared, broadcast=True),)
            submit: Callable[[Any], Any] = lambda a: client.submit(function, *lead, *a, pure=False)  # noqa: E731

            def wait(future) -> bool:
                try:
                    dask_wait([future], timeout=POLL_SECONDS)
                except TimeoutError:
                    return True
                return False
        else:
            pool = ProcessPoolExecutor(workers, initializer=remember_interrupts)
            stack.callback(lambda: pool.shutdown(cancel_futures=True))
            stack.push(lambda kind, *_: kind is not None and _interrupt_workers(pool))  # runs before the shutdown
            window = 2 * workers
            submit = lambda a: pool.submit(_unless_interrupted, function, *lead, *a)  # noqa: E731
            wait = lambda future: bool(futures_wait([future], timeout=POLL_SECONDS).not_done)  # noqa: E731

        def result(future):
            while wait(future):
                poll()
            poll()
            return future.result()

        in_flight = []
        for a in arguments:
            in_flight.append(submit(a))
            if len(in_flight) >= window:
                yield result(in_flight.pop(0))
        for future in in_flight:
            yield result(future)
