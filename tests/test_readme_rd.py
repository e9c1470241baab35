"""The README's rate-distortion example shows what it promises: a BD-rate against its reference.

The README runs ``examples/runs/rd_tunnel.toml`` and then ``lwbench rd ... --reference draco``.
Its draco sweep once started at 11 bits, where Draco merges returns (coverage flags took two of
its five points off the curve) and every pair said "3 efficient point(s); the Bjøntegaard delta
needs at least 4". This test runs the study file's reference and range-image sweeps (the pair
whose curves overlap) on fewer frames, then the README's ``rd`` line as written, store aside.
"""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lwbench.cli import app

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - the project's own fallback (pyproject: tomli below 3.11)
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def _readme_rd_command() -> list[str]:
    readme = (ROOT / "README.md").read_text().splitlines()
    lines = [ln for ln in readme if ln.startswith("lwbench rd --store lwbench-results/rd.sqlite")]
    assert len(lines) == 1, lines
    return shlex.split(lines[0].split("#")[0])[1:]


def _toml_value(value) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    return repr(value)


@pytest.mark.heavy
def test_the_readme_rd_example_gives_a_bd_rate(tmp_path):
    args = _readme_rd_command()
    reference = args[args.index("--reference") + 1]
    study = tomllib.loads((ROOT / "examples" / "runs" / "rd_tunnel.toml").read_text())
    store = tmp_path / "rd.sqlite"
    text = [f'store = "{store}"', "frames = 2", "sequence_metrics = false"]
    for ds in study["dataset"]:
        text += ["[[dataset]]", f"name = {_toml_value(ds['name'])}", f"params = {_toml_value(ds.get('params', {}))}"]
    for codec in study["codec"]:
        if codec["name"] in (reference, "rangeimage"):
            params = _toml_value(codec.get("params", {}))
            text += ["[[codec]]", f"name = {_toml_value(codec['name'])}", f"params = {params}"]
    (tmp_path / "study.toml").write_text("\n".join(text) + "\n")
    runner = CliRunner()
    res = runner.invoke(app, ["run", "--config", str(tmp_path / "study.toml"), "--in-process"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    args[args.index("--store") + 1] = str(store)
    res = runner.invoke(app, args, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    bd = re.search(rf"BD vs {reference}: rangeimage: BD-rate (-?[\d.]+) %", flat)
    assert bd is not None, flat
    assert float(bd.group(1)) < 0  # the range image needs fewer bytes than Draco for the same range RMSD
