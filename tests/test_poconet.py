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

from lwbench import DataFormatError, ParameterError, get_sensor
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
    return to_torch(
        [prepare(pts, cfg.k, cfg.ratio, len(cfg.d_out), np.random.default_rng(seed))], [feats], torch.device("cpu")
    )


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


@pytest.mark.heavy
def test_training_steps_lower_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    net = PocoNet(SMALL)
    a = _batch(1024, 0)
    b = to_torch(
        [prepare(a["xyz"][0][0].numpy(), SMALL.k, SMALL.ratio, len(SMALL.d_out), np.random.default_rng(1))],
        [a["features"][0].numpy()],
        torch.device("cpu"),
    )  # the same points, another sampling
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
    torch.save(
        {"format": "lwbench-poconet", "config": SMALL.as_dict(), "model": {"x": torch.zeros(1)}},
        tmp_path / "mismatch.pt",
    )
    with pytest.raises(DataFormatError, match="does not match"):
        load_checkpoint(str(tmp_path / "mismatch.pt"), "cpu")


@pytest.mark.heavy
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


def test_the_noisy_oracle_codec_is_the_curve_s_selection(tmp_path, street):
    from lwbench_plugins.poconet.diagnostics import kept_precision, noisy_classes, select_by_class

    ds = street
    labels, counts = label_dataset(ds)
    LabelStore(tmp_path).write(ds, [0, 1, 2, 3], labels, counts, LabelSettings())
    frame = ds[2]
    codec = OracleSelector(labels=str(tmp_path), ratio=1 / 24, precision=0.4, ground_share=0.1)
    idx = codec.select(frame)
    assert len(idx) == round(len(frame) / 24)
    rng = np.random.default_rng([0, frame.index, 400_000])
    noisy = noisy_classes(labels[2], 0.4, rng)
    marked = noisy == HIGH
    precision = (labels[2][marked] == HIGH).mean()  # 0.4, unless too few low points cap the false ones
    assert precision >= 0.4 - 1e-3
    assert kept_precision(labels[2], idx) == pytest.approx(precision, abs=0.03)  # the kept high part: a sample
    expected = select_by_class(noisy, len(idx), 0, frame.index, 0.1)
    np.testing.assert_array_equal(idx, expected)  # what noisy_oracle_curve keeps at p = 0.4
    balanced = OracleSelector(labels=str(tmp_path), ratio=1 / 24, rule="score").select(frame)
    assert len(balanced) == len(idx) and kept_precision(labels[2], balanced) < 1.0  # every cell gets points


@pytest.mark.heavy
def test_mapping_drive_labels_count_only_the_mapping_drive(tmp_path):
    from lwbench.registry import get_registry

    ds = get_registry().dataset("sim")(scene="urban", frames=3, noise=0.02, traversals=2)
    mapping = ds.traversals()[0]
    lab_all, cnt_all = label_dataset(ds)
    lab_map, cnt_map = label_dataset(ds, settings=LabelSettings(counts_from="mapping"))
    for i in range(len(ds)):
        assert len(lab_map[i]) == len(ds[i])
        assert cnt_map[i].max() <= len(mapping) < cnt_all[i].max()  # never more poses than the mapping drive has
    tracked = ds.traversals()[1][1]
    assert (cnt_map[tracked] == 0).any()  # the other day's parked cars: not on the map
    assert not (lab_map[tracked] == lab_all[tracked]).all()
    with pytest.raises(ParameterError, match="counts_from"):
        label_dataset(ds, settings=LabelSettings(counts_from="future"))


def test_observation_counts_are_exact_where_many_map_points_crowd_a_scan_point():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    map_points = rng.uniform(0, 0.3, (3000, 3))  # ~100 map points within 0.1 m of any scan point
    scans = [rng.uniform(0, 0.3, (50, 3)), rng.uniform(0.2, 0.5, (50, 3))]
    brute = np.zeros(len(map_points), np.int64)
    for s in scans:
        d, _ = cKDTree(s).query(map_points, k=1)
        brute += d < 0.1
    np.testing.assert_array_equal(observation_counts(scans, map_points, 0.1), brute)


