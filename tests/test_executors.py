"""The executors keep their promises under faults: bounded Dask connections, pool workers that
die with their driver (zombie or not), and a prompt Ctrl-C.

The process tests run the real ``vtm-pin`` executable: what matters there is what the process
prints up to its very exit, and which processes it leaves behind.
"""

from __future__ import annotations

import functools
import gc
import multiprocessing
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

import vtm_pin.study.executors as executors
from vtm_pin.cli import EXIT_INTERRUPTED, main

VTM_PIN = Path(sys.executable).with_name("vtm-pin")
#: Seconds a ``vtm-pin`` process may take to start (imports) on a loaded 2-core machine.
START = 60.0
#: Seconds allowed besides a stated time: process start-up and a loaded machine.
MARGIN = 5.0
#: Seconds a driver has to exit after Ctrl-C while pieces run (the promise of the issue).
INTERRUPT_EXIT = 5.0
#: Seconds a killed driver's workers have to go (and release its stdout): the fork server's
#: exit, and on other systems than Linux the watchdog's period, with a margin.
ORPHAN_EXIT = 10.0

needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")


def command(*args: str) -> list[str]:
    """The real executable, or ``python -m vtm_pin`` where it is not installed as a script."""
    head = [str(VTM_PIN)] if VTM_PIN.exists() else [sys.executable, "-m", "vtm_pin"]
    return [*head, *args]


def write_grid(folder: Path) -> Path:
    """A study of 270 UR10 Annex-B cases: minutes of work on 2 workers, whatever the engine."""
    vary = {
        "joint": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"],
        "speed": [0.2, 0.4, 0.6, 0.8, 1.0],
        "payload": [0.0, 2.0, 4.0, 6.0, 8.0, 10.0],
        "extension": [0.33, 0.66, 1.0],
    }
    path = folder / "grid.yaml"
    path.write_text(yaml.safe_dump({"scenario": "ur10_annex_b", "vary": vary}, sort_keys=False))
    return path


def write_one_case(folder: Path) -> Path:
    path = folder / "study.yaml"
    vary = {"speed": [1.0], "duration": [0.9]}
    path.write_text(yaml.safe_dump({"scenario": "ur10_annex_b", "vary": vary}, sort_keys=False))
    return path


# -- Dask: every refusal in one line, within a stated time ------------------------------------


@contextmanager
def fake_server(answer: bytes | None) -> Iterator[str]:
    """A port that accepts connections and sends ``answer`` (or nothing, ever)."""
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(0.1)
    held: list[socket.socket] = []
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                connection, _ = listener.accept()
            except TimeoutError:
                continue
            held.append(connection)
            if answer is not None:
                connection.sendall(answer)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        stop.set()
        thread.join()
        for connection in held:
            connection.close()
        listener.close()


def refusal(tmp_path: Path, capsys: pytest.CaptureFixture[str], address: str) -> str:
    """The one line ``vtm-pin study --scheduler address`` prints; nothing is written."""
    out = tmp_path / "out"
    assert (
        main(["study", str(write_one_case(tmp_path)), "--out", str(out), "--scheduler", address])
        == 1
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("vtm-pin: error: ") and "--scheduler" in err
    assert not out.exists()
    return err


@pytest.mark.parametrize(
    ("address", "phrase"),
    [
        ("", "is not a scheduler address"),
        ("tcp://127.0.0.1", "is not a scheduler address"),
        ("tcp://127.0.0.1:0", "is not a scheduler address"),
        ("inproc://127.0.0.1:8786", "inproc:// is not accepted"),
        ("ws://127.0.0.1:8786", "ws:// is not accepted"),
        ("ucx://127.0.0.1:8786", "ucx:// is not accepted"),
        ("tls://127.0.0.1:8786", "distributed.comm.tls.client.cert"),
    ],
)
def test_only_tcp_and_configured_tls_addresses_are_accepted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], address: str, phrase: str
) -> None:
    pytest.importorskip("distributed")
    import dask

    with dask.config.set({"distributed.comm.tls.client.cert": None}):
        assert phrase in refusal(tmp_path, capsys, address)


