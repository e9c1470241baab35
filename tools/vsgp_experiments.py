"""Measurements behind VSGP's defaults (``docs/vsgp.md``), runnable on any KITTI-layout folder.

    lwbench simulate tunnel --out /tmp/simtunnel --frames 50
    python tools/vsgp_experiments.py steps  /tmp/simtunnel --frames 10
    python tools/vsgp_experiments.py sweep  /tmp/simtunnel --frames 20
    python tools/vsgp_experiments.py timing /tmp/simtunnel --frames 20
    python tools/vsgp_experiments.py bodies /tmp/simtunnel --frames 10
    python tools/vsgp_experiments.py table  /tmp/simtunnel --frames 20 --m 200 300 400 500 600

A development script (not installed): the folder is any dataset lwbench loads. Each command
prints a Markdown table. Scores are lwbench's own range metrics (``lwbench_metrics.ranges``:
returns paired by direction; RMSD, coverage, false returns). Timings are medians and are also
given as a ratio to a reference workload timed in the same process (one 57,600 x 500 RQ kernel
evaluation), because this machine is shared and noisy.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from lwbench_metrics.ranges import RangeMetric, direction_coordinates, pair_by_direction
from lwbench_plugins.vsgp import VSGPCodec
from lwbench_plugins.vsgp.decoder import auto_stride, predict_grid, query_grid, variance_mask
from lwbench_plugins.vsgp.encoder import fit_scan
from lwbench_plugins.vsgp.gp import reference_seconds

from lwbench import CodecKind, Evaluation, Frame
from lwbench.registry import get_registry
from lwbench.run import resolve_dataset


def load_frames(path: str, n: int) -> list[Frame]:
    """The first ``n`` frames of any dataset lwbench loads (a path: the loader is sniffed)."""
    reg = get_registry()
    dataset = resolve_dataset(reg, path, {}, 0).build(reg)
    return [dataset[i] for i in range(min(n, len(dataset)))]


def scores(frame: Frame, decoded: np.ndarray) -> tuple[float, float, float]:
    """(range RMSD m, coverage, false returns) of a decoded cloud: lwbench's range metrics."""
    ev = Evaluation(frame, b"", np.asarray(decoded, np.float32), CodecKind.REPRESENTATION, {})
    m = RangeMetric().compute(ev)
    return (m["range_rmsd"] if m["range_rmsd"] is not None else float("nan")), m["coverage"] or 0.0, \
        m["false_returns"] or 0.0


def pointwise_errors(frame: Frame, decoded: np.ndarray) -> np.ndarray:
    """|r - r_hat| over every direction pair (the paper's pointwise statistic)."""
    p, rp = direction_coordinates(frame.points, frame.sensor)
    q, rq = direction_coordinates(decoded, frame.sensor)
    partner, _ = pair_by_direction(p, q, frame.sensor, 0.5)
    ok = partner >= 0
    return np.abs(rp[ok] - rq[partner[ok]])


