"""Every configuration of a store against the noise floor, as the markdown table of README.md and
docs/codecs.md: bytes, bits per point, range RMSD, D1 PSNR, coverage, the floor's bits per point
at the configuration's range RMSD and its distance to it (``lwbench.noise_floor``).

    python tools/floor_table.py STORE [--dataset NAME]
    python tools/floor_table.py --curve DATASET [--dataset-param KEY=VALUE ...] [--sigma M]

``--curve`` prints the floor itself for the first frame of a dataset (as ``lwbench run`` would
read it): the mask's bits, measured and bounded, and the floor at a few range RMSDs.

The rows come from ``lwbench run`` (``lwbench run --config examples/runs/floor_rd.toml`` runs the
README's, into ``lwbench-results/floor_rd.sqlite``); a flagged configuration (low coverage) is
listed with its flag, since the floor -- the floor of a codec that keeps every return -- does not
bound it.
"""

from __future__ import annotations

import argparse
import math

from lwbench.noise_floor import (
    FloorIds,
    entry_floor,
    floor_bits_per_point,
    gaussian_step_bits,
    quantized_gaussian_bits,
    scan_floor,
    step_for_rmsd,
)
from lwbench.registry import get_registry
from lwbench.results.leaderboard import build_leaderboard
from lwbench.results.store import ResultStore


def _fmt(v: float | None, spec: str) -> str:
    if v is None:
        return "–"
    if math.isinf(v):
        return "inf"
    return format(v, spec)


def curve(dataset: str, words: list[str], sigma: float | None) -> None:
    from lwbench import open_dataset

    frame = open_dataset(dataset, words)[0]
    floor = scan_floor(frame)
    sigma = sigma or floor.sigma
    m = floor.mask
    print(
        f"{dataset} {' '.join(words)}: sensor {frame.sensor.name} {frame.sensor.shape[0]} x {frame.sensor.shape[1]}, "
        f"{floor.points:,} points, {m.returns:,} cells returned (fill {m.fill:.3f}); sigma {1000 * sigma:.3g} mm"
    )
    print(
        f"mask: {floor.mask_bpp:.3f} bit/point measured (order-2 context), "
        f"{m.bound_bits / floor.points:.3f} bit/point bound (binary entropy of the fill ratio)"
    )
    print("| range RMSD (mm) | step sqrt(12)*RMSD (mm) | noise (bits/return) | closed form | floor (bits/point) |")
    print("|---|---|---|---|---|")
    for d in (0.0001, 0.0003, 0.001, 0.003, 0.01, 0.03):
        step = step_for_rmsd(d)
        print(
            f"| {1000 * d:g} | {1000 * step:.3g} | {quantized_gaussian_bits(sigma, step):.3f} "
            f"| {gaussian_step_bits(sigma, step):.3f} | {floor_bits_per_point(d, sigma, floor.mask_bpp):.3f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store", nargs="?")
    ap.add_argument("--dataset", default=None)
    ap.add_argument("--curve", default=None, help="a dataset: print its first frame's floor")
    ap.add_argument("--dataset-param", action="append", default=[])
    ap.add_argument("--sigma", type=float, default=None, help="range noise (m) instead of the sensor model's")
    args = ap.parse_args()
    if args.curve:
        curve(args.curve, args.dataset_param, args.sigma)
        return
    if not args.store:
        ap.error("give a STORE or --curve DATASET")
    reg = get_registry()
    with ResultStore(args.store, readonly=True) as store:
        entries = build_leaderboard(store, dataset=args.dataset, info=reg.metric_info(), sort="bits_per_point")
    ids = FloorIds.from_info(reg.metric_info())
    if ids is None:
        ap.error("the installed metrics do not declare the noise floor's quantities")
    print(
        "| dataset | codec | bytes | bits/point | range RMSD (mm) | D1 PSNR (dB) | coverage | floor (bits/point) "
        "| distance to the floor (bits/point) | flags |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for e in sorted(entries, key=lambda e: (e.dataset, e.value("bits_per_point") or math.inf)):
        floor, bpp, rmsd = entry_floor(e, ids), e.value("bits_per_point"), e.value("range_rmsd")
        if e.flags:  # the floor of a codec that keeps every return does not bound a flagged one
            floor = None
        gap = None if floor is None or bpp is None else bpp - floor
        exact = rmsd == 0 and not e.flags
        print(
            f"| {e.dataset} | {e.label} | {_fmt(e.value('bytes'), ',.0f')} | {_fmt(bpp, '.2f')} "
            f"| {_fmt(None if rmsd is None else 1000 * rmsd, '.3g')} | {_fmt(e.value('d1_psnr'), '.1f')} "
            f"| {_fmt(e.value('coverage'), '.3f')} | {'exact' if exact else _fmt(floor, '.2f')} "
            f"| {'–' if exact else _fmt(gap, '+.2f')} | {e.flags_text} |"
        )
    for ds in sorted({e.dataset for e in entries}):
        e = next(x for x in entries if x.dataset == ds and x.value("floor_sigma") is not None)
        print(
            f"\n{ds}: sigma {1000 * e.value('floor_sigma'):.3g} mm, mask {e.value('floor_mask_bpp'):.3f} bit/point, "
            f"{e.value('points_in'):,.0f} points per frame"
        )


if __name__ == "__main__":
    main()