def test_a_port_that_never_answers_is_refused_within_the_connect_timeout(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("distributed")
    monkeypatch.setattr(executors, "CONNECT_TIMEOUT", 1.0)  # 10 s by default
    with fake_server(None) as address:
        begin = time.monotonic()
        assert "no handshake came" in refusal(tmp_path, capsys, address)
    assert time.monotonic() - begin < 1.0 + MARGIN


def test_a_port_that_answers_garbage_is_refused_in_one_line_to_the_very_exit(
    tmp_path: Path,
) -> None:
    """Dask's client would allocate the 16 EiB the first 8 bytes announce, then print a
    traceback at exit; the handshake is read here instead, without trusting it."""
    pytest.importorskip("distributed")
    study = write_one_case(tmp_path)
    with fake_server(b"\xff" * 64) as address:
        args = command("study", str(study), "--out", str(tmp_path / "out"), "--scheduler", address)
        done = subprocess.run(args, capture_output=True, text=True, timeout=START)
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1, done.stderr
    assert "does not speak Dask's protocol" in done.stderr and "--scheduler" in done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_port_that_never_answers_is_refused_by_the_real_executable(tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    study = write_one_case(tmp_path)
    with fake_server(None) as address:
        args = command("study", str(study), "--out", str(tmp_path / "out"), "--scheduler", address)
        begin = time.monotonic()
        done = subprocess.run(args, capture_output=True, text=True, timeout=START)
        elapsed = time.monotonic() - begin
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert "within 10 s" in done.stderr
    assert executors.CONNECT_TIMEOUT <= elapsed < executors.CONNECT_TIMEOUT + START


@pytest.fixture()
def local_cluster(request: pytest.FixtureRequest) -> Iterator[object]:
    """A scheduler in this process, on TCP, with ``request.param`` threaded workers."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=request.param,
        threads_per_worker=1,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        scheduler_port=0,
        dashboard_address=":0",
    ) as cluster:
        yield cluster


@pytest.mark.parametrize("local_cluster", [0], indirect=True)
def test_a_scheduler_without_workers_is_refused_after_the_stated_wait(
    tmp_path: Path, local_cluster: object
) -> None:
    """The real interpreter's exit too: no traceback from the closed client, one line."""
    study = write_one_case(tmp_path)
    wait = 2.0  # WORKERS_TIMEOUT, shortened for the test (30 s by default)
    code = (
        "import sys, vtm_pin.study.executors as e; from vtm_pin.__main__ import entry_point; "
        f"e.WORKERS_TIMEOUT = {wait}; sys.exit(entry_point())"
    )
    address = local_cluster.scheduler_address  # type: ignore[attr-defined]
    args = ["study", str(study), "--out", str(tmp_path / "out"), "--scheduler", address]
    begin = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=wait + START
    )
    assert time.monotonic() - begin < wait + START
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1, done.stderr
    assert f"has no worker (waited {wait:g} s)" in done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("local_cluster", [1], indirect=True)
def test_a_worker_address_is_not_a_scheduler(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], local_cluster: object
) -> None:
    worker = next(iter(local_cluster.scheduler.workers))  # type: ignore[attr-defined]
    assert "is a Dask Worker, not a scheduler" in refusal(tmp_path, capsys, worker)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl to make a certificate")
def test_tls_to_a_port_that_is_not_tls_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("distributed")
    import dask

    key, cert = tmp_path / "key.pem", tmp_path / "cert.pem"
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-keyout", str(key), "-out", str(cert), "-subj", "/CN=localhost"),
        ],
        check=True,
        capture_output=True,
    )
    settings = {
        "distributed.comm.tls.ca-file": str(cert),
        "distributed.comm.tls.client.cert": str(cert),
        "distributed.comm.tls.client.key": str(key),
    }
    with dask.config.set(settings), fake_server(b"\xff" * 64) as address:
        err = refusal(tmp_path, capsys, address.replace("tcp://", "tls://"))
    assert "TLS handshake" in err


# -- the process pool: workers that die with their driver, a prompt Ctrl-C --------------------


