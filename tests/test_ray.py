"""``--executor ray`` on a local Ray instance: the same rows as the local executor, and the same
fault handling (a hanging plugin's evaluation times out as one failure row). Skipped where Ray
is not installed (``pip install 'lwbench[ray]'``)."""

from __future__ import annotations

import importlib.util
import os
import sqlite3
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed here")

TESTS = Path(__file__).parent


@pytest.fixture(scope="module")
def ray_cluster():
    import ray

    # Ray's workers inherit this environment: they find the misbehaving test plugins too.
    saved = {k: os.environ.get(k) for k in ("PYTHONPATH", "LWBENCH_PLUGINS")}
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(TESTS), saved["PYTHONPATH"]]))
    os.environ["LWBENCH_PLUGINS"] = "_hostile_plugins"
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    try:
        yield ray
    finally:
        ray.shutdown()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _rows(path: Path) -> dict:
    import json

    conn = sqlite3.connect(path)
    rows = conn.execute("SELECT key, status, error, metrics FROM results").fetchall()
    conn.close()
    return {k: (s, (e or "").split(":")[0], {m: v for m, v in json.loads(x).items() if not m.endswith(("_ms", "_mb"))})
            for k, s, e, x in rows}


def _run(tmp_path, kitti_folder, name, codecs, **kw):
    from lwbench.registry import new_registry
    from lwbench.run import DatasetRequest, RunRequest, Study

    reg = new_registry()
    request = RunRequest(datasets=(DatasetRequest("kitti", {"path": str(kitti_folder)}),),
                         codecs=tuple(n for n, _ in codecs), sweeps={n: p for n, p in codecs},
                         sequence_metrics=False, store=tmp_path / f"{name}.sqlite", **kw)
    (summary,) = Study.prepare(request, reg).run().summaries
    return summary, _rows(tmp_path / f"{name}.sqlite")


@pytest.mark.heavy
def test_ray_and_local_executors_store_identical_rows(ray_cluster, tmp_path, kitti_folder):
    codecs = [("raw", {}), ("random", {"ratio": ["0.2"]}), ("voxel", {}), ("rangeimage", {})]
    _, on_ray = _run(tmp_path, kitti_folder, "ray", codecs, executor="ray")
    _, local = _run(tmp_path, kitti_folder, "local", codecs, isolate=True)
    assert len(on_ray) == 12 and on_ray == local


@pytest.mark.heavy
def test_a_hanging_plugin_times_out_on_ray_as_one_failure_row(ray_cluster, tmp_path, kitti_folder):
    summary, rows = _run(tmp_path, kitti_folder, "hang", [("test-hang", {}), ("raw", {})], executor="ray",
                         timeout_s=40)  # the limit counts from submission: a Ray worker's start-up on a
    # loaded 2-core machine took more than 10 s (every row timed out under load)
    failed = [v for v in rows.values() if v[0] == "failed"]
    assert summary.evaluated == 6 and len(failed) == 1 and failed[0][1] == "WorkerError"
    assert len([v for v in rows.values() if v[0] == "ok"]) == 5
