"""The noise floor (lwbench.noise_floor): the entropy of Gaussian range noise at a step, the
return mask's bits, the floor curve against range RMSD, and where rd and the report show it."""

from __future__ import annotations

import lzma
import math
import types

import numpy as np
import pytest
from typer.testing import CliRunner

from lwbench import (
    GAUSSIAN_ENTROPY_BITS,
    floor_bits_per_point,
    gaussian_step_bits,
    get_sensor,
    mask_bits,
    quantized_gaussian_bits,
    scan_floor,
    step_for_rmsd,
)
from lwbench.cli import app
from lwbench.noise_floor import FloorIds, draw_floor, entry_floor, floor_lines, print_floor
from lwbench.plotting import pyplot
from lwbench.registry import get_registry
from lwbench.results.leaderboard import build_leaderboard
from lwbench.results.store import ResultStore
from lwbench.run import DatasetRequest, RunRequest, Study
from lwbench.testing import tunnel_scan


def _empirical_bits(values: np.ndarray) -> float:
    _, counts = np.unique(values, return_counts=True)
    p = counts / counts.sum()
    return float(-(p * np.log2(p)).sum())


def test_the_constant_is_the_differential_entropy_of_a_unit_gaussian():
    assert GAUSSIAN_ENTROPY_BITS == pytest.approx(0.5 * math.log2(2 * math.pi * math.e), abs=1e-15)
    assert GAUSSIAN_ENTROPY_BITS == pytest.approx(2.0471, abs=1e-4)
    assert gaussian_step_bits(0.02, 0.001) == pytest.approx(math.log2(20) + GAUSSIAN_ENTROPY_BITS)


@pytest.mark.parametrize("ratio", [0.05, 0.1, 0.5, 1.0, 2.0, 4.0])
def test_the_exact_sum_is_the_entropy_of_quantized_gaussian_samples(ratio):
    """Draw 400k Gaussian values, round them to the step: their empirical entropy is the sum's."""
    sigma = 0.03
    x = np.random.default_rng(1).normal(0.0, sigma, 400_000)
    codes = np.round(x / (ratio * sigma)).astype(np.int64)
    assert _empirical_bits(codes) == pytest.approx(quantized_gaussian_bits(sigma, ratio * sigma), abs=0.01)


def test_the_closed_form_is_the_fine_step_limit_and_the_sum_never_goes_negative():
    for ratio in (1e-4, 1e-3, 0.01, 0.1):
        assert quantized_gaussian_bits(1.0, ratio) == pytest.approx(gaussian_step_bits(1.0, ratio), abs=1e-3)
    assert quantized_gaussian_bits(1.0, 1.0) - gaussian_step_bits(1.0, 1.0) == pytest.approx(0.058, abs=0.002)
    steps = np.geomspace(1e-3, 100.0, 40)
    bits = [quantized_gaussian_bits(1.0, s) for s in steps]
    assert all(b >= 0 for b in bits) and all(a >= b for a, b in zip(bits, bits[1:], strict=False))
    assert all(a > b for a, b in zip(bits[:30], bits[1:30], strict=False))  # strictly, up to ~10 sigma
    assert gaussian_step_bits(1.0, 10.0) < 0 < quantized_gaussian_bits(1.0, 10.0) < 1e-4
    with pytest.raises(ValueError):
        quantized_gaussian_bits(0.0, 0.01)


def test_sqrt12_maps_a_uniform_steps_error_to_its_rmsd():
    x = np.random.default_rng(2).uniform(0, 100, 200_000)
    step = 0.01
    rmsd = float(np.sqrt(np.mean((np.round(x / step) * step - x) ** 2)))
    assert step_for_rmsd(rmsd) == pytest.approx(step, rel=0.01)


def test_a_real_coder_of_quantized_noise_stays_above_the_floor():
    """lzma on the quantized noise of 200k returns: at least the entropy, and near it."""
    sigma, step = 0.02, 0.002
    codes = np.round(np.random.default_rng(3).normal(0, sigma, 200_000) / step).astype(np.int8)
    coded = 8 * len(lzma.compress(codes.tobytes(), preset=9)) / len(codes)
    floor = quantized_gaussian_bits(sigma, step)
    assert floor < coded < floor + 1.0


