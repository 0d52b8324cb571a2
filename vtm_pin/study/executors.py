"""Where a study's pieces of work run: a local process pool, or a Dask cluster.

A piece is a list of cases; ``work(piece)`` returns their records (JSON-ready dicts). The
executors yield the records as the pieces complete, in any order, and know nothing of what a
case is.

* :func:`on_pool`: a process pool on this machine (``forkserver`` where available: the workers
  fork from a server that has imported vtm_pin and Pinocchio once), with BLAS / OpenMP threads
  pinned to 1 and Ctrl-C left to the driver. A worker ends when its driver dies, however it
  dies: killed outright, or dead but not yet reaped (a zombie); on Linux at once (the kernel
  kills it when its parent, the fork server, exits), elsewhere within
  :data:`WATCHDOG_PERIOD` seconds. Interrupted (Ctrl-C, or the records no longer wanted), the
  driver terminates the workers at once instead of waiting for the pieces under way.
* :func:`connect` and :func:`on_dask`: an existing ``dask.distributed`` cluster (the ``cluster``
  extra). Accepted addresses: ``tcp://host:port``, and ``tls://host:port`` when Dask's own TLS
  settings give the client its certificates (``distributed.comm.tls.ca-file``,
  ``distributed.comm.tls.client.cert`` and ``.key`` in the Dask configuration, e.g. the
  variables ``DASK_DISTRIBUTED__COMM__TLS__CA_FILE`` ...); anything else (``inproc://``,
  ``ws://``, ``ucx://``, no scheme) is refused. Each step is bounded in time and ends, if it
  fails, in one :class:`~vtm_pin.exceptions.StudyError` naming ``--scheduler`` (nothing more
  is printed, at exit either): the scheduler must accept the connection (refusals are tried
  again meanwhile) and send a Dask handshake within :data:`CONNECT_TIMEOUT` seconds (read
  here, at most :data:`HANDSHAKE_LIMIT` bytes, before Dask's client is made: a port that
  answers something else is refused without trusting what it says); it must then say it is
  a scheduler (not a worker) within :data:`CONNECT_TIMEOUT` seconds; and the cluster must
  have a worker within :data:`WORKERS_TIMEOUT` seconds. Only a scheduler that passes these
  checks and then stops answering is left to Dask's own time-outs.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import gc
import multiprocessing
import multiprocessing.forkserver
import os
import re
import signal
import socket
import ssl
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from ..exceptions import StudyError

#: Environment variables that pin a worker's BLAS / OpenMP pools to one thread.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: Modules the pool's fork server imports once, before it forks the workers.
PRELOAD = [
    "vtm_pin.study.runner",
    "vtm_pin.outputs.pipeline",
    "vtm_pin.scene.annex_b",
    "example_robot_data",
    "vtm_pin.study.preload",  # trimesh, Numba and the compiled kernels: ~0.6 s a worker
    "vtm_pin.outputs.plotting",  # Matplotlib, for the study's graphs (in_background)
    "matplotlib.backends.backend_agg",
]
#: How often a pool worker checks that its driver is alive [s] (the fallback where the
#: kernel cannot end it with its parent).
WATCHDOG_PERIOD = 1.0

#: What a background function returns.
T = TypeVar("T")
#: A piece of work: its records.
Work = Callable[[list[Any]], list[dict]]


def on_pool(
    pieces: Sequence[list[Any]],
    work: Work,
    workers: int,
    setup: Callable[[], None] | None = None,
) -> Iterator[dict]:
    """Run ``work`` on each piece in a pool of ``workers`` processes; yield the records.

    ``setup`` (picklable) runs once in each worker before its first piece.
    """
    context = start_fork_server()
    with _pinned_threads():
        executor = ProcessPoolExecutor(
            workers,
            mp_context=context,
            initializer=_init_worker,
            initargs=(os.getpid(), setup),
        )
    return _drain(executor, pieces, work, workers)


@contextlib.contextmanager
def in_background(function: Callable[..., T], *args: Any) -> Iterator[Future[T]]:
    """``function(*args)`` in a process of its own while the caller goes on: its future.

    The process forks from the pools' fork server (:func:`start_fork_server`) and is set up as
    a pool worker is. Left early (Ctrl-C, an error), the process is terminated; otherwise it
    is waited for.
    """
    context = start_fork_server()
    with _pinned_threads():
        executor = ProcessPoolExecutor(
            1, mp_context=context, initializer=_init_worker, initargs=(os.getpid(),)
        )
    finished = False
    try:
        yield executor.submit(function, *args)
        finished = True
    finally:
        if finished:
            executor.shutdown(wait=True)
        else:
            _terminate(executor)


def default_workers() -> int:
    """The number of cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def start_fork_server() -> multiprocessing.context.BaseContext:
    """Start the pools' fork server now, if this platform has one; returns the pools' context.

    The server imports :data:`PRELOAD` (~1.7 s) while the driver goes on (importing the
    command, reading the study, drawing its cases). A pool made later forks its workers from
    it, which start their cases at once (:mod:`vtm_pin.study.preload`), and the graphs'
    process, with Matplotlib loaded. It starts with the BLAS / OpenMP thread counts pinned to
    1 (:data:`THREAD_VARIABLES`), which its workers inherit: a server started by the pool's
    first task would have the driver's own. A no-op if it runs already; ``spawn`` where there
    is no fork server.
    """
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    with _pinned_threads():
        multiprocessing.forkserver.ensure_running()
    return context


