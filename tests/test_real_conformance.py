"""Every registered codec, at its defaults, on every shared real LiDAR folder (issue 11 §4).

Through ``lwbench run`` (typer's CliRunner, the path a user takes: loader auto-detection,
sensor model from the folder, the runner's fresh-instance decode and every frame metric), into
a store in ``tmp_path``; a single failed row fails the test with its error. Nothing is tuned
per folder: no ``--param``, no ``sensor=`` preset.

Skips where the samples are absent (``real_data`` fixture); the generated scans of
``test_codec_conformance.py`` check the same hazards everywhere. The fast set runs the first
frame of each folder; codecs that take long at their defaults (:data:`SLOW_CODECS`) and the
remaining frames are ``-m slow``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _real import real_data_dir
from typer.testing import CliRunner

from lwbench.cli import app
from lwbench.registry import get_registry
from lwbench.results.store import ResultStore

#: ``gmm`` fits K=200 full covariances by EM on all 17k-125k points: 10-70 s per scan, and the
#: runner encodes the first frame twice (warm-up, then timed).
SLOW_CODECS = ("gmm",)
# A codec that needs more than a scan (the oracle needs labels for the sequence) is not run here.
CODECS = sorted(name for name, cls in get_registry().codecs.items() if not cls.needs)
FAST_CODECS = [c for c in CODECS if c not in SLOW_CODECS]


def _folders() -> list[str]:
    if not real_data_dir().is_dir():
        return ["(absent)"]  # one placeholder id: the real_data fixture then skips it
    return sorted(p.name for p in real_data_dir().iterdir() if p.is_dir() and not p.name.startswith("."))


FOLDERS = _folders()


def run_codecs(folder: Path, store: Path, codecs: list[str], frames: int | None) -> str:
    """``lwbench run`` on ``folder``; asserts that every (frame, codec) row is ``ok``."""
    args = ["run", "--dataset", str(folder), "--store", str(store), "--no-sequence-metrics"]
    for c in codecs:
        args += ["--codec", c]
    if frames is not None:
        args += ["--frames", str(frames)]
    res = CliRunner().invoke(app, args, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    with ResultStore(store) as results:
        rows = list(results.rows(kind="frame"))
    failed = [f"{r.codec} frame {r.frame}: {r.error}" for r in rows if r.status != "ok"]
    assert not failed, f"{folder.name}:\n" + "\n".join(failed)
    per_codec = {c: sum(r.codec == c for r in rows) for c in codecs}
    n = min(per_codec.values())
    assert n >= 1 and all(v == n for v in per_codec.values()), per_codec
    assert all(r.metrics.get("points_out") is not None for r in rows)
    return res.output


@pytest.mark.heavy
@pytest.mark.parametrize("folder", FOLDERS)
def test_every_fast_codec_on_the_first_frame(real_data: Path, folder: str, tmp_path: Path) -> None:
    print(run_codecs(real_data / folder, tmp_path / "r.sqlite", FAST_CODECS, frames=1))


@pytest.mark.slow
@pytest.mark.parametrize("folder", FOLDERS)
def test_slow_codecs_on_the_first_frame(real_data: Path, folder: str, tmp_path: Path) -> None:
    print(run_codecs(real_data / folder, tmp_path / "r.sqlite", list(SLOW_CODECS), frames=1))


@pytest.mark.slow
@pytest.mark.parametrize("folder", FOLDERS)
def test_every_fast_codec_on_every_frame(real_data: Path, folder: str, tmp_path: Path) -> None:
    print(run_codecs(real_data / folder, tmp_path / "r.sqlite", FAST_CODECS, frames=None))
