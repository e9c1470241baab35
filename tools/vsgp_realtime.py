"""Issue 19's figures for VSGP: speed against a float64 reference, accuracy, rate-distortion,
warm starts. Every command prints Markdown; speeds are medians and ratios to the reference
workload timed in the same process, interleaved with the codec's calls (the machine is shared).

    lwbench simulate tunnel --out /tmp/simtunnel --frames 50
    python tools/vsgp_realtime.py speed /tmp/simtunnel --frames 20
    python tools/vsgp_realtime.py speed ../shared/data/real/kitti00_frames0-1 --param bytes=50000
    python tools/vsgp_realtime.py table /tmp/simtunnel --frames 50 --m 200 300 400 500 600
    python tools/vsgp_realtime.py rd ../shared/data/real/kitti00_frames0-1 --vsgp bytes=20000,40000,80000 \
        --rangeimage step=0.05,0.1,0.2,0.4
    python tools/vsgp_realtime.py warm /tmp/simtunnel --frames 40 --param mode=paper
    python tools/vsgp_realtime.py threshold /tmp/simurban --frames 6 --v-floor 0.03 0.1 0.2
    python tools/vsgp_realtime.py errors ../shared/data/real/kitti00_frames0-1 --param body=q16z --param bytes=50000

``--param KEY=VALUE`` sets a vsgp parameter for every call (repeatable). The scores are lwbench's
own range metrics (``lwbench_metrics.ranges``); the reference is :func:`reference_seconds` (a
57,600 x 500 float64 RQ kernel by ``|x|^2 + |z|^2 - 2 X Z^T`` in numpy, the workload issue 19 names).
A development script (not installed).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from lwbench_metrics.ranges import RangeMetric
from lwbench_plugins.vsgp import VSGPCodec
from lwbench_plugins.vsgp.gp import reference_seconds

from lwbench import CodecKind, Evaluation, Frame
from lwbench.registry import get_registry
from lwbench.run import resolve_dataset


def load_frames(path: str, n: int) -> list[Frame]:
    reg = get_registry()
    dataset = resolve_dataset(reg, path, {}, 0).build(reg)
    return [dataset[i] for i in range(min(n, len(dataset)))]


def scores(frame: Frame, decoded: np.ndarray) -> tuple[float, float, float]:
    """(range RMSD m, coverage, false returns)."""
    ev = Evaluation(frame, b"", np.asarray(decoded, np.float32), CodecKind.REPRESENTATION, {})
    m = RangeMetric().compute(ev)
    rm = m["range_rmsd"] if m["range_rmsd"] is not None else float("nan")
    return rm, m["coverage"] or 0.0, m["false_returns"] or 0.0


def parse_params(items: list[str]) -> dict[str, str]:
    return dict(kv.split("=", 1) for kv in items)


def _load() -> str:
    return "load average " + " / ".join(f"{x:.2f}" for x in os.getloadavg())


def codec_class(old: bool) -> type:
    """This checkout's VSGPCodec, or (``old``) the one of a package ``vsgp_old`` on the path --
    e.g. main's plugin copied there -- for before/after rows from one process."""
    if not old:
        return VSGPCodec
    import vsgp_old

    return vsgp_old.VSGPCodec


def measure(frames: list[Frame], params: dict, repeats: int = 1, old: bool = False) -> dict[str, float]:
    """Median encode/decode seconds (after a warm-up), reference seconds interleaved, scores."""
    codec = codec_class(old)(**{"device": "cpu", **params})
    codec.decode(codec.encode(frames[0]))  # warm-up: imports, allocator
    enc, dec, refs, rows, stages = [], [], [], [], []
    for fr in frames:
        refs.append(reference_seconds(repeats=1))
        best_e, best_d = np.inf, np.inf
        for _ in range(repeats):
            t = time.perf_counter()
            data = codec.encode(fr)
            best_e = min(best_e, time.perf_counter() - t)
            stage = dict(codec.last_timings)
            t = time.perf_counter()
            out = codec.decode(data)
            best_d = min(best_d, time.perf_counter() - t)
            stage.update(codec.last_timings)
        enc.append(best_e)
        dec.append(best_d)
        stages.append(stage)
        rows.append((len(data), fr.raw_bytes / len(data), *scores(fr, out)))
    o = np.array(rows)
    ref = float(np.median(refs))
    keys = [k for k in stages[0] if k in _STAGES]
    return {
        "stages": {k: float(np.median([st.get(k, np.nan) for st in stages])) for k in keys},
        "ref": ref,
        "enc": float(np.median(enc)),
        "dec": float(np.median(dec)),
        "bytes": o[:, 0].mean(),
        "ratio": o[:, 1].mean(),
        "rmsd": float(np.nanmean(o[:, 2])),
        "rmsd_std": float(np.nanstd(o[:, 2])),
        "coverage": o[:, 3].mean(),
        "false": o[:, 4].mean(),
        "worst_cov": o[:, 3].min(),
    }