def test_mask_bits_measure_structure_and_are_bounded_by_the_fill_ratio():
    full = np.ones((16, 1800), dtype=bool)
    assert mask_bits(full).bits == 0 and mask_bits(full).fill == 1
    rng = np.random.default_rng(4)
    coins = rng.random((16, 1800)) < 0.3
    m = mask_bits(coins)
    # i.i.d. bits: the context model cannot beat the binary entropy of the fill ratio (~0.881 bit)
    assert m.bits <= m.bound_bits
    assert m.bits / m.cells == pytest.approx(0.881, abs=0.01)
    sky = np.zeros((16, 1800), dtype=bool)
    sky[:10] = True  # the lower beams return, the upper ones see the sky
    sky[:10, rng.integers(0, 1800, 40)] = False
    s = mask_bits(sky)
    assert s.bits < 0.2 * s.bound_bits
    with pytest.raises(ValueError):
        mask_bits(np.ones(5, dtype=bool))


def test_the_floor_of_a_scan_follows_its_sensor_model_and_its_own_mask():
    frame = tunnel_scan(seed=0, dropout=0.05)
    floor = scan_floor(frame)
    assert floor.sigma == get_sensor("vlp16").range_noise_m
    assert floor.points == len(frame.points)
    assert floor.mask.returns == len(frame.points)  # one return per cell: the scan is on the grid
    assert 0 < floor.mask_bpp < floor.mask.bound_bits / floor.points
    # mask + the noise at sqrt(12) * RMSD; an exact RMSD has no finite floor
    d = 0.001
    assert floor.bits_per_point(d) == pytest.approx(floor.mask_bpp + quantized_gaussian_bits(0.03, math.sqrt(12) * d))
    assert floor.bits_per_point(0.0) is None and floor_bits_per_point(None, 0.03, 0.1) is None
    assert floor.bits_per_point(0.0005) > floor.bits_per_point(0.005) > floor.bits_per_point(0.05) > floor.mask_bpp


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("floor") / "rd.sqlite"
    reg = get_registry()
    request = RunRequest(datasets=(DatasetRequest("sim"),), frames=1, codecs=("raw", "rangeimage", "draco"),
                         sweeps={"rangeimage": {"step": [0.01, 0.05]}},
                         sequence_metrics=False, isolate=False, store=path)
    Study.prepare(request, reg).run()
    return path


#: The ids the floor reads, found by the quantities the installed metrics declare.
IDS = FloorIds.from_info(get_registry().metric_info())


def test_the_floor_finds_its_ids_by_declared_quantity_not_by_name():
    """Core knows no metric by name: a metric plugin that stores the same quantities under other
    ids gets the floor; one that does not declare them gets no floor line (and no error)."""
    from lwbench import MetricId

    assert IDS == FloorIds("range_rmsd", "bits_per_point", "points_in", "floor_sigma", "floor_mask_bpp")
    renamed = {i: MetricId(i, quantity=q) for i, q in [
        ("err_rms", "range_error_rms"), ("bpp", "rate_bits_per_point"), ("n", "input_points"),
        ("sigma", "range_noise_sigma"), ("mask", "mask_bits_per_point")]}
    assert FloorIds.from_info(renamed) == FloorIds("err_rms", "bpp", "n", "sigma", "mask")
    values = {"err_rms": 0.005, "sigma": 0.03, "mask": 0.2, "bpp": 9.0}
    entry = types.SimpleNamespace(dataset="d", label="c", flags=[], value=lambda k, s="mean": values.get(k))
    lines: list[str] = []
    print_floor([entry], None, renamed, lines.append)
    assert lines and "bits/point at each err_rms" in lines[0]
    without_mask = {i: m for i, m in renamed.items() if i != "mask"}
    assert FloorIds.from_info(without_mask) is None
    lines.clear()
    print_floor([entry], None, without_mask, lines.append)
    assert lines == []
    with pytest.raises(ValueError, match="quantity"):
        MetricId("x", quantity="loudness")


def _entries(store):
    with ResultStore(store, readonly=True) as results:
        return build_leaderboard(results, info=get_registry().metric_info())


