"""Runs that survive faults: plugins that hang, segfault, exit or leak; SIGKILLed runs that
resume; two runs writing one store at once. Each drives a real ``lwbench run`` subprocess, with
the misbehaving test plugins of ``_hostile_plugins`` loaded through ``LWBENCH_PLUGINS``.

Every test also checks that no process of the run outlives it: the subprocess' environment
carries a tag, and ``/proc`` is searched for it afterwards.
"""

from __future__ import annotations

import os
import random
import signal
import sqlite3
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from lwbench import get_sensor
from lwbench.io import write_kitti_sequence
from lwbench.testing import room_scan

TESTS = Path(__file__).parent
TIMINGS = ("_ms", "peak_mb")


@pytest.fixture(scope="module")
def scans(tmp_path_factory) -> Path:
    frames = [room_scan(get_sensor("vlp16"), seed=5, index=i, dropout=0.05) for i in range(6)]
    return write_kitti_sequence(frames, tmp_path_factory.mktemp("faults") / "seq")


def _env(tag: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["LWBENCH_PLUGINS"] = "_hostile_plugins"
    env["LWBENCH_FAULT_TEST"] = tag
    return env


def _lwbench(*args: str) -> list[str]:
    return [sys.executable, "-c", "from lwbench.cli import main; main()", *args]


def _run(tag: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(_lwbench(*args), env=_env(tag), capture_output=True, text=True, timeout=timeout)


def _survivors(tag: str, wait_s: float = 10.0) -> list[int]:
    """Processes whose environment carries ``tag`` (after up to ``wait_s`` for them to go)."""
    needle = f"LWBENCH_FAULT_TEST={tag}".encode()
    deadline = time.monotonic() + wait_s
    while True:
        found = []
        for pid in os.listdir("/proc"):
            if not pid.isdigit() or int(pid) == os.getpid():
                continue
            try:
                if needle in Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"):
                    found.append(int(pid))
            except OSError:
                continue
        if not found or time.monotonic() > deadline:
            return found
        time.sleep(0.2)


def _rows(store: Path) -> dict[str, tuple]:
    """Every row by key: status, error kind and the metrics but timings -- what must not
    depend on how the run was interrupted."""
    conn = sqlite3.connect(store)
    try:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        rows = conn.execute("SELECT key, status, error, metrics FROM results").fetchall()
        (n,) = conn.execute("SELECT COUNT(DISTINCT key) FROM results").fetchone()
    finally:
        conn.close()
    assert n == len(rows)  # no duplicates
    import json

    out = {}
    for key, status, error, metrics in rows:
        values = {k: v for k, v in json.loads(metrics).items() if not k.endswith(TIMINGS)}
        out[key] = (status, (error or "").split(":")[0], tuple(sorted(values.items())))
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and signals as on Linux")
@pytest.mark.parametrize("codec, why, workers", [
    ("test-hang", "timed out after 10 s", 2),
    ("test-segfault", "SIGSEGV", 1),
    ("test-exit", "exited with status 3", 2),
    pytest.param("test-hang", "timed out after 10 s", 1, marks=pytest.mark.slow),
    pytest.param("test-segfault", "SIGSEGV", 2, marks=pytest.mark.slow),
    pytest.param("test-exit", "exited with status 3", 1, marks=pytest.mark.slow),
])
@pytest.mark.heavy
def test_a_plugin_that_hangs_or_dies_costs_one_failure_row(scans, tmp_path, codec, why, workers):
    tag = uuid.uuid4().hex
    store = tmp_path / "r.sqlite"
    proc = _run(tag, "run", "--dataset", str(scans), "--codec", codec, "--codec", "raw", "--frames", "3",
                "--timeout", "10", "--workers", str(workers), "--store", str(store), "--no-sequence-metrics")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _survivors(tag) == []
    conn = sqlite3.connect(store)
    rows = conn.execute("SELECT codec, frame, status, error FROM results").fetchall()
    conn.close()
    failed = [(c, f) for c, f, s, _ in rows if s == "failed"]
    assert failed == [(codec, 1)], rows
    assert sorted((c, f) for c, f, s, _ in rows if s == "ok") == sorted(
        [("raw", 0), ("raw", 1), ("raw", 2), (codec, 0), (codec, 2)])
    (error,) = [e for c, f, s, e in rows if s == "failed"]
    assert error.startswith("WorkerError") and why in error


@pytest.mark.heavy
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_DATA as on Linux")
def test_a_leaking_plugin_meets_the_memory_ceiling(scans, tmp_path):
    tag = uuid.uuid4().hex
    store = tmp_path / "r.sqlite"
    proc = _run(tag, "run", "--dataset", str(scans), "--codec", "test-leak", "--codec", "raw", "--frames", "3",
                "--memory-limit", "400", "--store", str(store), "--no-sequence-metrics")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _survivors(tag) == []
    conn = sqlite3.connect(store)
    rows = conn.execute("SELECT codec, frame, status, error FROM results").fetchall()
    conn.close()
    assert [(c, f) for c, f, s, _ in rows if s == "failed"] == [("test-leak", 1)]
    assert len([r for r in rows if r[2] == "ok"]) == 5  # the recycled worker went on


@pytest.mark.heavy
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and signals as on Linux")
def test_sigkill_at_random_moments_then_resume_gives_the_uninterrupted_rows(scans, tmp_path):
    args = ["--dataset", str(scans), "--codec", "raw", "--codec", "rangeimage", "--codec", "random",
            "--codec", "draco", "--workers", "2"]  # killed with two workers busy: both must go too
    tag = uuid.uuid4().hex
    clean = tmp_path / "clean.sqlite"
    t0 = time.monotonic()
    assert _run(tag, "run", *args, "--store", str(clean)).returncode == 0
    full = time.monotonic() - t0
    reference = _rows(clean)
    assert len(reference) == 24  # 6 frames x 4 codecs (no poses: no sequence rows)

    store = tmp_path / "killed.sqlite"
    rng = random.Random(16)  # seeded: the same kill moments on every run of the test
    kills = 0
    for _ in range(3):
        proc = subprocess.Popen(_lwbench("run", *args, "--store", str(store)), env=_env(tag),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.3, 0.9 * full))
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.wait(60)
        assert _survivors(tag) == []  # the workers went with it
    assert kills >= 2
    assert _run(tag, "run", *args, "--store", str(store)).returncode == 0
    assert _rows(store) == reference


@pytest.mark.heavy
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc as on Linux")
def test_two_runs_writing_one_store_at_once(scans, tmp_path):
    tag = uuid.uuid4().hex
    one = ["--dataset", str(scans), "--codec", "raw", "--codec", "voxel", "--in-process"]
    two = ["--dataset", str(scans), "--codec", "raw", "--codec", "random", "--in-process"]
    shared = tmp_path / "shared.sqlite"
    procs = [subprocess.Popen(_lwbench("run", *a, "--store", str(shared)), env=_env(tag), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True) for a in (one, two)]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-3000:]
    apart = tmp_path / "apart.sqlite"
    for a in (one, two):
        assert _run(tag, "run", *a, "--store", str(apart)).returncode == 0
    assert _rows(shared) == _rows(apart)


@pytest.mark.heavy
def test_isolated_and_in_process_runs_store_the_same_rows(scans, tmp_path):
    tag = uuid.uuid4().hex
    args = ["--dataset", str(scans), "--codec", "raw", "--codec", "voxel", "--codec", "rangeimage", "--frames", "3"]
    assert _run(tag, "run", *args, "--in-process", "--store", str(tmp_path / "a.sqlite")).returncode == 0
    assert _run(tag, "run", *args, "--store", str(tmp_path / "b.sqlite")).returncode == 0
    assert _rows(tmp_path / "a.sqlite") == _rows(tmp_path / "b.sqlite")


def test_ctrl_c_is_the_driver_s_to_answer_not_a_worker_s():
    """Issue 33: Ctrl-C printed a traceback from every idle worker. A worker ignores SIGINT (the
    terminal sends it to the whole group); the driver stores what finished and stops them."""
    import os
    import signal
    import time

    from lwbench.registry import get_registry
    from lwbench.run.execute import ProcessExecutor

    with ProcessExecutor(get_registry().recipe(), workers=1, preload=()) as executor:
        executor._ensure(1)
        box = executor._slots[0].box
        os.kill(box.proc.pid, signal.SIGINT)
        time.sleep(1.0)
        assert box.alive