_STAGES = ("projection", "layout", "refine", "fit", "residual", "serialize", "parse", "predict", "sampling")


def _row(label: str, r: dict[str, float]) -> str:
    return (
        f"| {label} | {1000 * r['enc']:.1f} | {r['enc'] / r['ref']:.3f} | {1000 * r['dec']:.1f} | "
        f"{r['dec'] / r['ref']:.3f} | {1000 * r['ref']:.0f} | {r['bytes']:,.0f} | {r['ratio']:.1f} | "
        f"{100 * r['rmsd']:.2f} ± {100 * r['rmsd_std']:.2f} | {r['coverage']:.4f} | {r['false']:.4f} |"
    )


_HEAD = (
    "| setting | encode ms | × ref | decode ms | × ref | ref ms | bytes | ratio | range RMSD cm | coverage "
    "| false returns |\n|---|---|---|---|---|---|---|---|---|---|---|"
)


def cmd_speed(args: argparse.Namespace) -> None:
    frames = load_frames(args.folder, args.frames)
    print(f"{args.folder}: {len(frames)} frames, {_load()}\n")
    print(_HEAD)
    settings = args.setting or [""]
    stages = []
    for s in settings:
        old = s.startswith("old:")
        s = s.removeprefix("old:")
        params = {**args.param, **parse_params([kv for kv in s.split(",") if kv])}
        r = measure(frames, params, args.repeats, old)
        print(_row(("main: " if old else "") + (s or "defaults"), r), flush=True)
        stages.append((("main: " if old else "") + (s or "defaults"), r))
    print("\nmedian ms per stage (x reference):\n")
    for label, r in stages:
        parts = ", ".join(f"{k} {1000 * v:.1f} ({v / r['ref']:.3f})" for k, v in r["stages"].items())
        print(f"- {label}: {parts}")
    print(f"\n{_load()}")


def cmd_table(args: argparse.Namespace) -> None:
    frames = load_frames(args.folder, args.frames)
    print(f"{args.folder}: {len(frames)} frames, {_load()}\n")
    print(_HEAD)
    for m in args.m:
        r = measure(frames, {**args.param, "num_inducing": m})
        print(_row(f"M={m}", r), flush=True)


def _rangeimage_points(frames: list[Frame], params: dict) -> list[tuple[int, float, float, float]]:
    cls = get_registry().codec("rangeimage")
    out = []
    for fr in frames:
        codec = cls(**params)
        data = codec.encode(fr)
        out.append((len(data), *scores(fr, cls(**params).use_sensors([fr.sensor]).decode(data))))
    return out


def _sweep(spec: str) -> list[dict[str, str]]:
    """``key=v1,v2,...`` -> one parameter dict per value."""
    key, values = spec.split("=", 1)
    return [{key: v} for v in values.split(",")]


def cmd_rd(args: argparse.Namespace) -> None:
    """Bytes vs range RMSD for vsgp and rangeimage over parameter sweeps on the same frames."""
    frames = load_frames(args.folder, args.frames)
    print(f"{args.folder}: {len(frames)} frames, {_load()}\n")
    print("| codec | setting | bytes | ratio | range RMSD cm | coverage | false returns |")
    print("|---|---|---|---|---|---|---|")
    for spec in args.vsgp:
        for p in _sweep(spec):
            codec = VSGPCodec(**{"device": "cpu", **args.param, **p})
            rows = []
            for fr in frames:
                data = codec.encode(fr)
                rows.append((len(data), *scores(fr, codec.decode(data))))
            o = np.array(rows)
            ratio = np.mean([f.raw_bytes for f in frames]) / o[:, 0].mean()
            print(
                f"| vsgp | {p} | {o[:, 0].mean():,.0f} | {ratio:.1f} | {100 * np.nanmean(o[:, 1]):.2f} | "
                f"{o[:, 2].mean():.3f} | {o[:, 3].mean():.3f} |",
                flush=True,
            )
    for spec in args.rangeimage:
        for p in _sweep(spec):
            o = np.array(_rangeimage_points(frames, p))
            ratio = np.mean([f.raw_bytes for f in frames]) / o[:, 0].mean()
            print(
                f"| rangeimage | {p} | {o[:, 0].mean():,.0f} | {ratio:.1f} | {100 * np.nanmean(o[:, 1]):.2f} | "
                f"{o[:, 2].mean():.3f} | {o[:, 3].mean():.3f} |",
                flush=True,
            )


