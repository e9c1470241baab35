"""PocoNet's selector diagnostics (lwbench_plugins.poconet.diagnostics) and ``lwbench diagnose``:
ranking quality, the noisy oracle's corruption, the spatially balanced ranking and the command on
a simulated two-drive street."""

from __future__ import annotations

import json

import numpy as np
import pytest
from lwbench_plugins.poconet.diagnostics import (
    GROUND,
    HIGH,
    LOW,
    LabelFolder,
    balanced_order,
    crossing,
    frame_diagnostics,
    kept_precision,
    noisy_classes,
    noisy_oracle_curve,
    roc_auc,
    select_by_score,
    summarize,
    top_k_precision,
)
from typer.testing import CliRunner

from lwbench import DataFormatError, Frame, ParameterError, SequenceMetric, get_sensor


def test_auc_is_the_chance_a_positive_outscores_a_negative():
    pos = np.array([True, True, False, False])
    assert roc_auc(np.array([4.0, 3, 2, 1]), pos) == 1.0
    assert roc_auc(np.array([1.0, 2, 3, 4]), pos) == 0.0
    assert roc_auc(np.ones(4), pos) == 0.5  # ties count one half
    assert np.isnan(roc_auc(np.ones(3), np.ones(3, bool)))
    from sklearn.metrics import roc_auc_score

    rng = np.random.default_rng(0)
    s, y = rng.normal(size=500).round(1), rng.random(500) < 0.3  # rounded: many ties
    assert roc_auc(s, y) == pytest.approx(roc_auc_score(y, s), abs=1e-12)


def test_top_k_and_kept_precision():
    scores = np.array([0.9, 0.8, 0.1, 0.7, 0.2])
    pos = np.array([True, False, True, True, False])
    assert top_k_precision(scores, pos, 3) == pytest.approx(2 / 3)
    classes = np.array([HIGH, LOW, GROUND, HIGH, LOW])
    assert kept_precision(classes, np.array([0, 1, 2, 3])) == pytest.approx(2 / 3)  # ground left out


def test_noisy_classes_have_the_precision_asked_for_and_the_same_size():
    rng = np.random.default_rng(1)
    classes = rng.choice([LOW, HIGH, GROUND], size=20_000, p=[0.5, 0.1, 0.4]).astype(np.uint8)
    n_high = int((classes == HIGH).sum())
    for p in (0.2, 0.55, 1.0):
        noisy = noisy_classes(classes, p, np.random.default_rng(2))
        marked = noisy == HIGH
        assert marked.sum() == n_high
        assert (classes[marked] == HIGH).mean() == pytest.approx(p, abs=1 / n_high)
        np.testing.assert_array_equal(noisy == GROUND, classes == GROUND)
    np.testing.assert_array_equal(noisy_classes(classes, 1.0, rng), classes)
    with pytest.raises(ParameterError):
        noisy_classes(classes, 1.5, rng)


def test_balanced_order_takes_every_cell_before_a_second_point_of_any():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 30, (3000, 3))
    scores = -np.hypot(pts[:, 0] - 5, pts[:, 1] - 5)  # smooth: the plain top is one patch
    cells = {tuple(c) for c in np.floor(pts[:, :2] / 3.0).astype(int)}
    order = balanced_order(pts, scores, 3.0, np.random.default_rng(1))
    assert sorted(order.tolist()) == list(range(len(pts)))
    first = {tuple(c) for c in np.floor(pts[order[: len(cells)], :2] / 3.0).astype(int)}
    assert first == cells
    # within a cell the best score comes first
    k = order[0]
    same = np.all(np.floor(pts[:, :2] / 3.0) == np.floor(pts[k, :2] / 3.0), axis=1)
    assert scores[k] == scores[same].max()
    plain = balanced_order(pts, scores, 0.0, np.random.default_rng(1))
    assert np.all(np.diff(scores[plain]) <= 0)
    top = pts[plain[:100]]
    assert np.ptp(top[:, 0]) < 10  # the plain top: one patch


