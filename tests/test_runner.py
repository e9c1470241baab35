"""The runner end to end: rows, failures, resume, cache hits, workers."""

from __future__ import annotations

import types

import numpy as np
import pytest

from lwbench import Dataset, Frame, Param, RepresentationCodec, get_sensor, hookimpl
from lwbench.registry import new_registry
from lwbench.results.leaderboard import build_leaderboard
from lwbench.results.store import ResultStore
from lwbench.run import DatasetSpec, RunPlan, expand_codec_configs
from lwbench.run.runner import Runner  # the internal under test

CALLS: list[int] = []


class CountingCodec(RepresentationCodec):
    """Raw codec that counts its encodes and fails on frames listed in ``fail_on``."""

    name = "counting"
    params = (Param("fail_on", "int", -1),)

    def encode(self, frame: Frame) -> bytes:
        CALLS.append(frame.index)
        if frame.index == self.config["fail_on"]:
            raise RuntimeError("boom on purpose")
        return self.make_payload(frame, {"n": len(frame)}, frame.points.tobytes())

    def decode(self, data: bytes) -> np.ndarray:
        return np.frombuffer(self.read_payload(data).body, np.float32).reshape(-1, 3)


class BadDecodeCodec(CountingCodec):
    name = "nan_decoder"

    def decode(self, data: bytes) -> np.ndarray:
        out = super().decode(data).copy()
        out[0, 0] = np.nan
        return out


class TinyDataset(Dataset):
    name = "tiny"
    params = (Param("frames", "int", 4), Param("empty_frame", "int", -1))

    def __len__(self) -> int:
        return self.config["frames"]

    @property
    def has_poses(self) -> bool:
        return False

    def frame(self, index: int) -> Frame:
        rng = np.random.default_rng(index)
        n = 0 if index == self.config["empty_frame"] else 2000
        pts = rng.uniform(-8, 8, (n, 3)).astype(np.float32)
        return Frame(pts, get_sensor("vlp16"), index=index)


@pytest.fixture
def registry():
    reg = new_registry()
    plugin = types.SimpleNamespace(
        lwbench_codecs=hookimpl(lambda: [CountingCodec, BadDecodeCodec]),
        lwbench_datasets=hookimpl(lambda: [TinyDataset]),
    )
    assert reg.register(plugin, "test-plugin")
    CALLS.clear()
    return reg


def _runner(reg, store, codecs, **kw):
    spec = DatasetSpec("tiny", kw.pop("dataset_params", {}))
    configs = [c for name, values in codecs for c in expand_codec_configs(reg.codec(name), values, 0)]
    plan = RunPlan(spec, tuple(configs), metric_params=kw.pop("metric_params", {}))
    return Runner(store, plan, registry=reg, **kw)


