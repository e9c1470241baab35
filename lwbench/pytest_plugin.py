"""lwbench's pytest plugin: quality and speed gates a team writes in its own tests.

Registered through the ``pytest11`` entry point, so installing lwbench makes it available in
any project. In a test file::

    def test_our_codec_keeps_its_promises(lwbench_gate):
        lwbench_gate("vsgp", params={"num_inducing": 500}, dataset="sim",
                     dataset_params={"scene": "tunnel"}, frames=10,
                     max_range_rmsd=0.095, min_coverage=0.99, min_ratio=90)

    def test_our_codec_is_not_slower(lwbench_benchmark):
        lwbench_benchmark("draco", dataset="sim", frames=5)   # pytest-benchmark, quality in extra_info

``lwbench_gate(codec, **run_options, **thresholds)`` runs the configuration (reusing stored
results) and checks ``min_<id>`` / ``max_<id>`` thresholds on any metric id; a failure says
codec, parameters, dataset, metric, measured vs required, frames and the worst frame. It
returns the :class:`lwbench.gates.GateResult` for further asserts. ``codec`` may be a Codec
class that is not installed as a plugin (the codec under development).

Options: ``--lwbench-store PATH`` (or ini ``lwbench_store``) names a results store to reuse and
extend -- e.g. the one an earlier CI step wrote with ``lwbench run`` -- instead of a fresh one
per session.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

_RUN_OPTIONS = ("params", "dataset", "dataset_params", "frames", "seed", "metric_params", "sequence_metrics")


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("lwbench", "lwbench gates")
    group.addoption("--lwbench-store", default=None, help="results store the lwbench gates reuse and extend")
    parser.addini("lwbench_store", "results store the lwbench gates reuse and extend", default="")


@pytest.fixture(scope="session")
def lwbench_store(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The results store gates read and write (one per session unless configured)."""
    given = request.config.getoption("--lwbench-store") or request.config.getini("lwbench_store")
    return Path(given) if given else tmp_path_factory.mktemp("lwbench") / "gates.sqlite"


def _split(kwargs: dict[str, Any]) -> tuple[dict[str, Any], dict[str, float]]:
    run = {k: v for k, v in kwargs.items() if k in _RUN_OPTIONS}
    thresholds = {k: v for k, v in kwargs.items() if k not in _RUN_OPTIONS}
    for name in thresholds:
        if not name.startswith(("min_", "max_")):
            raise TypeError(f"lwbench_gate: unknown option {name!r} (run options: {', '.join(_RUN_OPTIONS)}; "
                            "thresholds: min_<metric id>=, max_<metric id>=)")
    return run, thresholds


@pytest.fixture
def lwbench_gate(lwbench_store: Path) -> Callable[..., Any]:
    """``lwbench_gate(codec, **run_options, **thresholds) -> GateResult``."""
    from lwbench.gates import parse_threshold, run_gate
    from lwbench.metric import SequenceMetric

    def gate(codec: str | type, **kwargs: Any):
        __tracebackhide__ = True
        run, thresholds = _split(kwargs)
        if "sequence_metrics" not in run:
            # Localization and occupancy cost seconds: run them only when a threshold needs them.
            from lwbench.registry import get_registry

            reg = get_registry()
            seq_ids = {str(i) for m in reg.sequence_metrics.values() if issubclass(m, SequenceMetric) for i in m.ids}
            run["sequence_metrics"] = any(parse_threshold(t, reg)[1] in seq_ids for t in thresholds)
        return run_gate(codec, store=lwbench_store, **run).require(**thresholds)

    return gate


@pytest.fixture
def lwbench_benchmark(request: pytest.FixtureRequest, lwbench_store: Path) -> Callable[..., Any]:
    """``lwbench_benchmark(codec, **run_options)``: time encode + decode of the gated frames with
    pytest-benchmark (so ``--benchmark-compare-fail=mean:10%`` gates speed against a saved
    baseline, never against absolute times), with the configuration's quality figures in the
    benchmark JSON's ``extra_info``."""
    try:
        benchmark = request.getfixturevalue("benchmark")
    except pytest.FixtureLookupError:
        pytest.fail("lwbench_benchmark needs pytest-benchmark: pip install pytest-benchmark")

    def bench(codec: str | type, rounds: int = 5, **kwargs: Any):
        from lwbench.gates import gate_plan, run_gate
        from lwbench.run.evaluate import encode_decode

        run, thresholds = _split(kwargs)
        result = run_gate(codec, store=lwbench_store, **run).require(**thresholds)
        reg, plan = gate_plan(codec, **run)
        dataset = plan.dataset.build(reg)
        frames = [dataset[i] for i in plan.frame_indices(dataset)]
        (config,) = plan.configs
        cls = reg.codec(config.name)
        encoder = cls(**config.params)
        encode_decode(cls, config, encoder, frames[0])  # warm-up, outside the timing

        def once() -> None:
            for f in frames:
                encode_decode(cls, config, encoder, f)

        benchmark.extra_info.update({
            "codec": result.label,
            "dataset": result.dataset,
            "frames": len(frames),
            # The board's default columns (what each metric declares default), where measured.
            **{k: v for k in reg.default_columns() if (v := result.value(k)) is not None},
        })
        benchmark.pedantic(once, rounds=rounds, iterations=1)
        return result

    return bench
