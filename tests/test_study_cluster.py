"""A study on a real Dask cluster: a ``dask scheduler`` and two ``dask worker`` processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest
import yaml

pytest.importorskip("distributed")

from vtm_pin.study.cases import load_study
from vtm_pin.study.runner import run_study

DASK = str(Path(sys.executable).with_name("dask"))
#: Seconds a cluster may take to come up on a loaded 2-core machine.
START_TIMEOUT = 90.0


@pytest.fixture()
def scheduler(tmp_path: Path) -> Iterator[str]:
    """The address of a local cluster: one scheduler and two single-threaded workers."""
    file = tmp_path / "scheduler.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
    processes = [
        subprocess.Popen(
            [
                DASK,
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(file),
            ],
            **quiet,
        )
    ]
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while not file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(file.read_text())["address"]
        for _ in range(2):
            processes.append(
                subprocess.Popen(
                    [
                        DASK,
                        "worker",
                        address,
                        "--nthreads",
                        "1",
                        "--nworkers",
                        "1",
                        "--no-dashboard",
                        "--local-directory",
                        str(tmp_path / "workers"),
                    ],
                    **quiet,
                )
            )
        from distributed import Client

        with Client(address, timeout=START_TIMEOUT) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT)
        yield address
    finally:
        for process in processes[::-1]:
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()


@pytest.mark.slow  # ~25 s with the local Dask cluster's start and stop
def test_a_cluster_run_equals_the_local_run(tmp_path: Path, scheduler: str) -> None:
    path = tmp_path / "study.yaml"
    vary = {"joint": ["shoulder_lift_joint", "elbow_joint"], "speed": [0.5, 1.0], "duration": [0.9]}
    path.write_text(yaml.safe_dump({"scenario": "ur10_annex_b", "vary": vary}, sort_keys=False))
    study = load_study(path)
    local = run_study(study, tmp_path / "local", workers=1)
    remote = run_study(study, tmp_path / "remote", scheduler=scheduler)
    assert remote.computed == 4 and remote.summary["executor"].startswith("dask")
    drop = ["wall_time"]  # machine timing, not physics
    pd.testing.assert_frame_equal(remote.table.drop(columns=drop), local.table.drop(columns=drop))
    assert pd.read_parquet(tmp_path / "remote" / "results.parquet")["case"].is_unique
