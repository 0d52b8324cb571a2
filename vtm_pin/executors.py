"""Where a study's pieces of work run: a local process pool, or a Dask cluster.

A piece is a list of cases; ``work(piece)`` returns their records (JSON-ready dicts). The
executors yield the records as the pieces complete, in any order, and know nothing of what a
case is.

* :func:`on_pool`: a process pool on this machine (``forkserver`` where available: the workers
  fork from a server that has imported vtm_pin and Pinocchio once), with BLAS / OpenMP threads
  pinned to 1 and Ctrl-C left to the driver; a worker ends when its driver dies.
* :func:`connect` and :func:`on_dask`: an existing ``dask.distributed`` cluster (the ``cluster``
  extra).
"""

from __future__ import annotations

import multiprocessing
import os
import re
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from .exceptions import StudyError

#: Environment variables that pin a worker's BLAS / OpenMP pools to one thread.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: Modules the pool's fork server imports once, before it forks the workers.
PRELOAD = ["vtm_pin.study_runner", "vtm_pin.pipeline", "vtm_pin.annex_b", "example_robot_data"]

#: A piece of work: its records.
Work = Callable[[list[Any]], list[dict]]


def on_pool(pieces: Sequence[list[Any]], work: Work, workers: int) -> Iterator[dict]:
    """Run ``work`` on each piece in a pool of ``workers`` processes; yield the records."""
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if "forkserver" in methods:
        context.set_forkserver_preload(PRELOAD)
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))  # inherited by the workers
    try:
        executor = ProcessPoolExecutor(
            workers, mp_context=context, initializer=_init_worker, initargs=(os.getpid(),)
        )
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    return _drain(executor, pieces, work, workers)


def _drain(
    executor: ProcessPoolExecutor, pieces: Sequence[list[Any]], work: Work, workers: int
) -> Iterator[dict]:
    """Keep the pool fed with a few pieces per worker; yield records as they complete."""
    pending: set[Future[list[dict]]] = set()
    queue = iter(pieces)
    try:
        for piece in queue:
            pending.add(executor.submit(work, piece))
            if len(pending) >= 4 * workers:
                break
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield from future.result()
                more = next(queue, None)
                if more is not None:
                    pending.add(executor.submit(work, more))
    except BrokenProcessPool as exc:  # from a result, or from submitting to the broken pool
        raise StudyError(
            "",
            "",
            "a worker process died (out of memory, or killed); the finished cases are stored: "
            "run the same command again to continue",
        ) from exc
    finally:
        executor.shutdown(wait=False, cancel_futures=True)


def _init_worker(driver: int) -> None:
    """A pool worker: Ctrl-C is the driver's to handle; the worker ends when the driver dies.

    A driver killed outright (SIGKILL) cannot shut its pool down; a watchdog thread ends the
    worker within :data:`WATCHDOG_PERIOD` seconds instead of leaving it to run.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch, args=(driver,), daemon=True).start()


#: How often a pool worker checks that its driver is alive [s].
WATCHDOG_PERIOD = 1.0


def _watch(driver: int) -> None:
    while True:
        time.sleep(WATCHDOG_PERIOD)
        try:
            os.kill(driver, 0)
        except ProcessLookupError:
            os._exit(1)
        except PermissionError:  # alive, owned by another user (a recycled pid): keep going
            continue


#: Seconds to wait for a Dask scheduler to answer.
CONNECT_TIMEOUT = 10.0


def connect(scheduler: str) -> Any:
    """A client of the Dask scheduler at ``scheduler`` (``tcp://host:port``).

    Raises:
        StudyError: dask.distributed is missing, the address is malformed, or the scheduler
            does not answer within :data:`CONNECT_TIMEOUT` seconds.
    """
    try:
        from dask.distributed import Client
    except ImportError as exc:
        raise StudyError(
            "command line", "--scheduler", "needs dask.distributed: pip install 'vtm_pin[cluster]'"
        ) from exc
    if not re.fullmatch(r"(tcp|tls|ws|wss|inproc)://[^\s/:]+:\d{1,5}", scheduler):
        raise StudyError(
            "command line",
            "--scheduler",
            f"'{scheduler}' is not a scheduler address such as tcp://host:8786",
        )
    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise StudyError(
            "command line",
            "--scheduler",
            f"no Dask scheduler answered at {scheduler} within {CONNECT_TIMEOUT:g} s ({exc})",
        ) from exc


def dask_workers(client: Any) -> int:
    """Worker processes of the cluster (at least 1)."""
    return max(1, len(client.scheduler_info().get("workers", {})))


def on_dask(pieces: Sequence[list[Any]], work: Work, client: Any) -> Iterator[dict]:
    """Run ``work`` on each piece on the cluster of ``client``; yield the records.

    The client is closed when the pieces are done (or the generator is closed).
    """
    from dask.distributed import as_completed

    try:
        if not pieces:
            return
        futures = client.map(work, list(pieces), pure=False)
        for future in as_completed(futures, loop=client.loop):
            yield from future.result()
    finally:
        client.close()