def test_select_by_score_keeps_the_exact_budget_and_the_ground_quota():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-20, 20, (5000, 3))
    cls = rng.choice([LOW, HIGH, GROUND], size=5000).astype(np.uint8)
    for k in (1, 400, 4999, 5000):
        keep = select_by_score(pts, cls, rng.random(5000), k, np.random.default_rng(3), 0.1, 3.0)
        assert len(keep) == k and len(np.unique(keep)) == k
    keep = select_by_score(pts, cls, rng.random(5000), 1000, np.random.default_rng(3), 0.1, 3.0)
    assert (cls[keep] == GROUND).sum() == 100
    few_ground = np.where(cls == GROUND, LOW, cls)
    keep = select_by_score(pts, few_ground, rng.random(5000), 1000, np.random.default_rng(3), 0.5, 3.0)
    assert len(keep) == 1000


def test_crossing_interpolates_where_the_curve_goes_below_a_level():
    curve = [(0.2, 10.0), (0.4, 6.0), (0.6, 2.0), (1.0, 1.0)]
    assert crossing(curve, 4.0) == pytest.approx(0.5)
    assert crossing(curve, 20.0) == 0.2
    assert crossing(curve, 0.5) is None
    assert crossing([(0.2, 1.0), (0.5, 5.0), (1.0, 1.0)], 3.0) == pytest.approx(0.75)  # stays below from there


def test_diagnostics_add_up_over_frames():
    classes = np.array([HIGH, HIGH, LOW, LOW, GROUND, GROUND])
    scores = np.array([0.9, 0.1, 0.8, 0.0, 0.5, 0.5])
    d = frame_diagnostics(classes, np.array([0, 2, 4]), scores)
    assert (d.high, d.low, d.kept_high, d.kept_low, d.kept_ground) == (2, 2, 1, 1, 1)
    assert d.auc == pytest.approx(0.75) and d.top_k == 2 and d.top_k_hits == 1
    s = summarize([d, d])
    assert s["base_rate"] == 0.5 and s["kept_precision"] == 0.5 and s["kept_ground_share"] == pytest.approx(1 / 3)


def _write_labels(root, classes: list[np.ndarray]) -> None:
    (root / "labels").mkdir(parents=True)
    for i, c in enumerate(classes):
        c.astype(np.uint8).tofile(root / "labels" / f"{i:06d}.label")
    (root / "labels.json").write_text(json.dumps({"frames": {str(i): len(c) for i, c in enumerate(classes)}}))


def test_a_label_folder_is_checked_against_the_scan(tmp_path):
    _write_labels(tmp_path, [np.array([0, 1, 2, 1])])
    folder = LabelFolder(tmp_path)
    assert folder.classes(0, 4).tolist() == [0, 1, 2, 1]
    with pytest.raises(DataFormatError, match="for 4 points"):
        folder.classes(0, 5)
    with pytest.raises(DataFormatError, match="no labels for frame 3"):
        folder.classes(3, 4)
    np.array([0, 7, 1, 1], np.uint8).tofile(tmp_path / "labels" / "000000.label")
    with pytest.raises(DataFormatError, match="damaged"):
        LabelFolder(tmp_path).classes(0, 4)
    with pytest.raises(DataFormatError, match="no labels.json"):
        LabelFolder(tmp_path / "nowhere")
    (tmp_path / "labels.json").write_text("[1, 2]")
    with pytest.raises(DataFormatError, match="not a label index"):
        LabelFolder(tmp_path)


class _KeptShare(SequenceMetric):
    """A stand-in for localization: the share of kept points that lie at x > 0 (the 'high' ones)."""

    name = "kept_share"
    ids = ("share",)

    def compute(self, seq):
        return {"share": float(np.mean([(d[:, 0] > 0).mean() for d in seq.decoded]))}


class _Line:
    """Two frames of points along x; the high-priority ones at x > 0."""

    name = "line"

    def __init__(self) -> None:
        rng = np.random.default_rng(0)
        self.frames = []
        for i in range(2):
            pts = np.column_stack([rng.uniform(-10, 10, 4000), rng.uniform(-5, 5, 4000), np.zeros(4000)])
            self.frames.append(Frame(pts.astype(np.float32), get_sensor("vlp16"), index=i))

    def __getitem__(self, i: int) -> Frame:
        return self.frames[i]