@pytest.mark.heavy
def test_rows_carry_the_floor_inputs_and_rd_prints_the_floor(store):
    entries = _entries(store)
    coarse = next(e for e in entries if e.label == "rangeimage(step=0.05)")
    assert coarse.value("floor_sigma") == 0.01  # the noise the simulator adds, not the VLP-16's 3 cm
    expected = floor_bits_per_point(coarse.value("range_rmsd"), 0.01, coarse.value("floor_mask_bpp"))
    assert entry_floor(coarse, IDS) == pytest.approx(expected)
    res = CliRunner().invoke(app, ["rd", "--store", str(store)], catch_exceptions=False, env={"COLUMNS": "400"})
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())  # the console wraps long lines
    line = text[text.index("floor on sim") :]
    gap = coarse.value("bits_per_point") - expected
    assert " ".join(f"rangeimage(step=0.05) {expected:.2f} ({gap:+.2f})".split()) in line
    assert "raw exact (no finite floor)" in line
    assert floor_lines(entries, IDS)[0].startswith("floor on sim")


@pytest.mark.heavy
def test_the_report_draws_the_floor_on_every_rd_plot(store, tmp_path, monkeypatch):
    import lwbench.results.report as report

    labels: dict[str, list[str]] = {}
    real_save = report.save_png_svg

    def keep_labels(fig, out, name):
        labels[name] = [line.get_label() for line in fig.axes[0].get_lines()]
        return real_save(fig, out, name)

    monkeypatch.setattr(report, "save_png_svg", keep_labels)
    figures = report.rd_figures(_entries(store), get_registry().metric_info(), tmp_path)
    assert figures and {f.name for f in figures} == set(labels)
    for name, drawn in labels.items():
        assert "noise floor" in drawn, (name, drawn)


def test_the_floor_curve_sits_below_the_codecs_at_their_distortions(store):
    entries = [e for e in _entries(store) if not e.flags and (e.value("range_rmsd") or 0) > 0]
    plt = pyplot()
    fig, ax = plt.subplots()
    assert draw_floor(ax, entries, "range_rmsd", "bits_per_point", IDS)
    (line,) = [x for x in ax.get_lines() if x.get_label() == "noise floor"]
    x, y = line.get_data()
    for e in entries:
        at = np.interp(np.log(e.value("range_rmsd")), np.log(y), x)
        assert at == pytest.approx(entry_floor(e, IDS), rel=0.02)
    empty = types.SimpleNamespace(flags=[], value=lambda k, s="mean": None)
    assert not draw_floor(ax, [empty], "chamfer", "bytes", IDS)
    plt.close(fig)


def test_the_simulator_declares_the_noise_it_adds():
    # Issue 33: it added 1 cm and declared the preset's 3 cm, so rangeimage sat 0.3-0.6 bit/point
    # *below* the floor, silently.
    from lwbench import open_dataset

    for noise in (0.01, 0.025):
        ds = open_dataset("sim", {"frames": 2, "noise": noise, "cache": "false"})
        assert ds.sensor.range_noise_m == noise and ds[1].sensor.range_noise_m == noise


def test_a_codec_below_the_floor_is_called_out():
    def entry(label, bpp):
        values = {"range_rmsd": 0.005, "floor_sigma": 0.03, "floor_mask_bpp": 0.2, "bits_per_point": bpp}
        return types.SimpleNamespace(dataset="sim", label=label, flags=[], value=lambda k, s="mean": values.get(k))

    floor = floor_bits_per_point(0.005, 0.03, 0.2)
    (line,) = floor_lines([entry("above", floor + 1.0), entry("below", floor - 0.4)], IDS)
    above, below = line.split("; ")[-2:]
    assert "BELOW THE FLOOR" not in above and "BELOW THE FLOOR" in below and "declared range noise" in below


def test_on_other_distortions_the_floor_is_points_not_a_line_across_codecs(store):
    entries = [e for e in _entries(store) if not e.flags and (e.value("range_rmsd") or 0) > 0]
    plt = pyplot()
    fig, ax = plt.subplots()
    assert draw_floor(ax, entries, "chamfer", "bytes", IDS)
    (line,) = [x for x in ax.get_lines() if x.get_label() == "noise floor"]
    assert line.get_linestyle() == "None" and len(line.get_xdata()) == len(entries)
    plt.close(fig)


def test_a_plot_where_every_point_is_exact_is_left_out_not_drawn_empty(store, tmp_path):
    # Issue 33: an empty range_rmsd plot (and matplotlib's "No artists with labels" warning) for a
    # sweep whose points are all exact or undefined there.
    import warnings

    import lwbench.results.report as report

    exact = [e for e in _entries(store) if e.codec == "raw"]
    assert exact and all(e.value("range_rmsd") == 0 for e in exact)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures = report.rd_figures(exact, get_registry().metric_info(), tmp_path)
    assert not any(f.name.startswith("rd_range_rmsd") for f in figures)
