"""PocoNet (plugins/poconet): the labels of §III-B on hand-made cases, the network's shapes and
losses, training, the shipped checkpoint, and the oracle."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lwbench_plugins.poconet.codec import (
    SHIPPED_WEIGHTS,
    OracleSelector,
    PocoNetSelector,
    load_checkpoint,
    select_by_class,
)
from lwbench_plugins.poconet.data import crop, prepare, to_torch
from lwbench_plugins.poconet.labels import (
    GROUND,
    HIGH,
    LOW,
    LabelSettings,
    LabelStore,
    dynamic_threshold,
    frame_labels,
    label_dataset,
    observation_counts,
)
from lwbench_plugins.poconet.network import NetConfig, PocoNet, siamese_loss

from lwbench import DataFormatError, get_sensor
from lwbench.testing import room_scan

SMALL = NetConfig(d_out=(8, 16, 32, 32), codeword=64)


# -- labels ---------------------------------------------------------------------------------
def test_algorithm_1_keeps_the_share_asked_for_with_the_fewest_extra_ties():
    counts = np.array([5, 5, 4, 3, 1])
    assert dynamic_threshold(counts, 0.6) == 3  # > 3: the three points with 5, 5, 4
    assert dynamic_threshold(counts, 0.2) == 4  # one point asked for; the tie at 5 keeps two
    assert dynamic_threshold(counts, 1.0) == 0  # all
    assert dynamic_threshold(np.array([2, 1]), 1.0, n_total=10) == 0  # fewer candidates: all of them
    assert dynamic_threshold(np.array([], np.int64), 0.5) == 0


def test_frame_labels_put_ground_apart_and_the_top_counts_high():
    counts = np.array([9, 9, 1, 7, 2, 2, 50, 50])
    ground = np.array([False] * 6 + [True, True])
    labels = frame_labels(counts, ground, r_th=0.25)  # 2 of 8 points high priority
    assert labels.tolist() == [HIGH, HIGH, LOW, LOW, LOW, LOW, GROUND, GROUND]


def test_observation_counts_count_each_pose_once():
    map_points = np.array([[0.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]])
    scans = [
        np.array([[0.02, 0, 0], [0.0, 0.03, 0], [-0.04, 0, 0]]),  # three points near map point 0: once
        np.array([[1.05, 0, 0], [0.0, 0.0, 0.08]]),  # near points 1 and 0
        np.array([[5.2, 0, 0]]),  # 0.2 m from point 2: not within d_th
    ]
    assert observation_counts(scans, map_points, d_th=0.1).tolist() == [2, 1, 0]


@pytest.fixture(scope="module")
def street():
    """Four scans of the simulated street (HDL-64E), 1 m apart, with their poses."""
    from lwbench.registry import get_registry

    return get_registry().dataset("sim")(scene="urban", frames=4, noise=0.02)


def test_labelling_a_sequence_writes_checked_labels(tmp_path, street):
    ds = street
    settings = LabelSettings(r_th=1 / 12)
    labels, counts = label_dataset(ds, settings=settings)
    assert all(len(lab) == len(ds[i]) for i, lab in enumerate(labels))
    for lab, cnt in zip(labels, counts, strict=True):
        shares = np.bincount(lab, minlength=3) / len(lab)
        assert shares[GROUND] > 0.3  # the road is the dominant plane
        assert shares[HIGH] >= 1 / 12  # at least r_th (ties at the threshold add some)
        assert cnt[lab == HIGH].min() > cnt[lab == LOW].max()  # the threshold splits the counts
    store = LabelStore(tmp_path)
    store.write(ds, [0, 1, 2, 3], labels, counts, settings)
    lab, cnt = store.read(1, len(ds[1]))
    np.testing.assert_array_equal(lab, labels[1])
    with pytest.raises(DataFormatError, match="for .* points"):
        store.read(1, len(ds[1]) + 1)


# -- network --------------------------------------------------------------------------------
def _batch(n: int, seed: int, cfg: NetConfig = SMALL):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-10, 10, (n, 3)).astype(np.float32)
    feats = np.column_stack([pts, rng.uniform(0, 1, n)]).astype(np.float32)
    return to_torch([prepare(pts, cfg.k, cfg.ratio, len(cfg.d_out), np.random.default_rng(seed))], [feats],
                    torch.device("cpu"))


def test_shapes_and_the_siamese_loss():
    torch.manual_seed(0)
    net = PocoNet(SMALL)
    logits, code = net(_batch(2048, 0))
    assert logits.shape == (1, 2048, 3) and code.shape == (1, SMALL.codeword)
    same, _ = net(_batch(2048, 0))
    labels = torch.zeros(1, 2048, dtype=torch.long)
    _, parts = siamese_loss((logits, same), (code, code), labels, torch.ones(3), lam=1.0)
    assert parts["global"] == 0.0 and parts["label"] > 0
    other_logits, other_code = net(_batch(2048, 1))  # another sampling: codewords differ
    _, parts = siamese_loss((logits, other_logits), (code, other_code), labels, torch.ones(3), lam=1.0)
    assert parts["global"] > 0


def test_training_steps_lower_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    net = PocoNet(SMALL)
    a = _batch(1024, 0)
    b = to_torch([prepare(a["xyz"][0][0].numpy(), SMALL.k, SMALL.ratio, len(SMALL.d_out), np.random.default_rng(1))],
                 [a["features"][0].numpy()], torch.device("cpu"))  # the same points, another sampling
    x = a["xyz"][0][0, :, 0]  # the class is where a point lies: learnable from the geometry
    labels = ((x > -3).long() + (x > 3).long()).unsqueeze(0)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    losses = []
    for _ in range(12):
        (la, ca), (lb, cb) = net(a), net(b)
        loss, parts = siamese_loss((la, lb), (ca, cb), labels, torch.ones(3), lam=1.0)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(parts["loss"])
    assert losses[-1] < 0.6 * losses[0]


def test_a_crop_is_the_points_nearest_a_random_one():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, (5000, 3))
    idx = crop(len(pts), 500, pts, np.random.default_rng(1))
    assert len(np.unique(idx)) == 500
    small = crop(300, 500, pts[:300], rng)
    assert len(small) == 500 and set(small.tolist()) == set(range(300))


# -- checkpoints and selection --------------------------------------------------------------
def test_selection_by_class_fills_the_budget_high_then_ground_with_a_ground_quota():
    cls = np.array([HIGH] * 10 + [GROUND] * 10 + [LOW] * 10)[np.random.default_rng(0).permutation(30)]

    def counts(idx, of=cls):
        return [int((of[idx] == c).sum()) for c in (HIGH, GROUND, LOW)]

    assert counts(select_by_class(cls, 8, 0, 0)) == [8, 0, 0]
    assert counts(select_by_class(cls, 8, 0, 0, ground_share=0.25)) == [6, 2, 0]
    assert counts(select_by_class(cls, 25, 0, 0, ground_share=0.25)) == [10, 10, 5]
    no_ground = cls[cls != GROUND]
    assert counts(select_by_class(no_ground, 8, 0, 0, ground_share=0.5), no_ground) == [8, 0, 0]  # none: high
    a, b = select_by_class(cls, 5, 0, 0), select_by_class(cls, 5, 1, 0)
    np.testing.assert_array_equal(a, select_by_class(cls, 5, 0, 0))  # deterministic for a seed
    assert set(a.tolist()) != set(b.tolist())  # and the seed picks within the class



def test_a_corrupt_or_foreign_checkpoint_is_a_clear_error(tmp_path):
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DataFormatError, match="not a readable checkpoint"):
        load_checkpoint(str(tmp_path / "junk.pt"), "cpu")
    torch.save({"format": "something-else", "model": {}}, tmp_path / "foreign.pt")
    with pytest.raises(DataFormatError, match="not a PocoNet checkpoint"):
        load_checkpoint(str(tmp_path / "foreign.pt"), "cpu")
    torch.save({"format": "lwbench-poconet", "config": SMALL.as_dict(), "model": {"x": torch.zeros(1)}},
               tmp_path / "mismatch.pt")
    with pytest.raises(DataFormatError, match="does not match"):
        load_checkpoint(str(tmp_path / "mismatch.pt"), "cpu")


def test_the_shipped_checkpoint_loads_and_selects_exactly_the_budget():
    frame = room_scan(get_sensor("hdl64e"), seed=3, index=2)
    for ratio in (1 / 12, 1 / 24):
        codec = PocoNetSelector(ratio=ratio)
        idx = codec.select(frame)
        assert len(idx) == round(ratio * len(frame)) and len(np.unique(idx)) == len(idx)
        np.testing.assert_array_equal(idx, PocoNetSelector(ratio=ratio).select(frame))  # deterministic
    assert len(PocoNetSelector(points=777).select(frame)) == 777
    assert SHIPPED_WEIGHTS.stat().st_size < 5 * 2**20


def test_the_oracle_keeps_high_priority_then_ground(tmp_path, street):
    ds = street
    labels, counts = label_dataset(ds)
    LabelStore(tmp_path).write(ds, [0, 1, 2, 3], labels, counts, LabelSettings())
    frame = ds[1]
    n_high = int((labels[1] == HIGH).sum())
    idx = OracleSelector(labels=str(tmp_path), points=n_high + 100, ground_share=0.0).select(frame)
    chosen = labels[1][idx]
    assert (chosen == HIGH).sum() == n_high and (chosen == GROUND).sum() == 100
    few = OracleSelector(labels=str(tmp_path), points=500, ground_share=0.0).select(frame)
    assert (labels[1][few] == HIGH).all()
    # Within the class a seeded random order: spread over the class, not its densest patch.
    high = frame.points[labels[1] == HIGH]
    def spread(x):
        lo, hi = np.percentile(x, [5, 95])
        return hi - lo

    assert spread(frame.points[few, 0]) > 0.8 * spread(high[:, 0])
    np.testing.assert_array_equal(few, OracleSelector(labels=str(tmp_path), points=500, ground_share=0.0).select(frame))
    with pytest.raises(Exception, match="oracle.labels"):
        OracleSelector().select(frame)