@contextlib.contextmanager
def _pinned_threads() -> Iterator[None]:
    """This process's environment with :data:`THREAD_VARIABLES` at 1, then as it was."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _drain(
    executor: ProcessPoolExecutor, pieces: Sequence[list[Any]], work: Work, workers: int
) -> Iterator[dict]:
    """Keep the pool fed with a few pieces per worker; yield records as they complete.

    Left early (Ctrl-C, an error, or the generator closed), the workers are terminated: the
    pieces under way are lost, not waited for.
    """
    pending: set[Future[list[dict]]] = set()
    queue = iter(pieces)
    finished = False
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
        finished = True
    except BrokenProcessPool as exc:  # from a result, or from submitting to the broken pool
        raise StudyError(
            "",
            "",
            "a worker process died (out of memory, or killed); the finished cases are stored: "
            "run the same command again to continue",
        ) from exc
    finally:
        if finished:
            executor.shutdown(wait=True)
        else:
            _terminate(executor)


def _terminate(executor: ProcessPoolExecutor) -> None:
    """Stop the pool now: drop the pieces not started, terminate the workers under way."""
    processes = list((getattr(executor, "_processes", None) or {}).values())  # CPython's
    executor.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        try:
            process.terminate()
        except (OSError, ValueError):  # already gone, or already closed
            pass
    for process in processes:
        try:
            process.join(WATCHDOG_PERIOD)
        except (OSError, ValueError, AssertionError):
            pass


#: A pool worker's garbage-collector thresholds (``gc.set_threshold``; Python's are 700, 10,
#: 10): a young collection every 50,000 net allocations, not 700.
WORKER_GC_THRESHOLDS = (50_000, 20, 100)


def tune_collector() -> None:
    """Set a study worker's garbage collector: what it has imported out of it, rarer passes.

    What the worker has imported lives as long as it does: frozen (``gc.freeze``), it is out
    of the collector's full passes, which otherwise traverse it every few hundred cases
    (0.2-0.3 ms a UR10 case measured, 4-7 % of its time). A case allocates some ten thousand
    containers, most short-lived, and its records and results live until its batch ends: with
    Python's thresholds the collector ran ~200 young and ~20 middle passes over 1,250 UR10
    cases (0.10-0.14 ms a case by ``gc.callbacks``), with :data:`WORKER_GC_THRESHOLDS` two
    young passes (~0.02 ms a case) and the same peak memory (513 against 519 MB). The
    cases' own cycles are still collected.
    """
    gc.freeze()
    gc.set_threshold(*WORKER_GC_THRESHOLDS)


def _init_worker(driver: int, setup: Callable[[], None] | None = None) -> None:
    """A pool worker: Ctrl-C is the driver's to handle; the worker ends when the driver dies.

    Then ``setup()``, if given (:func:`on_pool`).

    A driver killed outright (SIGKILL) cannot shut its pool down. Its fork server then sees
    the driver's end of their pipe close and exits; on Linux the kernel kills the worker when
    that parent exits (``PR_SET_PDEATHSIG``). Elsewhere, and as a second line, a watchdog
    thread ends the worker within :data:`WATCHDOG_PERIOD` seconds once its parent has changed
    or its driver is gone or a zombie (dead, not yet reaped).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tune_collector()
    parent = os.getppid()
    if parent != driver:  # a fork server (single-threaded): safe to die with
        _die_with_parent()
    if os.getppid() != parent or not _alive(driver):
        os._exit(1)
    threading.Thread(target=_watch, args=(driver, parent), daemon=True).start()
    if setup is not None:
        setup()