def children(pid: int) -> set[int]:
    """Processes whose parent is ``pid`` (from /proc)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_bytes()
            except OSError:  # gone meanwhile
                continue
            if int(stat.rsplit(b")", 1)[1].split()[1]) == pid:
                found.add(int(entry.name))
    return found


def descendants(pid: int) -> set[int]:
    found = children(pid)
    for child in list(found):
        found |= descendants(child)
    return found


def running(pid: int) -> bool:
    """Whether ``pid`` is a process, and not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return False
    return stat.rsplit(b")", 1)[1].split()[0] not in (b"Z", b"X")


#: Seconds a process that has closed its files may take to finish exiting (become a zombie).
EXITING = 2.0


def survivors(pids: set[int]) -> list[str]:
    """The command lines of ``pids`` still running once :data:`EXITING` seconds have passed.

    A process killed closes its files (the pipe's end: ``communicate`` returns) before the
    kernel has made it a zombie; it is given that moment.
    """
    deadline = time.monotonic() + EXITING
    while (alive := [pid for pid in pids if running(pid)]) and time.monotonic() < deadline:
        time.sleep(0.05)
    lines = []
    for pid in alive:
        try:
            lines.append(f"{pid}: {Path(f'/proc/{pid}/cmdline').read_bytes()[:200]!r}")
        except OSError:  # gone meanwhile
            pass
    return lines