def grid_cloud(frame: Frame, keep: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The cloud a variance mask keeps on the sensor's grid (cell-centre rays)."""
    return frame.sensor.unproject(np.where(keep, r, 0.0).astype(np.float32))


def cmd_steps(frames: list[Frame], args: argparse.Namespace) -> None:
    print("| max steps | steps run (mean) | bound / point | encode s (median) | refine s | range RMSD cm "
          "| coverage |")
    print("|---|---|---|---|---|---|---|")
    for steps in args.steps:
        rows = []
        for fr in frames:
            codec = VSGPCodec(**{**args.param, "steps": steps, "tol": args.tol, "device": "cpu"})
            t = time.perf_counter()
            data = codec.encode(fr)
            enc = time.perf_counter() - t
            tim = dict(codec.last_timings)
            rm, cov, _ = scores(fr, codec.decode(data))
            ranges = fr.sensor.project(fr.points).ranges
            res = fit_scan(ranges, fr.sensor, fr.sensor.max_range, codec.fit_config(),
                           torch.device("cpu")) if args.bound else None
            b = res.bounds[-1] if res is not None and res.bounds else float("nan")
            rows.append((tim["steps_run"], b, enc, tim["refine"], rm, cov))
        o = np.array(rows)
        print(f"| {steps} | {o[:, 0].mean():.1f} | {np.nanmean(o[:, 1]):.3f} | {np.median(o[:, 2]):.3f} | "
              f"{np.median(o[:, 3]):.3f} | {100 * o[:, 4].mean():.2f} ± {100 * o[:, 4].std():.2f} | "
              f"{o[:, 5].mean():.3f} |")


def cmd_sweep(frames: list[Frame], args: argparse.Namespace) -> None:
    """Variance threshold sweep: predict once per frame, then score every (K_m, K_std)."""
    cache = []
    for fr in frames:
        s = fr.sensor
        ranges = s.project(fr.points).ranges
        res = fit_scan(ranges, s, s.max_range, VSGPCodec(**args.param).fit_config(), torch.device("cpu"))
        az, el = query_grid(s, 1)
        stride = auto_stride(res.hyper, az[1] - az[0])
        mean, var = predict_grid(res.z, res.u, res.hyper, az, el, stride, torch.device("cpu"))
        cache.append((fr, s.max_range - mean, var, res.hyper.outputscale))
    results = []
    for v_floor in args.v_floor:
        for k_m in args.k_m:
            for k_std in args.k_std:
                rows = []
                for fr, r, var, scale in cache:
                    keep = variance_mask(var, k_m, k_std, v_floor * scale)
                    keep &= (r >= fr.sensor.min_range) & (r < fr.sensor.max_range)
                    rows.append(scores(fr, grid_cloud(fr, keep, r)))
                o = np.array(rows)
                results.append((v_floor, k_m, k_std, *np.nanmean(o, 0), o[:, 1].min()))
    print("| v_floor | K_m | K_std | range RMSD cm | coverage (mean) | coverage (worst frame) "
          "| false returns |")
    print("|---|---|---|---|---|---|---|")
    for v_floor, k_m, k_std, rm, cov, fa, cmin in results:
        print(f"| {v_floor:g} | {k_m:g} | {k_std:g} | {100 * rm:.2f} | {cov:.3f} | {cmin:.3f} | {fa:.3f} |")
    ok = [r for r in results if r[6] >= args.min_coverage]
    if ok:
        best = min(ok, key=lambda r: (round(r[5], 3), round(r[3], 4)))
        print(f"\nfewest false returns with every frame's coverage >= {args.min_coverage}: "
              f"v_floor={best[0]:g} K_m={best[1]:g} K_std={best[2]:g}")


def cmd_timing(frames: list[Frame], args: argparse.Namespace) -> None:
    ref = reference_seconds()
    enc_stages = ["projection", "layout", "refine", "fit", "serialize"]
    dec_stages = ["parse", "predict", "sampling"]
    for m in args.m:
        codec = VSGPCodec(**{**args.param, "num_inducing": m, "steps": args.steps[0], "device": "cpu"})
        codec.decode(codec.encode(frames[0]))  # warm-up
        e_rows, d_rows, enc, dec = [], [], [], []
        for fr in frames:
            t = time.perf_counter()
            data = codec.encode(fr)
            enc.append(time.perf_counter() - t)
            e_rows.append([codec.last_timings[k] for k in enc_stages])
            t = time.perf_counter()
            codec.decode(data)
            dec.append(time.perf_counter() - t)
            d_rows.append([codec.last_timings[k] for k in dec_stages])
        e = np.median(np.array(e_rows), 0)
        d = np.median(np.array(d_rows), 0)
        print(f"\nM={m}, steps={args.steps[0]}, {len(frames)} frames, "
              f"torch threads={torch.get_num_threads()}, "
              f"reference (57,600x500 RQ kernel) = {ref * 1000:.1f} ms\n")
        print("| stage | median ms | x reference |")
        print("|---|---|---|")
        for k, v in zip(enc_stages + dec_stages, list(e) + list(d), strict=True):
            print(f"| {k} | {1000 * v:.1f} | {v / ref:.2f} |")
        print(f"| **encode total** | {1000 * np.median(enc):.1f} | {np.median(enc) / ref:.2f} |")
        print(f"| **decode total** | {1000 * np.median(dec):.1f} | {np.median(dec) / ref:.2f} |")


def cmd_bodies(frames: list[Frame], args: argparse.Namespace) -> None:
    print("| body | bytes (mean) | range RMSD cm | extra RMSD vs float32 (mm) | coverage |")
    print("|---|---|---|---|---|")
    base = None
    for fmt in ("float32", "float16", "q16", "q16z"):
        rows = []
        for fr in frames:
            codec = VSGPCodec(**{**args.param, "body": fmt, "steps": args.steps[0], "device": "cpu"})
            data = codec.encode(fr)
            rows.append((len(data), *scores(fr, codec.decode(data))))
        o = np.array(rows)
        base = o[:, 1] if base is None else base
        extra = 1000 * (o[:, 1] - base).mean()
        print(f"| {fmt} | {o[:, 0].mean():.0f} | {100 * o[:, 1].mean():.2f} | {extra:.2f} | "
              f"{o[:, 2].mean():.3f} |")


def cmd_table(frames: list[Frame], args: argparse.Namespace) -> None:
    """Per-M accuracy with the paper's pointwise statistic too: mean and std of |r - r_hat|
    over every direction pair, pooled over frames (Table I's "9 +- 10 cm" reads so)."""
    print("| M | bytes | range RMSD cm (mean ± std over frames) | pointwise abs error cm (mean ± std) | "
          "coverage | false returns |")
    print("|---|---|---|---|---|---|")
    for m in args.m:
        codec = VSGPCodec(**{**args.param, "num_inducing": m, "device": "cpu"})
        sizes, rms, errs, covs, fas = [], [], [], [], []
        for fr in frames:
            data = codec.encode(fr)
            out = codec.decode(data)
            errs.append(pointwise_errors(fr, out))
            rm, cov, fa = scores(fr, out)
            sizes.append(len(data))
            rms.append(rm)
            covs.append(cov)
            fas.append(fa)
        e = np.concatenate(errs) * 100
        r = np.array(rms) * 100
        print(f"| {m} | {np.mean(sizes):.0f} | {r.mean():.1f} ± {r.std():.1f} | "
              f"{e.mean():.1f} ± {e.std():.1f} | "
              f"{np.mean(covs):.3f} | {np.mean(fas):.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=["steps", "sweep", "timing", "bodies", "table"])
    ap.add_argument("folder")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    ap.add_argument("--steps", type=int, nargs="+", default=[0, 1, 2, 5, 10, 20])
    ap.add_argument("--tol", type=float, default=0.0)
    ap.add_argument("--bound", action="store_true", help="also report the final bound (refits)")
    ap.add_argument("--k-m", type=float, nargs="+", default=[0.1, 0.2, 0.3, 0.5, 0.7, 1.0])
    ap.add_argument("--k-std", type=float, nargs="+", default=[0.0, 0.25, 0.5, 1.0])
    ap.add_argument("--v-floor", type=float, nargs="+", default=[0.0, 0.01, 0.03, 0.1])
    ap.add_argument("--min-coverage", type=float, default=0.95)
    ap.add_argument("--m", type=int, nargs="+", default=[500])
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                    help="a vsgp codec parameter for every run (repeatable)")
    args = ap.parse_args()
    args.param = dict(kv.split("=", 1) for kv in args.param)
    if args.threads:
        torch.set_num_threads(args.threads)
    frames = load_frames(args.folder, args.frames)
    commands = {"steps": cmd_steps, "sweep": cmd_sweep, "timing": cmd_timing, "bodies": cmd_bodies,
                "table": cmd_table}
    commands[args.command](frames, args)


if __name__ == "__main__":
    main()