def test_the_ground_is_the_largest_level_plane_even_beside_a_larger_wall():
    from lwbench_plugins.poconet.labels import ground_mask

    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(-10, 10, (4000, 2)), rng.normal(-1.7, 0.01, 4000)])
    wall = np.column_stack([rng.uniform(-10, 10, 6000), rng.normal(5, 0.01, 6000), rng.uniform(-1.7, 8, 6000)])
    pts = np.concatenate([floor, wall])
    mask = ground_mask(pts, LabelSettings())
    assert mask[:4000].mean() > 0.99 and mask[4000:].mean() < 0.05
    np.testing.assert_array_equal(mask, ground_mask(pts, LabelSettings()))  # seeded: the same every time


def test_binary_loss_and_a_normalized_codeword_that_the_points_see():
    torch.manual_seed(0)
    cfg = NetConfig(d_out=(8, 16, 32, 32), codeword=64, output="sigmoid", context="points")
    net = PocoNet(cfg)
    logits, code = net(_batch(2048, 0, cfg))
    c = code.detach()
    assert float(c.mean().abs()) < 1e-4 and float(c.std(unbiased=False)) == pytest.approx(1.0, abs=1e-3)
    probs = net.probabilities(logits)
    assert probs.shape == (1, 2048, 3) and ((probs > 0) & (probs < 1)).all()
    labels = torch.randint(0, 3, (1, 2048))
    _, parts = siamese_loss((logits, logits), (code, code), labels, None, lam=1.0, binary=True)
    expected = torch.nn.functional.binary_cross_entropy_with_logits(
        logits.reshape(-1, 3), torch.nn.functional.one_hot(labels.reshape(-1), 3).float()
    )
    assert parts["label"] == pytest.approx(float(expected), rel=1e-5)
    net.eval()
    with torch.no_grad():
        own, _ = net(_batch(2048, 0, cfg))
        zeroed, _ = net(_batch(2048, 0, cfg), torch.zeros_like(code))
    assert (own - zeroed).abs().max() > 1e-3  # the codeword reaches the points' outputs


def test_heading_augmentation_keeps_the_driving_direction():
    from lwbench_plugins.poconet.train import augment_heading

    pts = np.array([[10.0, 0.0, 1.0]], np.float32)
    for seed in range(50):
        out = augment_heading(pts, np.random.default_rng(seed), "jitter", 10.0)[0]
        assert np.degrees(abs(np.arctan2(out[1], out[0]))) <= 10.0 + 1e-4 and out[2] == 1.0
    mirrored = [
        augment_heading(np.array([[0.0, 5.0, 0.0]], np.float32), np.random.default_rng(s))[0, 1] < 0 for s in range(50)
    ]
    assert 10 < sum(mirrored) < 40  # a mirror half the time
    np.testing.assert_array_equal(augment_heading(pts, np.random.default_rng(0), "none"), pts)


@pytest.mark.heavy
def test_poconet_ranks_by_p_high_with_spatial_balance_and_a_random_control(tmp_path):
    frame = room_scan(get_sensor("hdl64e"), seed=3, index=2)
    ranked = PocoNetSelector(ratio=1 / 12)
    control = PocoNetSelector(ratio=1 / 12, score="random")
    plain = PocoNetSelector(ratio=1 / 12, cell=0.0)
    p_high = ranked.scores(frame)
    a, b, c = ranked.select(frame), control.select(frame), plain.select(frame)
    assert len(a) == len(b) == len(c) == round(len(frame) / 12)
    assert p_high[a].mean() > p_high[b].mean()  # the network's ranking, not only the rule
    assert p_high[c].mean() >= p_high[a].mean()  # without balance: the very top scores


@pytest.mark.slow
def test_training_runs_end_to_end_and_resumes(tmp_path):
    from lwbench_plugins.poconet.train import TrainConfig, export, train

    net = NetConfig(d_out=(8, 16, 32, 32), codeword=64, output="sigmoid", context="points").as_dict()
    cfg = TrainConfig(
        out=str(tmp_path),
        drives=("urban:30",),
        val_drives=("urban:20",),
        frames=6,
        margin=1,
        val_frames=2,
        epochs=1,
        points_in=4096,
        net=net,
    )
    train(cfg)
    cfg.epochs = 2
    last = train(cfg)  # resumes at epoch 2
    import json

    curve = [json.loads(x) for x in (tmp_path / "curve.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in curve] == [1, 2] and all(np.isfinite(r["auc_high"]) for r in curve)
    assert {"gfa_swap_changed", "gfa_zero_changed", "gfa_swap_dp"} <= set(curve[-1])
    small = export(last, tmp_path / "w.pt")
    net, meta = load_checkpoint(str(small), "cpu")
    assert net.config.output == "sigmoid" and meta["train"]["counts_from"] == "mapping"
