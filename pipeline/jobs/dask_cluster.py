"""Where ``fsid batch`` and ``fsid campaign`` run their tasks: an existing Dask scheduler
(``--scheduler tcp://host:8786``: one started by hand, by dask-jobqueue on SLURM/PBS or by
dask-kubernetes), else a local cluster of worker processes started for the run (one thread
each: the numerics are single-threaded and a process keeps its compiled kernels between
tasks). Results arrive as they finish; a task whose worker dies runs again on another.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from pipeline.errors import FsidError

#: seconds to wait for an existing scheduler to answer
CONNECT_TIMEOUT_S = 20.0


def default_workers() -> int:
    """Workers of a local cluster: one per core."""
    return max(1, os.cpu_count() or 1)


@contextmanager
def dask_client(scheduler: str | None, workers: int | None, quiet: bool = True) -> Iterator[Any]:
    """A ``distributed.Client`` on ``scheduler``, or on a local cluster of ``workers``
    processes (default one per core) closed at the end; FsidError when the scheduler does
    not answer."""
    import dask
    from distributed import Client, LocalCluster

    dask.config.set({"distributed.scheduler.allowed-failures": 3, "distributed.worker.daemon": False})
    _quiet_logs()
    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise FsidError(
                f"--scheduler {scheduler}: no Dask scheduler answers there ({exc}); start one (dask scheduler) "
                "or leave --scheduler out for a local cluster"
            ) from None
        _quiet_logs()
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or default_workers()
    try:
        cluster = LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40 if quiet else 30
        )
    except (RuntimeError, OSError, TimeoutError) as exc:
        raise FsidError(
            f"could not start a local Dask cluster of {n} workers ({exc}); start one by hand (dask scheduler, "
            "dask worker) and give --scheduler, or fewer --workers"
        ) from None
    client = Client(cluster)
    _quiet_logs()
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def as_finished(
    client: Any, fn: Callable[..., Any], items: Sequence[Any], *args: Any, key: Callable[[Any], str]
) -> Iterator[tuple[Any, Any, BaseException | None]]:
    """(item, result or None, exception or None) of ``fn(item, *args)`` on the cluster, in
    the order they finish. A task that cannot run (its worker died more than the allowed
    number of times) arrives with its exception; a scheduler that goes away ends it with an
    FsidError."""
    from distributed import as_completed

    futures = {client.submit(fn, it, *args, key=f"fsid-{key(it)}-{time.time_ns()}", pure=False): it for it in items}
    try:
        for fut in as_completed(futures):
            item = futures[fut]
            try:
                got = fut.result()
            except Exception as exc:  # noqa: BLE001 - the task's own failure, recorded with the item
                if client.status != "running":
                    raise FsidError(
                        f"the Dask scheduler went away ({type(exc).__name__}): the tasks finished so far are kept; "
                        "run the same command again to do the rest"
                    ) from None
                yield item, None, exc
                continue
            yield item, got, None
    finally:
        for fut in futures:
            if not fut.done():
                fut.cancel()


def _quiet_logs() -> None:
    """distributed logs a lost connection with its traceback on stderr: the command says
    what happened in one line instead."""
    for name in ["distributed", *logging.root.manager.loggerDict]:
        if name.startswith("distributed"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
