"""``lwbench run --config``: a committed TOML file runs datasets x codecs x grids x seeds."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from lwbench.cli import app


def _invoke(*args: str):
    return CliRunner().invoke(app, list(args), catch_exceptions=False)


@pytest.mark.heavy
def test_a_run_file_runs_every_grid_point_and_seed(tmp_path, kitti_folder):
    store = tmp_path / "rd.sqlite"
    (tmp_path / "study.toml").write_text(f"""
store = "{store}"
frames = 2
seeds = [0, 1]

[[dataset]]
name = "{kitti_folder}"

[[codec]]
name = "raw"

[[codec]]
name = "random"
params = {{ ratio = [0.1, 0.3] }}
""")
    res = _invoke("run", "--config", str(tmp_path / "study.toml"))
    assert res.exit_code == 0, res.output
    board = json.loads(_invoke("leaderboard", "--store", str(store), "--format", "json").stdout)
    configs = sorted((d["codec"], d["params"].get("ratio"), d["params"].get("seed")) for d in board)
    assert configs == [("random", 0.1, 0), ("random", 0.1, 1), ("random", 0.3, 0), ("random", 0.3, 1),
                       ("raw", None, None)]
    assert all(d["frames"] == 2 for d in board if d["codec"] == "random")


def test_a_run_file_with_an_unknown_key_is_refused(tmp_path):
    (tmp_path / "bad.toml").write_text('frame = 3\n[[dataset]]\nname = "sim"\n[[codec]]\nname = "raw"\n')
    res = _invoke("run", "--config", str(tmp_path / "bad.toml"))
    assert res.exit_code == 2 and "unknown key(s) frame" in res.output and "frames" in res.output


def test_the_shipped_study_file_plans(tmp_path):
    from pathlib import Path

    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    study = Path(__file__).resolve().parents[1] / "examples" / "runs" / "rd_tunnel.toml"
    (plan,) = read_run_file(study).plans(get_registry())
    assert len(plan.configs) == 1 + 4 + 8 + 5 + 5 + 4 + 4 + 3 * 4


def test_a_codec_named_twice_runs_the_union_of_its_grids_and_a_dataset_sets_its_frames(tmp_path):
    """Issue 34, item 4: rangeimage's step swept and its lossless mode with both refine settings
    (as examples/runs/codecs_rd.toml), one dataset at 5 frames and another at 1, in one run file."""
    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    path = tmp_path / "rd.toml"
    path.write_text(
        '[[dataset]]\nname = "sim"\nparams = { scene = "tunnel" }\nframes = 5\n'
        '[[dataset]]\nname = "sim"\nparams = { scene = "urban" }\nframes = 1\n'
        '[[codec]]\nname = "rangeimage"\nparams = { step = [0.05, 0.02] }\n'
        '[[codec]]\nname = "rangeimage"\nparams = { mode = "lossless", refine = ["beam", "none"] }\n'
        '[[codec]]\nname = "raw"\n'
    )
    tunnel, urban = read_run_file(path).plans(get_registry())
    assert (tunnel.frames, urban.frames) == (5, 1)
    ri = [c.params for c in tunnel.configs if c.name == "rangeimage"]
    assert sorted(p["step"] for p in ri if p["mode"] != "lossless") == [0.02, 0.05]
    assert sorted(p["refine"] for p in ri if p["mode"] == "lossless") == ["beam", "none"]
    assert len(ri) == 4 and [c.name for c in tunnel.configs].count("raw") == 1


def test_a_dataset_frames_that_is_not_a_positive_integer_is_refused(tmp_path):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    path = tmp_path / "bad.toml"
    path.write_text('[[dataset]]\nname = "sim"\nframes = 0\n[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError, match="frames must be a positive integer"):
        read_run_file(path)


# -- issue 34, item 4: timeout, per-dataset metric_params, ${VAR} in dataset paths -----------------


def _run_file(tmp_path, text: str, name: str = "study.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


_SIM_RAW = '[[dataset]]\nname = "sim"\n[[codec]]\nname = "raw"\n'


class _Planned(Exception):
    """Raised in place of planning: carries the request ``lwbench run`` built."""

    def __init__(self, request) -> None:
        super().__init__("planned")
        self.request = request


def _request_of_cli(monkeypatch, *args: str):
    """The RunRequest ``lwbench run ARGS`` would plan and run (nothing is run)."""
    from lwbench.run import Study

    def prepare(cls, request, registry):
        raise _Planned(request)

    monkeypatch.setattr(Study, "prepare", classmethod(prepare))
    with pytest.raises(_Planned) as planned:
        _invoke("run", *args)
    return planned.value.request


def test_a_run_files_timeout_reaches_the_request_and_the_command_line_overrides_it(tmp_path, monkeypatch):
    from lwbench.run import DEFAULT_TIMEOUT_S
    from lwbench.run.config import read_run_file

    timed = _run_file(tmp_path, "timeout = 600\n" + _SIM_RAW)
    unlimited = _run_file(tmp_path, "timeout = 0\n" + _SIM_RAW, "unlimited.toml")
    silent = _run_file(tmp_path, _SIM_RAW, "silent.toml")
    assert read_run_file(timed).timeout_s == 600
    assert read_run_file(unlimited).timeout_s is None  # 0: no limit, as --timeout 0
    assert read_run_file(silent).timeout_s == DEFAULT_TIMEOUT_S

    assert _request_of_cli(monkeypatch, "--config", str(timed)).timeout_s == 600  # the file's, not the CLI default
    assert _request_of_cli(monkeypatch, "--config", str(timed), "--timeout", "30").timeout_s == 30
    assert _request_of_cli(monkeypatch, "--config", str(timed), "--timeout", "0").timeout_s is None
    assert _request_of_cli(monkeypatch, "--config", str(unlimited), "--timeout", "45").timeout_s == 45
    assert _request_of_cli(monkeypatch, "--config", str(silent)).timeout_s == DEFAULT_TIMEOUT_S
    # without a run file: the default, or the flag
    assert _request_of_cli(monkeypatch, "--dataset", "sim", "--codec", "raw").timeout_s == DEFAULT_TIMEOUT_S
    assert _request_of_cli(monkeypatch, "--dataset", "sim", "--codec", "raw", "--timeout", "0").timeout_s is None


@pytest.mark.parametrize("value", ["-1", '"600"', "true", "inf", "nan"])
def test_a_timeout_that_is_not_seconds_is_refused(tmp_path, value):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    path = _run_file(tmp_path, f"timeout = {value}\n" + _SIM_RAW)
    with pytest.raises(ParameterError, match=r"study\.toml: timeout must be seconds per evaluation"):
        read_run_file(path)


def test_a_datasets_metric_params_reach_only_that_datasets_plans(tmp_path):
    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    path = _run_file(tmp_path, """