def _die_with_parent() -> None:
    """Ask Linux to kill this process when its parent exits (no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):  # no prctl: the watchdog is the only line
        pass


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by another user (a recycled pid)
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as file:
            state = file.read().rsplit(b")", 1)[1].split()[0]
    except (OSError, IndexError):  # no /proc (not Linux), or gone meanwhile
        return True
    return state not in (b"Z", b"X")


def _watch(driver: int, parent: int) -> None:
    while True:
        time.sleep(WATCHDOG_PERIOD)
        if os.getppid() != parent or not _alive(driver):
            os._exit(1)


#: Seconds a Dask scheduler has to accept the connection and send its handshake (a refused
#: connection is tried again meanwhile: the scheduler may be starting).
CONNECT_TIMEOUT = 10.0
#: Seconds a cluster without a worker is given to get one before the study is refused.
WORKERS_TIMEOUT = 30.0
#: Largest first message accepted from a scheduler [bytes]: its handshake, under 100 bytes.
HANDSHAKE_LIMIT = 65536
#: Schemes of the scheduler addresses accepted.
SCHEMES = ("tcp", "tls")
#: How vtm-pin's Dask client gets its TLS certificates: Dask's own configuration.
TLS_SETTINGS = (
    "set Dask's TLS settings distributed.comm.tls.ca-file, distributed.comm.tls.client.cert "
    "and distributed.comm.tls.client.key (in ~/.config/dask/*.yaml, or as the variables "
    "DASK_DISTRIBUTED__COMM__TLS__CA_FILE, DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT and "
    "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY)"
)
_ADDRESS = re.compile(
    r"(?P<scheme>[A-Za-z][\w+.-]*)://(?P<host>\[[0-9A-Fa-f:.]+\]|[^\s/:\[\]]+):(?P<port>\d{1,5})"
)


def connect(scheduler: str) -> Any:
    """A client of the Dask scheduler at ``scheduler`` that has at least one worker.

    Raises:
        StudyError: dask.distributed is missing; the address is malformed or of a scheme not
            in :data:`SCHEMES` (``tls`` without Dask's TLS settings); no scheduler accepts
            the connection and sends a Dask handshake within :data:`CONNECT_TIMEOUT` seconds;
            the port answers something else; or the cluster has no worker within
            :data:`WORKERS_TIMEOUT` seconds.
    """
    try:
        from dask.distributed import Client
    except ImportError as exc:
        raise _refusal("needs dask.distributed: pip install 'vtm_pin[cluster]'") from exc
    host, port, context = _address(scheduler)
    _handshake(scheduler, host, port, context)
    _identify(scheduler, context)
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise _refusal(f"the Dask scheduler at {scheduler} cannot be used ({exc})") from exc
    try:
        client.wait_for_workers(1, timeout=WORKERS_TIMEOUT)
    except BaseException as exc:  # Ctrl-C as well: the client is closed, not left to exit
        close(client)
        if not isinstance(exc, (OSError, TimeoutError)):
            raise
        raise _refusal(
            f"the Dask scheduler at {scheduler} has no worker (waited {WORKERS_TIMEOUT:g} s); "
            f"start some, e.g. dask worker {scheduler}"
        ) from exc
    return client


def _refusal(problem: str) -> StudyError:
    return StudyError("command line", "--scheduler", problem)


def _address(scheduler: str) -> tuple[str, int, ssl.SSLContext | None]:
    """Host, port and TLS context (for ``tls://``) of a scheduler address; refused if unusable."""
    match = _ADDRESS.fullmatch(scheduler)
    if match is None or not 0 < int(match["port"]) < 65536:
        raise _refusal(f"'{scheduler}' is not a scheduler address such as tcp://host:8786")
    scheme = match["scheme"].lower()
    if scheme not in SCHEMES:
        raise _refusal(
            f"'{scheduler}': {scheme}:// is not accepted; a scheduler is reached by tcp:// "
            "(or tls:// with Dask's TLS settings)"
        )
    host, port = match["host"].strip("[]"), int(match["port"])
    if scheme == "tcp":
        return host, port, None
    from distributed.security import Security

    try:
        context = Security().get_connection_args("client")["ssl_context"]
    except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError
        raise _refusal(f"'{scheduler}': Dask's TLS settings cannot be used ({exc})") from exc
    if context is None:
        raise _refusal(f"'{scheduler}': tls:// needs a client certificate: {TLS_SETTINGS}")
    return host, port, context


def _handshake(scheduler: str, host: str, port: int, context: ssl.SSLContext | None) -> None:
    """Check that a Dask scheduler answers at ``host:port``, within :data:`CONNECT_TIMEOUT`.

    Reads the handshake the scheduler sends first (at most :data:`HANDSHAKE_LIMIT` bytes),
    before Dask's client, which would trust the length a port announces, and wait for ever.
    """
    deadline = time.monotonic() + CONNECT_TIMEOUT
    late = f"no Dask scheduler answered at {scheduler} within {CONNECT_TIMEOUT:g} s"
    raw = _open(scheduler, host, port, deadline, late)
    try:
        with raw:
            raw.settimeout(max(deadline - time.monotonic(), 0.01))  # for the TLS handshake
            link = context.wrap_socket(raw) if context is not None else raw
            with link:
                size = struct.unpack("<Q", _read(link, 8, deadline))[0]
                if not 8 <= size <= HANDSHAKE_LIMIT:
                    raise _refusal(
                        f"{scheduler} does not speak Dask's protocol (it announces a first "
                        f"message of {size} bytes)"
                    )
                message = _decode(_read(link, size, deadline))
    except TimeoutError as exc:
        raise _refusal(f"{late} (the connection was accepted, but no handshake came)") from exc
    except ConnectionError as exc:  # EOF, reset
        raise _refusal(f"{scheduler} closed the connection without a Dask handshake") from exc
    except ssl.SSLError as exc:
        raise _refusal(f"the TLS handshake with {scheduler} failed ({exc})") from exc
    except OSError as exc:
        raise _refusal(f"the connection to {scheduler} failed ({exc})") from exc
    if not isinstance(message, dict) or "python" not in message:
        raise _refusal(f"{scheduler} does not speak Dask's protocol (no handshake)")


def _identify(scheduler: str, context: ssl.SSLContext | None) -> None:
    """Check that the Dask server at ``scheduler`` is a scheduler (not a worker, say).

    Asked once its handshake has been checked, within :data:`CONNECT_TIMEOUT` seconds.
    """
    from distributed.comm import connect as open_comm

    async def identity() -> Any:
        comm = await open_comm(scheduler, timeout=CONNECT_TIMEOUT, ssl_context=context)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        answer = asyncio.run(asyncio.wait_for(identity(), CONNECT_TIMEOUT))
    except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
        raise _refusal(
            f"the Dask server at {scheduler} did not say what it is within "
            f"{CONNECT_TIMEOUT:g} s ({exc or type(exc).__name__})"
        ) from exc
    kind = answer.get("type") if isinstance(answer, dict) else None
    if kind != "Scheduler":
        raise _refusal(f"{scheduler} is a Dask {kind or 'server'}, not a scheduler")


def _open(scheduler: str, host: str, port: int, deadline: float, late: str) -> socket.socket:
    """A connection to ``host:port``, tried again until ``deadline`` while refused."""
    while True:
        left = deadline - time.monotonic()
        try:
            return socket.create_connection((host, port), timeout=max(left, 0.01))
        except socket.gaierror as exc:
            raise _refusal(f"'{scheduler}': unknown host {host} ({exc.strerror})") from exc
        except OSError as exc:
            if time.monotonic() + 0.2 >= deadline:
                raise _refusal(f"{late} ({exc.strerror or exc})") from exc
            time.sleep(0.2)


def _read(link: socket.socket, size: int, deadline: float) -> bytes:
    """Exactly ``size`` bytes from ``link`` by ``deadline``."""
    data = bytearray()
    while len(data) < size:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        link.settimeout(left)
        chunk = link.recv(min(size - len(data), 65536))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return bytes(data)


def _decode(body: bytes) -> Any:
    """A Dask message from its frames, or None if it is not one."""
    from distributed.protocol.core import loads
    from distributed.protocol.utils import unpack_frames

    try:
        frames, missing = unpack_frames(body, partial=True)
        if missing:
            return None
        return loads(frames, deserialize=False)
    except Exception:  # garbage: whatever the decoder makes of it
        return None


def close(client: Any) -> None:
    """Close a client, quietly and within :data:`CONNECT_TIMEOUT` seconds."""
    try:
        client.close(timeout=CONNECT_TIMEOUT)
    except Exception:  # a client that cannot close cleanly is left to the interpreter
        pass


def dask_workers(client: Any) -> int:
    """Worker processes of the cluster (at least 1)."""
    return max(1, len(client.scheduler_info().get("workers", {})))


def on_dask(pieces: Sequence[list[Any]], work: Work, client: Any) -> Iterator[dict]:
    """Run ``work`` on each piece on the cluster of ``client``; yield the records.

    The client is closed when the pieces are done (or the generator is closed), within
    :data:`CONNECT_TIMEOUT` seconds.
    """
    from dask.distributed import as_completed

    try:
        if not pieces:
            return
        futures = client.map(work, list(pieces), pure=False)
        for future in as_completed(futures, loop=client.loop):
            yield from future.result()
    finally:
        close(client)
