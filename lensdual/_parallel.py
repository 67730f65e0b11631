"""Running independent tasks here, on a dask Client or on an Executor (one home)."""

import os
import warnings

__all__ = []


def available_threads(limit=8):
    """The cores this process may run on (its CPU affinity where known), at most ``limit``."""
    if hasattr(os, "sched_getaffinity"):
        n = len(os.sched_getaffinity(0))
    else:
        n = os.cpu_count() or 1
    return max(1, min(limit, n))


def check_client(client):
    """Return ``client`` if it is None or has a ``map`` method, else raise TypeError."""
    if client is not None and not callable(getattr(client, "map", None)):
        raise TypeError("client must be None, a dask.distributed.Client or a "
                        f"concurrent.futures.Executor, got {type(client).__name__}")
    return client


def run_tasks(fn, tasks, client, ignore=()):
    """``[fn(t) for t in tasks]`` serially, on a dask Client or on an Executor.

    ``ignore``: the warning categories the tasks silence themselves. Warning
    filters are process-wide and ``warnings.catch_warnings`` is not
    thread-safe: a task that leaves its block restores the filters another
    thread's task entered with. The categories are therefore also silenced
    here, around all the tasks, so that every state a thread restores silences
    them too.
    """
    with warnings.catch_warnings():
        for category in ignore:
            warnings.simplefilter("ignore", category)
        if client is None:
            return [fn(t) for t in tasks]
        if all(callable(getattr(client, k, None))
               for k in ("submit", "map", "gather", "scatter")):
            return client.gather(client.map(fn, tasks, pure=False))  # dask.distributed.Client
        return list(client.map(fn, tasks))