def test_the_noisy_oracle_keeps_points_of_the_precision_asked_for():
    ds = _Line()

    def truth(f: Frame) -> np.ndarray:
        c = np.where(f.points[:, 0] > 9.0, HIGH, LOW).astype(np.uint8)  # 5 % high
        c[f.points[:, 1] < -4.5] = GROUND
        return c

    curve = noisy_oracle_curve(ds, [0, 1], truth, lambda n: n // 40, [0.3, 1.0], _KeptShare(), ground_share=0.0)
    assert [c.precision for c in curve] == [0.3, 1.0]
    assert curve[1].values["share"] == pytest.approx(1.0)  # every kept point truly high (x > 9)
    assert curve[0].values["share"] < 0.7  # 30 % truly high, the rest anywhere
    # The balanced rule takes every 3 m cell's best point first: the marked points win only
    # inside their cells, so precision moves the selection less.
    balanced = noisy_oracle_curve(
        ds, [0, 1], truth, lambda n: n // 40, [0.3, 1.0], _KeptShare(), ground_share=0.0, rule="score", cell=3.0
    )
    assert balanced[0].values["share"] < balanced[1].values["share"] < curve[1].values["share"]
    with pytest.raises(ParameterError, match="rule"):
        noisy_oracle_curve(ds, [0], truth, lambda n: 10, [1.0], _KeptShare(), rule="argmax")


runner = CliRunner()


@pytest.fixture(scope="module")
def two_drive_street(tmp_path_factory):
    """A short simulated two-drive street and its labels (both definitions) from `lwbench label`."""
    from lwbench.cli import app

    root = tmp_path_factory.mktemp("diag")
    ds = ["--dataset-param", "scene=urban", "--dataset-param", "traversals=2", "--dataset-param", "frames=3"]
    for counts_from in ("all", "mapping"):
        res = runner.invoke(
            app,
            ["label", "sim", "--out", str(root / counts_from), "--counts-from", counts_from, *ds],
            catch_exceptions=False,
        )
        assert res.exit_code == 0, res.output
    return root, ds


@pytest.mark.heavy
def test_diagnose_reports_each_label_definition(two_drive_street):
    from lwbench.cli import app

    root, ds = two_drive_street
    out = root / "oracle.json"
    res = runner.invoke(
        app,
        [
            "diagnose",
            "oracle",
            "--param",
            f"labels={root / 'mapping'}",
            "--param",
            "ratio=0.05",
            "--dataset",
            "sim",
            *ds,
            "--labels",
            f"mapping={root / 'mapping'}",
            "--labels",
            f"all={root / 'all'}",
            "--json",
            str(out),
        ],
        catch_exceptions=False,
    )
    assert res.exit_code == 0, res.output
    result = json.loads(out.read_text())
    assert result["frames"] == 6 and set(result["labels"]) == {"mapping", "all"}
    assert result["labels"]["mapping"]["kept_precision"] == 1.0  # the oracle on its own labels
    assert 0 < result["labels"]["all"]["kept_precision"] < 1.0  # the other definition differs
    assert "| mapping |" in res.stdout
    bad = runner.invoke(
        app,
        ["diagnose", "random", "--param", "ratio=0.1", "--dataset", "sim", *ds, "--labels", f"x={root / 'nowhere'}"],
    )
    assert bad.exit_code != 0


@pytest.mark.slow
def test_diagnose_draws_the_noisy_oracle_curve(two_drive_street):
    from lwbench.cli import app

    root, ds = two_drive_street
    out = root / "curve.json"
    res = runner.invoke(
        app,
        [
            "diagnose",
            "random",
            "--param",
            "ratio=0.1",
            "--dataset",
            "sim",
            *ds,
            "--labels",
            f"mapping={root / 'mapping'}",
            "--curve",
            "--precision",
            "1.0",
            "--curve-rule",
            "class",
            "--curve-rule",
            "score",
            "--json",
            str(out),
        ],
        catch_exceptions=False,
    )
    assert res.exit_code == 0, res.output
    curve = json.loads(out.read_text())["curve"]
    for rule in ("class", "score"):
        points = curve["rules"][rule]["points"]
        assert [p["precision"] for p in points][-1] == 1.0 and all(p["ate_rmse"] is not None for p in points)
    assert curve["random"]["ate_rmse"] is not None and "beats random from precision" in res.stdout