seeds = [0, 1]
[metric_params]
floor = { sigma = 0.02 }
geometry = { peak = 59.7 }

[[dataset]]
name = "sim"
params = { scene = "tunnel" }
metric_params = { floor = { sigma = 0.01 } }

[[dataset]]
name = "sim"
params = { scene = "urban" }

[[dataset]]
name = "sim"
params = { scene = "indoor" }
metric_params = { ranges = { } , geometry = { peak = 20.0 } }

[[codec]]
name = "raw"
""")
    plans = read_run_file(path).plans(get_registry())
    by_scene = {}
    for p in plans:
        by_scene.setdefault(p.dataset.params["scene"], []).append(p.metric_params)
    assert by_scene["tunnel"] == [{"floor": {"sigma": 0.01}, "geometry": {"peak": 59.7}}] * 2
    assert by_scene["urban"] == [{"floor": {"sigma": 0.02}, "geometry": {"peak": 59.7}}] * 2
    assert by_scene["indoor"] == [{"floor": {"sigma": 0.02}, "geometry": {"peak": 20.0}, "ranges": {}}] * 2
    assert read_run_file(path).metric_params == {"floor": {"sigma": 0.02}, "geometry": {"peak": 59.7}}


@pytest.mark.parametrize(("given", "error"), [
    ("floor = { sgima = 0.01 }", r"metric floor: unknown parameter\(s\) sgima; known: sigma"),
    ('floor = { sigma = "abc" }', r"sigma: cannot read 'abc' as float"),
    ("flor = { sigma = 0.01 }", r"unknown metric\(s\) flor"),
])
def test_a_bad_per_dataset_metric_param_fails_as_a_top_level_one(tmp_path, given, error):
    from lwbench.errors import LwbenchError
    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    top = _run_file(tmp_path, f"[metric_params]\n{given}\n" + _SIM_RAW, "top.toml")
    own = _run_file(tmp_path, f'[[dataset]]\nname = "sim"\nmetric_params = {{ {given} }}\n[[codec]]\nname = "raw"\n',
                    "own.toml")
    failures = []
    for path in (top, own):
        with pytest.raises(LwbenchError, match=error) as refused:
            read_run_file(path).plans(get_registry())
        failures.append((type(refused.value), str(refused.value)))
    assert failures[0] == failures[1]
    res = _invoke("run", "--config", str(own), "--store", str(tmp_path / "never.sqlite"))
    assert res.exit_code != 0 and not (tmp_path / "never.sqlite").exists()


@pytest.mark.parametrize("text", [
    '[[dataset]]\nname = "sim"\nmetric_params = { floor = 0.01 }\n[[codec]]\nname = "raw"\n',
    '[[dataset]]\nname = "sim"\nmetric_params = 3\n[[codec]]\nname = "raw"\n',
    'metric_params = { floor = 0.01 }\n' + _SIM_RAW,
])
def test_metric_params_that_are_not_tables_of_settings_are_refused(tmp_path, text):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    with pytest.raises(ParameterError, match=r"study\.toml: .*metric_params.* must be a table"):
        read_run_file(_run_file(tmp_path, text))


def test_an_unknown_dataset_key_lists_metric_params_among_the_known(tmp_path):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    path = _run_file(tmp_path, '[[dataset]]\nname = "sim"\nmetric_param = {}\n[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError, match=r"unknown key\(s\) metric_param; known: frames, metric_params, name, "
                                             r"params"):
        read_run_file(path)


def test_environment_variables_in_dataset_names_and_string_params_are_expanded(tmp_path, monkeypatch):
    from lwbench.run.config import read_run_file

    monkeypatch.setenv("LWBENCH_TEST_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("LWBENCH_TEST_SENSOR", "hdl64e")
    path = _run_file(tmp_path, """