def cmd_threshold(args: argparse.Namespace) -> None:
    """The variance filter's floor: each frame encoded once, decoded with every ``--v-floor``."""
    frames = load_frames(args.folder, args.frames)
    print(f"{args.folder}: {len(frames)} frames, {_load()}\n")
    print("| v_floor | range RMSD cm | coverage (mean) | coverage (worst frame) | false returns |")
    print("|---|---|---|---|---|")
    payloads = [VSGPCodec(**{"device": "cpu", **args.param}).encode(fr) for fr in frames]
    for v in args.v_floor:
        codec = VSGPCodec(device="cpu", v_floor=v).use_sensors([fr.sensor for fr in frames])
        o = np.array([scores(fr, codec.decode(data)) for fr, data in zip(frames, payloads, strict=True)])
        print(
            f"| {v:g} | {100 * np.nanmean(o[:, 0]):.2f} | {o[:, 1].mean():.4f} | {o[:, 1].min():.4f} | "
            f"{o[:, 2].mean():.4f} |",
            flush=True,
        )


def cmd_warm(args: argparse.Namespace) -> None:
    """Cold (every frame alone) vs warm (the previous frame's state) encodes of a sequence, in
    order; the payloads of both decode alone."""
    frames = load_frames(args.folder, args.frames)
    print(f"{args.folder}: {len(frames)} frames, {_load()}\n")
    print("| start | steps run (mean) | encode ms (median) | × ref | range RMSD cm | coverage |")
    print("|---|---|---|---|---|---|")
    for warm in (False, True):
        codec = VSGPCodec(**{"device": "cpu", **args.param, "warm_start": warm})
        codec.encode(frames[0])
        codec.reset_stream()
        enc, refs, rows, steps = [], [], [], []
        for fr in frames:
            refs.append(reference_seconds(repeats=1))
            t = time.perf_counter()
            data = codec.encode(fr)
            enc.append(time.perf_counter() - t)
            steps.append(codec.last_timings.get("steps_run", 0.0))
            rows.append(scores(fr, VSGPCodec(**{"device": "cpu", **args.param}).use_sensors([fr.sensor]).decode(data)))
        o = np.array(rows)
        ref = float(np.median(refs))
        print(
            f"| {'warm' if warm else 'cold'} | {np.mean(steps):.1f} | {1000 * np.median(enc):.1f} | "
            f"{np.median(enc) / ref:.3f} | {100 * np.nanmean(o[:, 0]):.2f} | {o[:, 1].mean():.4f} |",
            flush=True,
        )


def cmd_errors(args: argparse.Namespace) -> None:
    """Where the range RMSD comes from: percentiles of ``|r - r_hat|`` over the metric's pairs
    and the share of the squared error carried by the worst 5 % of them."""
    from lwbench_metrics.ranges import direction_coordinates, match_returns

    frames = load_frames(args.folder, args.frames)
    print(f"{args.folder}: {len(frames)} frames, {_load()}\n")
    print("| frame | pairs | RMSD cm | median cm | p75 | p90 | p95 | p99 | worst 5 % share of squared error |")
    print("|---|---|---|---|---|---|---|---|---|")
    codec = VSGPCodec(**{"device": "cpu", **args.param})
    for fr in frames:
        decoded = codec.decode(codec.encode(fr))
        pc, pr = direction_coordinates(fr.points, fr.sensor)
        qc, qr = direction_coordinates(decoded, fr.sensor)
        partner, _ = match_returns(fr.points, decoded, pc, qc, fr.sensor, 0.5)
        ok = partner >= 0
        e = np.abs(pr[ok] - qr[partner[ok]])
        sq = np.sort(e**2)
        pct = " | ".join(f"{100 * v:.1f}" for v in np.percentile(e, [50, 75, 90, 95, 99]))
        print(
            f"| {fr.index} | {int(ok.sum()):,} | {100 * np.sqrt(sq.mean()):.1f} | {pct} | "
            f"{sq[-max(1, len(sq) // 20) :].sum() / sq.sum():.2f} |",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=["speed", "table", "rd", "warm", "threshold", "errors"])
    ap.add_argument("folder")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=1, help="speed: best of this many calls per frame")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--setting",
        action="append",
        default=[],
        metavar="K=V,K=V",
        help="speed: one row per setting (repeatable); 'old:K=V' measures package vsgp_old's codec",
    )
    ap.add_argument("--m", type=int, nargs="+", default=[200, 300, 400, 500, 600])
    ap.add_argument("--vsgp", action="append", default=[], metavar="KEY=V1,V2")
    ap.add_argument("--rangeimage", action="append", default=[], metavar="KEY=V1,V2")
    ap.add_argument("--v-floor", type=float, nargs="+", default=[0.01, 0.03, 0.1, 0.2, 0.3])
    args = ap.parse_args()
    args.param = parse_params(args.param)
    {
        "speed": cmd_speed,
        "table": cmd_table,
        "rd": cmd_rd,
        "warm": cmd_warm,
        "threshold": cmd_threshold,
        "errors": cmd_errors,
    }[args.command](args)


if __name__ == "__main__":
    main()
