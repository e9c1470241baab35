"""``lwbench poconet-ceiling`` (issue 37): hand-made per-point features against PocoNet's labels."""

from __future__ import annotations

import numpy as np
import pytest
from lwbench_plugins.poconet.ceiling import FEATURES, point_features

from lwbench import Frame, get_sensor


def _frame(points: np.ndarray) -> Frame:
    return Frame(points.astype(np.float32), get_sensor("vlp16"))


def test_the_features_say_plane_line_and_wall_where_they_are():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(2, 10, 3000), rng.uniform(-4, 4, 3000), np.full(3000, -1.7)])
    pole = np.column_stack([np.full(400, 5.0), np.full(400, 3.0), np.linspace(-1.7, 2.0, 400)])
    wall = np.column_stack([np.full(2000, 12.0), rng.uniform(-4, 4, 2000), rng.uniform(-1.7, 2.0, 2000)])
    pts = np.concatenate([ground, pole, wall])
    f = point_features(_frame(pts), np.array([100, 3000 + 200, 3400 + 100]))
    col = {name: f[:, j] for j, name in enumerate(FEATURES)}
    assert col["scattering"][0] < 1e-6 and col["scattering"][2] < 1e-6  # ground and wall: planes, no 3rd axis
    assert col["linearity"][1] > 0.99 and col["planarity"][1] < 0.01  # the pole: a line
    assert col["verticality"][0] < 0.01 and col["verticality"][2] > 0.99  # ground flat, wall upright
    assert col["height_spread"][0] < 1e-6 < col["height_spread"][2]
    # Over many points a plane's neighbourhoods are planar more than linear (one point's 16
    # random neighbours can be elongated).
    ground_f = point_features(_frame(pts), np.arange(0, 3000, 10))
    assert ground_f[:, FEATURES.index("planarity")].mean() > ground_f[:, FEATURES.index("linearity")].mean()
    np.testing.assert_allclose(col["range"], np.linalg.norm(pts[[100, 3200, 3500]], axis=1), rtol=1e-6)
    assert (col["intensity"] == 0).all()  # no intensity in the scan: the feature is 0, not missing


@pytest.mark.heavy
def test_the_command_fits_on_training_streets_and_scores_held_out_ones(tmp_path):
    from typer.testing import CliRunner

    from lwbench.cli import app

    res = CliRunner().invoke(app, ["poconet-ceiling", "--train", "urban:30", "--test", "urban:100", "--frames", "12",
                                   "--scans", "1", "--points", "800", "--no-network", "--out", str(tmp_path),
                                   "--json", str(tmp_path / "r.json")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    import json

    result = json.loads((tmp_path / "r.json").read_text())
    test = result["test"]["urban:100"]
    assert 0.0 <= test["model_auc"] <= 1.0 and 0.0 < test["base_rate"] < 1.0
    assert set(test["single"]) <= set(FEATURES) and "| urban:100 |" in res.stdout


def test_poconet_ranks_by_scores_from_a_file_and_refuses_foreign_or_damaged_ones(tmp_path, street4):
    """``poconet score=file`` (the features' model control): the same rule, another model's
    ranking -- here the height, so the kept non-ground points must be the high ones."""
    from lwbench_plugins.poconet.codec import PocoNetSelector
    from lwbench_plugins.poconet.diagnostics import ScoreFolder, write_score_folder

    from lwbench import DataFormatError, ParameterError

    ds = street4
    heights = {ds[i].index: ds[i].points[:, 2].astype(np.float64) for i in range(len(ds))}
    write_score_folder(tmp_path / "s", ds, heights, "height")
    frame = ds[1]
    by_height = PocoNetSelector(ratio=1 / 12, score="file", scores=str(tmp_path / "s"), cell=0.0)
    by_random = PocoNetSelector(ratio=1 / 12, score="random", cell=0.0)
    np.testing.assert_array_equal(by_height.scores(frame), heights[frame.index].astype(np.float32))
    kept, control = by_height.select(frame), by_random.select(frame)
    assert len(kept) == len(control) == round(len(frame) / 12)
    z = frame.points[:, 2]
    assert np.median(z[kept]) > np.median(z[control]) + 1.0  # ranked by the file, not at random
    assert PocoNetSelector.missing({"score": "file", "scores": None}).startswith("set poconet.scores")
    with pytest.raises(ParameterError, match="poconet.scores"):
        PocoNetSelector(ratio=1 / 12, score="file").select(frame)
    with pytest.raises(DataFormatError, match="for .* points"):
        ScoreFolder(tmp_path / "s").scores(frame.index, len(frame) + 1)
    (tmp_path / "s" / "scores" / f"{frame.index:06d}.f32").write_bytes(b"\0\0\0")
    with pytest.raises(DataFormatError, match="damaged"):
        ScoreFolder(tmp_path / "s").scores(frame.index, len(frame))
    (tmp_path / "s" / "scores.json").write_text("{}")
    with pytest.raises(DataFormatError, match="not a score index"):
        ScoreFolder(tmp_path / "s")


@pytest.fixture(scope="module")
def street4():
    from lwbench.registry import get_registry

    return get_registry().dataset("sim")(scene="urban", frames=4, noise=0.02)


def test_features_within_a_sample_see_only_the_sample():
    """``--context N``: neighbourhoods drawn from a sample of the scan, as the network's input is
    -- a plane sampled sparsely is still a plane, but its points' neighbours lie further off."""
    rng = np.random.default_rng(1)
    plane = np.column_stack([rng.uniform(2, 10, 4000), rng.uniform(-4, 4, 4000), np.full(4000, -1.7)])
    frame = _frame(plane)
    among = np.sort(rng.choice(4000, 500, replace=False))
    rows = among[:50]
    dense, sparse = point_features(frame, rows), point_features(frame, rows, among)
    j = FEATURES.index("density")
    assert (sparse[:, j] > 1.5 * dense[:, j]).mean() > 0.9  # 8x fewer points: neighbours ~2.8x further
    assert sparse[:, FEATURES.index("scattering")].max() < 1e-6  # still a plane