[[dataset]]
name = "${LWBENCH_TEST_DATA}/kitti00_frames0-1"
params = { sensor = "${LWBENCH_TEST_SENSOR}", note = "$LWBENCH_TEST_SENSOR and $5", frames = 3 }

[[dataset]]
name = "relative/${LWBENCH_TEST_SENSOR}"

[[codec]]
name = "raw"
""")
    kitti, relative = read_run_file(path).datasets
    assert kitti.source == f"{tmp_path / 'data'}/kitti00_frames0-1"
    # only the braced form is a variable; other values are left as they are
    assert dict(kitti.params) == {"sensor": "hdl64e", "note": "$LWBENCH_TEST_SENSOR and $5", "frames": 3}
    assert relative.source == "relative/hdl64e"  # relative to the current directory, as written


@pytest.mark.parametrize("value", [None, ""])
def test_an_unset_environment_variable_is_an_error_that_names_it_and_the_file(tmp_path, monkeypatch, value):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    if value is None:
        monkeypatch.delenv("LWBENCH_TEST_UNSET", raising=False)
    else:
        monkeypatch.setenv("LWBENCH_TEST_UNSET", value)
    path = _run_file(tmp_path, '[[dataset]]\nname = "${LWBENCH_TEST_UNSET}/kitti"\n[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError) as refused:
        read_run_file(path)
    assert "LWBENCH_TEST_UNSET" in str(refused.value) and str(path) in str(refused.value)
    assert "not set" in str(refused.value)
    res = _invoke("run", "--config", str(path), "--store", str(tmp_path / "never.sqlite"))
    assert res.exit_code == 2 and "LWBENCH_TEST_UNSET" in res.output
    assert not (tmp_path / "never.sqlite").exists()


@pytest.mark.parametrize(("name", "error"), [
    ("${LWBENCH_TEST_DATA", "no closing"),
    ("${LWBENCH_TEST_DATA}/a/${", "no closing"),
    ("${}/kitti", "does not name an environment variable"),
    ("${1DATA}/kitti", "does not name an environment variable"),
])
def test_a_malformed_variable_is_refused(tmp_path, monkeypatch, name, error):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    monkeypatch.setenv("LWBENCH_TEST_DATA", str(tmp_path))
    path = _run_file(tmp_path, f'[[dataset]]\nname = "{name}"\n[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError, match=error):
        read_run_file(path)


def test_a_string_dataset_param_with_an_unset_variable_is_refused(tmp_path, monkeypatch):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    monkeypatch.delenv("LWBENCH_TEST_UNSET", raising=False)
    path = _run_file(tmp_path, '[[dataset]]\nname = "sim"\nparams = { scene = "${LWBENCH_TEST_UNSET}" }\n'
                               '[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError, match=r"params\.scene .*LWBENCH_TEST_UNSET"):
        read_run_file(path)


# What each shipped run file runs: its datasets (LWBENCH_REAL/... for the real samples) and, on
# its simulated datasets, how many configurations each codec gets: the studies behind the docs'
# figures, each one `lwbench run --config` (issue 34, item 4: they were shell loops over `lwbench run`).
_REAL = "${LWBENCH_REAL}"
_SHIPPED = {
    "rd_tunnel.toml": dict(
        timeout=3600.0, sequence_metrics=True,
        datasets=[("sim", {"scene": "tunnel"}, None, {})],
        configs={"raw": 1, "draco": 4, "rangeimage": 8, "vsgp": 5, "gmm": 5, "random": 4, "voxel": 4,
                 "harris3d": 4, "iss": 4, "sift3d": 4}),
    "codecs_rd.toml": dict(
        timeout=3600.0, sequence_metrics=False,
        datasets=[("sim", {}, 5, {}), (f"{_REAL}/ouster_os1-128_seq3", {}, None, {}),
                  (f"{_REAL}/kitti00_frames0-1", {"sensor": "hdl64e"}, None, {})],
        # rangeimage: 3 steps, lossless x 2 refine, refine=none; voxel: 4 sizes, quantized at 1 cm
        configs={"raw": 1, "draco": 4, "rangeimage": 3 + 2 + 1, "voxel": 4 + 1}),
    "codecs_rd_context.toml": dict(
        timeout=3600.0, sequence_metrics=False,
        datasets=[("sim", {}, 5, {}), (f"{_REAL}/ouster_os1-128_seq3", {}, 1, {}),
                  (f"{_REAL}/kitti00_frames0-1", {"sensor": "hdl64e"}, 1, {})],
        configs={"vsgp": 1, "gmm": 1}),
    "floor_rd.toml": dict(
        timeout=600.0, sequence_metrics=False,
        datasets=[("sim", {}, 5, {"floor": {"sigma": 0.01}}),
                  (f"{_REAL}/kitti00_frames0-1", {"sensor": "hdl64e"}, 1, {})],
        configs="every installed codec but oracle and gpcc, at its defaults"),
    "vsgp_outdoor_rd.toml": dict(
        timeout=600.0, sequence_metrics=False,
        datasets=[(f"{_REAL}/kitti00_frames0-1", {}, 2, {}), (f"{_REAL}/ouster_os1-128_seq3", {}, 2, {}),
                  ("sim", {}, 5, {})],
        # 4 TAUs x (default GP, num_inducing=300, predictor=none), 3 byte budgets, the defaults
        configs={"vsgp": 3 * 4 + 3 + 1, "rangeimage": 4}),
}


def _shipped_run_files():
    from pathlib import Path

    return sorted((Path(__file__).resolve().parents[1] / "examples" / "runs").glob("*.toml"))


def test_the_studies_of_the_docs_are_shipped():
    assert set(_SHIPPED) <= {p.name for p in _shipped_run_files()}


@pytest.mark.parametrize("path", _shipped_run_files(), ids=lambda p: p.name)
def test_a_shipped_run_file_reads_and_plans_what_it_says(path, tmp_path, monkeypatch):
    """Every run file in examples/runs: its datasets (``${LWBENCH_REAL}`` expanded) and codecs are
    the request's and its simulated datasets' plans; the studies described above, exactly so."""
    import sys
    from dataclasses import replace

    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib

    real = tmp_path / "real"
    monkeypatch.setenv("LWBENCH_REAL", str(real))
    doc = tomllib.loads(path.read_text())
    request = read_run_file(path)
    assert [(d.source, d.frames) for d in request.datasets] == [
        (str(d["name"]).replace(_REAL, str(real)), d.get("frames")) for d in doc["dataset"]]
    assert all("${" not in d.source for d in request.datasets)
    registry = get_registry()
    lacking = {c["name"]: registry.codec(c["name"]).unavailable() for c in doc["codec"]}
    if any(lacking.values()):  # a codec wrapping an external program (gpcc's tmc3): planning refuses it here
        pytest.skip("; ".join(f"{n}: {why}" for n, why in lacking.items() if why))
    # Planning needs datasets that exist: the simulated ones (the real ones are paths, checked above).
    sims = tuple(d for d in request.datasets if d.source == "sim")
    plans = replace(request, datasets=sims).plans(registry)
    assert len(plans) == len(sims) * len(request.seeds)
    for i, plan in enumerate(plans):
        d = sims[i // len(request.seeds)]
        assert {c.name for c in plan.configs} == {c["name"] for c in doc["codec"]}
        assert plan.frames == (d.frames if d.frames is not None else request.frames)
        assert plan.metric_params == d.merged_metric_params(request.metric_params)

    want = _SHIPPED.get(path.name)
    if want is None:  # a run file not described here: the checks above
        return
    assert (request.timeout_s, request.sequence_metrics) == (want["timeout"], want["sequence_metrics"])
    assert request.store is not None and request.store.parent.name == "lwbench-results"
    got = [(d.source, dict(d.params), d.frames, {m: dict(v) for m, v in d.metric_params.items()})
           for d in request.datasets]
    assert got == [(s.replace(_REAL, str(real)), p, f, m) for s, p, f, m in want["datasets"]]
    configs = want["configs"]
    if isinstance(configs, str):  # every installed codec (oracle needs labels), each once at its defaults
        # (gpcc, an external program's wrapper, has its own study: gpcc_rd.toml)
        configs = {name: 1 for name in registry.codecs if name not in ("oracle", "gpcc")}
    for plan in plans:
        counts = {}
        for c in plan.configs:
            counts[c.name] = counts.get(c.name, 0) + 1
        assert counts == configs