def test_rows_for_every_frame_and_config_with_all_core_metrics(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        summary = _runner(registry, store, [("raw", {}), ("random", {"ratio": ["0.1", "0.5"]})]).run()
        assert summary.evaluated == 12 and summary.failed == 0
        rows = list(store.rows())
        assert len(rows) == 12
        ids = set(registry.metric_ids()) - {"select_ms", "peak_mb"}
        for r in rows:
            assert ids <= {k for k, v in r.metrics.items() if v is not None}, r.codec
            assert r.versions["numpy"] and r.machine and r.seed == 0
        entries = build_leaderboard(store, sort="ratio", flagged_last=False)
        assert [e.codec for e in entries] == ["random", "random", "raw"]
        assert entries[0].value("ratio") > entries[1].value("ratio") > 1
        raw = entries[2]
        assert raw.value("range_rmsd") == 0 and raw.value("coverage") == 1
        # The quality guard: keeping 10 % or 50 % of the returns is below the coverage floor,
        # so by default those configurations are flagged and rank after the unflagged raw.
        guarded = build_leaderboard(store, sort="ratio")
        assert [e.codec for e in guarded] == ["raw", "random", "random"]
        assert guarded[0].flags == [] and all(e.flags == ["low_coverage"] for e in guarded[1:])
        loose = build_leaderboard(store, sort="ratio", min_coverage=0.05)
        assert [e.codec for e in loose] == ["random", "random", "raw"]


def test_a_codec_that_raises_is_recorded_and_the_run_goes_on(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        summary = _runner(registry, store, [("counting", {"fail_on": ["2"]}), ("nan_decoder", {})],
                          dataset_params={"empty_frame": 3}).run()
        rows = {(r.codec, r.frame): r for r in store.rows()}
        assert len(rows) == 8
        assert rows[("counting", 2)].status == "failed"
        assert "boom on purpose" in rows[("counting", 2)].error
        assert rows[("counting", 1)].status == "ok"
        assert "empty" in rows[("counting", 3)].error
        assert all(rows[("nan_decoder", i)].status == "failed" for i in range(4))
        assert "NaN" in rows[("nan_decoder", 0)].error
        assert summary.failed == 6
        entry = next(e for e in build_leaderboard(store) if e.codec == "counting")
        assert (entry.frames, entry.failures) == (2, 2)


def test_interrupted_run_resumes_without_recomputing_a_row(registry, tmp_path):
    path = tmp_path / "r.sqlite"

    def stop_after_three(progress):
        if progress.done == 3:
            raise KeyboardInterrupt

    with ResultStore(path) as store:
        summary = _runner(registry, store, [("counting", {})], dataset_params={"frames": 6}).run(stop_after_three)
        assert summary.interrupted and store.count() == 3
    warm_and_timed = list(CALLS)
    assert sorted(set(warm_and_timed)) == [0, 1, 2]
    CALLS.clear()
    with ResultStore(path) as store:  # a new process would see the same file
        summary = _runner(registry, store, [("counting", {})], dataset_params={"frames": 6}).run()
        assert summary.skipped == 3 and summary.evaluated == 3 and store.count() == 6
    assert sorted(set(CALLS)) == [3, 4, 5]  # frames 0-2 were not encoded again
    CALLS.clear()
    with ResultStore(path) as store:
        summary = _runner(registry, store, [("counting", {})], dataset_params={"frames": 6}).run()
    assert summary.evaluated == 0 and summary.skipped == 6 and CALLS == []


def test_warm_up_is_timed_apart_from_the_steady_state(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        _runner(registry, store, [("raw", {})]).run()
        rows = sorted(store.rows(), key=lambda r: r.frame)
        assert "warmup_encode_ms" in rows[0].extra
        assert all("warmup_encode_ms" not in r.extra for r in rows[1:])


def test_failed_rows_are_retried_only_when_asked(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        _runner(registry, store, [("counting", {"fail_on": ["1"]})]).run()
        CALLS.clear()
        assert _runner(registry, store, [("counting", {"fail_on": ["1"]})]).run().evaluated == 0
        again = _runner(registry, store, [("counting", {"fail_on": ["1"]})], retry_failed=True).run()
        assert again.evaluated == 1 and 1 in CALLS


def test_same_command_gives_the_same_table(registry, tmp_path):
    tables = []
    for name in ("a", "b"):
        with ResultStore(tmp_path / f"{name}.sqlite") as store:
            _runner(registry, store, [("random", {"ratio": ["0.2"]})]).run()
            tables.append({r.frame: {k: v for k, v in r.metrics.items() if not k.endswith(("_ms", "_mb"))}
                           for r in store.rows()})
    assert tables[0] == tables[1]


@pytest.mark.heavy
def test_parallel_workers_give_the_same_rows_as_one_process(tmp_path):
    from lwbench.registry import get_registry

    reg = get_registry()
    spec = DatasetSpec("files", {"path": str(tmp_path / "scans")})
    (tmp_path / "scans").mkdir()
    rng = np.random.default_rng(0)
    for i in range(4):
        pts = rng.uniform(-5, 5, (3000, 3)).astype("<f4")
        np.column_stack([pts, np.zeros(3000, "<f4")]).tofile(tmp_path / "scans" / f"{i:06d}.bin")
    configs = expand_codec_configs(reg.codec("random"), {"ratio": ["0.3"]}, 0)
    out = []
    for workers in (1, 2):
        with ResultStore(tmp_path / f"w{workers}.sqlite") as store:
            assert Runner(store, RunPlan(spec, tuple(configs)), workers=workers, registry=reg).run().evaluated == 4
            out.append({r.frame: r.metrics["chamfer"] for r in store.rows()})
    assert out[0] == out[1]


def test_a_changed_metric_parameter_recomputes_and_is_never_averaged_in(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        first = _runner(registry, store, [("counting", {})]).run()
        assert first.evaluated == 4
        CALLS.clear()
        # Same codec, same frames, but scored with another PSNR peak: a different key.
        again = _runner(registry, store, [("counting", {})], metric_params={"geometry": {"peak": 59.7}}).run()
        assert again.evaluated == 4 and again.skipped == 0 and CALLS
        assert store.count() == 8
        (entry,) = [e for e in build_leaderboard(store) if e.codec == "counting"]
        # Only the newest scoring counts; the rows scored the old way are reported, not mixed in.
        assert entry.frames == 4 and entry.stale == 4


def test_a_new_plugin_release_is_not_served_its_predecessors_rows(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        assert _runner(registry, store, [("counting", {})]).run().evaluated == 4
        assert _runner(registry, store, [("counting", {})]).run().evaluated == 0
        registry.plugin_versions[("codec", "counting")] = "test-plugin==0.0.2"
        assert _runner(registry, store, [("counting", {})]).run().evaluated == 4


def test_force_recomputes_on_purpose(registry, tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        _runner(registry, store, [("counting", {})]).run()
        CALLS.clear()
        forced = _runner(registry, store, [("counting", {})], force=True).run()
        assert forced.evaluated == 4 and sorted(set(CALLS)) == [0, 1, 2, 3] and store.count() == 4


def test_unknown_metric_parameters_are_refused(registry):
    from lwbench.errors import ParameterError, PluginError

    with pytest.raises(PluginError, match="unknown metric"):
        registry.check_metric_params({"nope": {"x": "1"}})
    with pytest.raises(ParameterError, match="unknown parameter"):
        registry.check_metric_params({"geometry": {"peek": "1"}})