def start_pool(tmp_path: Path, engine: str) -> tuple[subprocess.Popen[str], Path, set[int]]:
    """``vtm-pin study`` on 2 workers, once both workers run (its fork server, resource
    tracker and 2 workers are up); returns the process, its output folder, its descendants."""
    out = tmp_path / "out"
    args = command("study", str(write_grid(tmp_path)), "--out", str(out), "--workers", "2")
    process = subprocess.Popen(
        [*args, "--engine", engine], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + START
    while len(tree := descendants(process.pid)) < 4:
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "the workers did not start"
        time.sleep(0.1)
    time.sleep(1.0)  # the workers are under way: their first pieces take seconds
    return process, out, tree | descendants(process.pid)


@needs_proc
@pytest.mark.slow
def test_workers_die_with_a_zombie_driver(tmp_path: Path) -> None:
    """A driver killed outright and not reaped is a zombie: ``kill(pid, 0)`` still succeeds.
    Its workers hold its stdout: ``communicate`` returns only once they are gone."""
    process, out, tree = start_pool(tmp_path, "scalar")
    process.kill()  # not reaped until communicate() has read both pipes to their end
    begin = time.monotonic()
    process.communicate(timeout=ORPHAN_EXIT)
    assert time.monotonic() - begin < ORPHAN_EXIT
    assert process.returncode == -signal.SIGKILL
    assert not survivors(tree)
    assert not (out / "results.parquet").exists()


def interrupt_pool(tmp_path: Path, when: str) -> None:
    process, out, tree = start_pool(tmp_path, "batched")
    if when == "first records stored":
        deadline = time.monotonic() + 120.0
        while not any((out / "cases").glob("*.jsonl")):
            assert process.poll() is None and time.monotonic() < deadline
            time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    begin = time.monotonic()
    _, err = process.communicate(timeout=60.0)
    assert time.monotonic() - begin < INTERRUPT_EXIT, err
    assert process.returncode == EXIT_INTERRUPTED
    assert err.startswith("vtm-pin: interrupted; ") and "run the same command again" in err, err
    assert not survivors(tree)
    assert not (out / "results.parquet").exists()


@needs_proc
@pytest.mark.slow
def test_ctrl_c_ends_the_pool_at_once_while_batches_run(tmp_path: Path) -> None:
    """Each batch of this study takes several seconds: waiting for them would exceed 5 s."""
    interrupt_pool(tmp_path, "workers started")


@needs_proc
@pytest.mark.slow
def test_ctrl_c_after_the_first_records_ends_the_pool_at_once(tmp_path: Path) -> None:
    interrupt_pool(tmp_path, "first records stored")


@needs_proc
def test_a_pool_that_finishes_shuts_down_cleanly() -> None:
    """The normal end is not the interrupt path: every record, no process left behind."""
    pieces = [[1, 2], [3], [4, 5, 6]]
    records = list(executors.on_pool(pieces, _records, 2))
    assert sorted(r["case"] for r in records) == [1, 2, 3, 4, 5, 6]
    workers = {r["pid"] for r in records}
    assert os.getpid() not in workers and not survivors(workers)
    # each worker froze what it imported: the garbage collector's full passes skip it; and
    # set the rarer passes of a study worker
    assert all(r["frozen"] > 10_000 for r in records)
    assert all(r["thresholds"] == executors.WORKER_GC_THRESHOLDS for r in records)
    assert gc.get_threshold() != executors.WORKER_GC_THRESHOLDS  # the driver's are its own


def test_closing_the_records_early_terminates_the_workers() -> None:
    """The generator closed mid-way (what Ctrl-C does): the workers are terminated at once,
    not joined after their pieces."""
    pieces = [[0.0], *[[60.0]] * 3]  # one quick piece; the others would take a minute
    records = executors.on_pool(pieces, _sleep, 2)
    assert next(records) == {"case": 0.0}
    begin = time.monotonic()
    records.close()
    assert time.monotonic() - begin < INTERRUPT_EXIT
    assert not multiprocessing.active_children()  # terminated and joined


def _records(piece: list[int]) -> list[dict]:
    frozen, thresholds = gc.get_freeze_count(), gc.get_threshold()
    return [
        {"case": case, "pid": os.getpid(), "frozen": frozen, "thresholds": thresholds}
        for case in piece
    ]


def _sleep(piece: list[float]) -> list[dict]:
    time.sleep(piece[0])
    return [{"case": piece[0]}]


@needs_proc
def test_the_workers_of_a_bare_pool_die_with_their_zombie_driver(tmp_path: Path) -> None:
    """The same promise as the slow test above, on a pool of sleeping workers."""
    script = tmp_path / "driver.py"
    script.write_text(
        "import sys, time\n"
        "import vtm_pin.study.executors as e\n"
        "def sleep(piece):\n"
        "    time.sleep(piece[0])\n"
        "    return [{'case': piece[0]}]\n"
        "if __name__ == '__main__':\n"
        "    e.PRELOAD = []\n"
        "    for record in e.on_pool([[0.0]] + [[60.0]] * 3, sleep, 2):\n"
        "        print(record, flush=True)\n"
    )
    process = subprocess.Popen(
        [sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert process.stdout is not None
    assert process.stdout.readline().startswith("{'case': 0.0")  # the pool runs
    tree = descendants(process.pid)
    process.kill()
    begin = time.monotonic()
    process.communicate(timeout=ORPHAN_EXIT)
    assert time.monotonic() - begin < ORPHAN_EXIT
    assert len(tree) >= 3
    assert not survivors(tree)


#: A driver without the thread variables that runs a pool and prints what its workers see.
PINNED = """
import json, os
from vtm_pin.study import executors
def work(piece):
    return [{{n: os.environ.get(n) for n in executors.THREAD_VARIABLES}}]
if __name__ == "__main__":
    if {early}:
        executors.start_fork_server()
    seen = list(executors.on_pool([[1], [2], [3], [4]], work, 2))
    print(json.dumps([seen, {{n: os.environ.get(n) for n in executors.THREAD_VARIABLES}}]))
"""


@pytest.mark.skipif(
    "forkserver" not in multiprocessing.get_all_start_methods(), reason="no fork server"
)
@pytest.mark.parametrize("early", [False, True])
def test_pool_workers_run_with_blas_threads_pinned_to_one(tmp_path: Path, early: bool) -> None:
    """The workers fork from a server that started with the variables at 1, whether a pool or
    an early start (the study command's, while it reads the study) started it; the driver's own
    environment is left as it was. (The server used to start at the pool's first task, after
    the driver had put the variables back: the workers had the driver's.)"""
    script = tmp_path / "pinned.py"
    script.write_text(PINNED.format(early=early))
    env = {k: v for k, v in os.environ.items() if k not in executors.THREAD_VARIABLES}
    done = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    seen, driver = yaml.safe_load(done.stdout)
    assert len(seen) == 4
    assert all(worker == dict.fromkeys(executors.THREAD_VARIABLES, "1") for worker in seen)
    assert driver == dict.fromkeys(executors.THREAD_VARIABLES)


WARM = """
import json, sys
from vtm_pin.physics import arm_kernel, body_kernel, chain_dynamics
from vtm_pin.study import executors
def work(piece):
    kernels = (chain_dynamics._compiled, body_kernel._compiled, arm_kernel._compiled,
               arm_kernel._compiled_speeds)
    counts = [len(k().signatures) for k in kernels] if chain_dynamics.runs() else None
    return [{"trimesh": "trimesh" in sys.modules, "numba": "numba" in sys.modules,
             "agg": "matplotlib.backends.backend_agg" in sys.modules,
             "runs": chain_dynamics.runs(), "compiled": counts}]
if __name__ == "__main__":
    seen = list(executors.on_pool([[1], [2]], work, 2))
    print(json.dumps([seen, "trimesh" in sys.modules]))
"""


@pytest.mark.skipif(
    "forkserver" not in multiprocessing.get_all_start_methods(), reason="no fork server"
)
def test_workers_start_with_what_their_first_case_would_load(tmp_path: Path) -> None:
    """The fork server loads trimesh, and Numba's kernels with their one signature each
    (vtm_pin.study.preload), before it forks: a worker's first case no longer pays ~0.6 s for
    them; and Matplotlib, which the study's graphs process (forked from it too) then does not
    import (~0.5 s). The driver loads none of them."""
    script = tmp_path / "warm.py"
    script.write_text(WARM)
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    seen, driver = yaml.safe_load(done.stdout)
    assert len(seen) == 2 and not driver
    for worker in seen:
        assert worker["trimesh"] and worker["agg"]
        if worker["runs"]:  # the fast extra, and Numba can run here
            assert worker["numba"] and worker["compiled"] == [1, 1, 1, 1]


def _set_up(value: str) -> None:
    os.environ["VTM_PIN_TEST_SETUP"] = value


def _set_up_seen(piece: list[Any]) -> list[dict[str, Any]]:
    return [{"seen": os.environ.get("VTM_PIN_TEST_SETUP"), "pid": os.getpid()} for _ in piece]


def test_a_pools_set_up_runs_in_each_worker_before_its_pieces() -> None:
    """on_pool's ``setup`` (a study hands its workers the driver's robot models this way)."""
    setup = functools.partial(_set_up, "models kept")
    records = list(executors.on_pool([[1], [2], [3], [4]], _set_up_seen, 2, setup=setup))
    assert [r["seen"] for r in records] == ["models kept"] * 4
    assert os.environ.get("VTM_PIN_TEST_SETUP") is None  # not the driver's


def test_a_pooled_study_is_read_from_the_command_line_before_the_cli_is_imported(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`vtm-pin study` on local workers starts the fork server before the CLI's imports;
    anything else, or anything the guess cannot read, leaves it to the command."""
    from vtm_pin import __main__ as entry

    monkeypatch.setattr(entry, "default_workers", lambda: 2)
    assert entry.pooled_study(["study", "s.yaml"])
    assert entry.pooled_study(["study", "s.yaml", "--workers", "3", "--engine", "scalar"])
    assert entry.pooled_study(["study", "--work=2", "s.yaml"])  # argparse's abbreviations
    for argv in (
        [],
        ["run", "s.yaml"],
        ["program", "p.yaml"],
        ["study", "s.yaml", "--workers", "1"],
        ["study", "s.yaml", "--workers=1"],
        ["study", "s.yaml", "--scheduler", "tcp://127.0.0.1:8786"],
        ["study", "s.yaml", "--workers", "two"],  # the command says what is wrong
        ["study", "--help"],
    ):
        assert not entry.pooled_study(argv), argv
    monkeypatch.setattr(entry, "default_workers", lambda: 1)
    assert not entry.pooled_study(["study", "s.yaml"])


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def test_a_background_process_gives_its_result_and_is_ended_if_left_early() -> None:
    """`in_background`: the function runs in another process; a caller that leaves early (an
    error) does not wait for it: the process is terminated at once."""
    with executors.in_background(_pid_after, 0.0) as future:
        assert future.result(timeout=120) != os.getpid()
    begin = time.monotonic()
    with pytest.raises(RuntimeError), executors.in_background(_pid_after, 60.0) as future:
        time.sleep(0.5)  # it has started
        raise RuntimeError("the caller failed")
    assert time.monotonic() - begin < 30.0  # not the 60 s it would have taken
