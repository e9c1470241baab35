"""``lwbench vsgp-bench``: issue 19's figures for VSGP (docs/vsgp.md) -- speed against a float64
reference, accuracy, rate-distortion, warm starts, the variance floor, where the range error
comes from. Registered with ``lwbench_register_commands``; every subcommand prints Markdown.

    lwbench simulate tunnel --out /tmp/simtunnel --frames 50
    lwbench vsgp-bench speed /tmp/simtunnel --frames 20
    lwbench vsgp-bench speed ../shared/data/real/kitti00_frames0-1 --param bytes=50000
    lwbench vsgp-bench table /tmp/simtunnel --frames 50 --m 200,300,400,500,600
    lwbench vsgp-bench rd ../shared/data/real/kitti00_frames0-1 --vsgp bytes=20000,40000,80000 \\
        --rangeimage step=0.05,0.1,0.2,0.4
    lwbench vsgp-bench warm /tmp/simtunnel --frames 40 --param mode=paper
    lwbench vsgp-bench threshold /tmp/simurban --frames 6 --v-floor 0.03,0.1,0.2
    lwbench vsgp-bench errors ../shared/data/real/kitti00_frames0-1 --param body=q16z --param bytes=50000

Speeds are medians and ratios to the reference workload (:func:`.gp.reference_seconds`: a 57,600
x 500 float64 RQ kernel by ``|x|^2 + |z|^2 - 2 X Z^T`` in numpy, the workload issue 19 names)
timed in the same process, interleaved with the codec's calls (the machine is shared). The
scores are the run's own range metric (``lwbench.frame_metric("ranges")``): range RMSD,
coverage, false returns. ``--param KEY=VALUE`` sets a vsgp parameter for every call.

No ``from __future__ import annotations``: typer reads the annotations at run time. Heavy
imports (torch, through the codec) happen inside the commands.
"""

import os
import time
from typing import Annotated, Any

import numpy as np
import typer

from lwbench import CodecKind, Evaluation, Frame, ParameterError

__all__ = ["register"]

_STAGES = ("projection", "layout", "refine", "fit", "residual", "serialize", "parse", "predict", "sampling")

_HEAD = (
    "| setting | encode ms | × ref | decode ms | × ref | ref ms | bytes | ratio | range RMSD cm | coverage "
    "| false returns |\n|---|---|---|---|---|---|---|---|---|---|---|"
)

Dataset = Annotated[str, typer.Argument(
    metavar="DATASET", help="A dataset folder or scan file, or a registered dataset name.")]
DatasetParams = Annotated[list[str] | None, typer.Option("--dataset-param", help="KEY=VALUE for the dataset.")]
Frames = Annotated[int, typer.Option("--frames", min=1, help="The first N frames of the dataset.")]
Params = Annotated[list[str] | None, typer.Option(
    "--param", help="KEY=VALUE: a vsgp setting for every call (repeat).")]


def _assignments(words: list[str] | None, option: str) -> dict[str, str]:
    out = {}
    for word in words or []:
        key, sep, value = word.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"{option} {word!r}: expected KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def _values(text: str, option: str, kind: type) -> list:
    """``V1,V2,...`` -> the values (a number list such as ``--m 200,300``)."""
    try:
        return [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ParameterError(f"{option} {text!r}: expected comma-separated {kind.__name__}s") from None


def _sweep(spec: str, option: str) -> list[dict[str, str]]:
    """``key=v1,v2,...`` -> one parameter dict per value."""
    key, sep, values = spec.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise ParameterError(f"{option} {spec!r}: expected KEY=V1[,V2...]")
    return [{key.strip(): v.strip()} for v in values.split(",")]


def load_frames(dataset: str, params: list[str] | None, n: int) -> list[Frame]:
    from lwbench import open_dataset

    ds = open_dataset(dataset, list(params or []))
    return [ds[i] for i in range(min(n, len(ds)))]


def _vsgp(params: dict[str, Any], old: bool = False):
    """This plugin's codec on the CPU, or (``old``) the ``VSGPCodec`` of a package ``vsgp_old`` on
    the path -- e.g. main's plugin copied there -- for before/after rows from one process."""
    if not old:
        from lwbench import codec_class

        cls = codec_class("vsgp")  # this package's codec, without importing the package from inside it
    else:
        import importlib

        try:
            cls = importlib.import_module("vsgp_old").VSGPCodec
        except ImportError:
            raise ParameterError("--setting old:...: no package vsgp_old on the path (PYTHONPATH=DIR holding "
                                 "a copy of the plugin named vsgp_old)") from None
    return cls(**{"device": "cpu", **params})


_METRIC: list = []


def scores(frame: Frame, decoded: np.ndarray) -> tuple[float, float, float]:
    """(range RMSD m, coverage, false returns): the run's range metric."""
    if not _METRIC:
        from lwbench import frame_metric

        _METRIC.append(frame_metric("ranges"))
    m = _METRIC[0].compute(_evaluation(frame, decoded))
    rm = m["range_rmsd"] if m["range_rmsd"] is not None else float("nan")
    return rm, m["coverage"] or 0.0, m["false_returns"] or 0.0


def _evaluation(frame: Frame, decoded: np.ndarray) -> Evaluation:
    return Evaluation(frame, b"", np.asarray(decoded, np.float32), CodecKind.REPRESENTATION, {})


def _load() -> str:
    return "load average " + " / ".join(f"{x:.2f}" for x in os.getloadavg())


def _header(dataset: str, frames: list[Frame]) -> None:
    if not frames:
        raise ParameterError(f"{dataset}: no frames")
    print(f"{dataset}: {len(frames)} frames, {_load()}\n")


def measure(frames: list[Frame], params: dict, repeats: int = 1, old: bool = False) -> dict[str, Any]:
    """Median encode/decode seconds (after a warm-up), reference seconds interleaved, scores."""
    from .gp import reference_seconds

    codec = _vsgp(params, old)
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


def _row(label: str, r: dict[str, Any]) -> str:
    return (
        f"| {label} | {1000 * r['enc']:.1f} | {r['enc'] / r['ref']:.3f} | {1000 * r['dec']:.1f} | "
        f"{r['dec'] / r['ref']:.3f} | {1000 * r['ref']:.0f} | {r['bytes']:,.0f} | {r['ratio']:.1f} | "
        f"{100 * r['rmsd']:.2f} ± {100 * r['rmsd_std']:.2f} | {r['coverage']:.4f} | {r['false']:.4f} |"
    )


def speed(dataset: str, dataset_param, n: int, param: dict, settings: list[str], repeats: int) -> None:
    frames = load_frames(dataset, dataset_param, n)
    _header(dataset, frames)
    print(_HEAD)
    stages = []
    for s in settings or [""]:
        old = s.startswith("old:")
        s = s.removeprefix("old:")
        params = {**param, **_assignments([kv for kv in s.split(",") if kv], "--setting")}
        r = measure(frames, params, repeats, old)
        label = ("main: " if old else "") + (s or "defaults")
        print(_row(label, r), flush=True)
        stages.append((label, r))
    print("\nmedian ms per stage (x reference):\n")
    for label, r in stages:
        parts = ", ".join(f"{k} {1000 * v:.1f} ({v / r['ref']:.3f})" for k, v in r["stages"].items())
        print(f"- {label}: {parts}")
    print(f"\n{_load()}")


def table(dataset: str, dataset_param, n: int, param: dict, ms: list[int]) -> None:
    frames = load_frames(dataset, dataset_param, n)
    _header(dataset, frames)
    print(_HEAD)
    for m in ms:
        r = measure(frames, {**param, "num_inducing": m})
        print(_row(f"M={m}", r), flush=True)


def _rangeimage_points(frames: list[Frame], params: dict) -> list[tuple[int, float, float, float]]:
    from lwbench import codec_class

    cls = codec_class("rangeimage")
    out = []
    for fr in frames:
        codec = cls(**params)
        data = codec.encode(fr)
        out.append((len(data), *scores(fr, cls(**params).use_sensors([fr.sensor]).decode(data))))
    return out


def rd(dataset: str, dataset_param, n: int, param: dict, vsgp: list[str], rangeimage: list[str]) -> None:
    """Bytes vs range RMSD for vsgp and rangeimage over parameter sweeps on the same frames."""
    sweeps = [("vsgp", p) for spec in vsgp for p in _sweep(spec, "--vsgp")]
    sweeps += [("rangeimage", p) for spec in rangeimage for p in _sweep(spec, "--rangeimage")]
    if not sweeps:
        raise ParameterError("rd: give at least one --vsgp KEY=V1,V2 or --rangeimage KEY=V1,V2")
    frames = load_frames(dataset, dataset_param, n)
    _header(dataset, frames)
    print("| codec | setting | bytes | ratio | range RMSD cm | coverage | false returns |")
    print("|---|---|---|---|---|---|---|")
    for name, p in sweeps:
        if name == "vsgp":
            codec = _vsgp({**param, **p})
            rows = []
            for fr in frames:
                data = codec.encode(fr)
                rows.append((len(data), *scores(fr, codec.decode(data))))
        else:
            rows = _rangeimage_points(frames, p)
        o = np.array(rows)
        ratio = np.mean([f.raw_bytes for f in frames]) / o[:, 0].mean()
        print(
            f"| {name} | {p} | {o[:, 0].mean():,.0f} | {ratio:.1f} | {100 * np.nanmean(o[:, 1]):.2f} | "
            f"{o[:, 2].mean():.3f} | {o[:, 3].mean():.3f} |",
            flush=True,
        )


def threshold(dataset: str, dataset_param, n: int, param: dict, floors: list[float]) -> None:
    """The variance filter's floor: each frame encoded once, decoded with every ``--v-floor``."""
    frames = load_frames(dataset, dataset_param, n)
    _header(dataset, frames)
    print("| v_floor | range RMSD cm | coverage (mean) | coverage (worst frame) | false returns |")
    print("|---|---|---|---|---|")
    payloads = [_vsgp(param).encode(fr) for fr in frames]
    for v in floors:
        codec = _vsgp({"v_floor": v}).use_sensors([fr.sensor for fr in frames])
        o = np.array([scores(fr, codec.decode(data)) for fr, data in zip(frames, payloads, strict=True)])
        print(
            f"| {v:g} | {100 * np.nanmean(o[:, 0]):.2f} | {o[:, 1].mean():.4f} | {o[:, 1].min():.4f} | "
            f"{o[:, 2].mean():.4f} |",
            flush=True,
        )


def warm(dataset: str, dataset_param, n: int, param: dict) -> None:
    """Cold (every frame alone) vs warm (the previous frame's state) encodes of a sequence, in
    order; the payloads of both decode alone."""
    from .gp import reference_seconds

    frames = load_frames(dataset, dataset_param, n)
    _header(dataset, frames)
    print("| start | steps run (mean) | encode ms (median) | × ref | range RMSD cm | coverage |")
    print("|---|---|---|---|---|---|")
    for warm_start in (False, True):
        codec = _vsgp({**param, "warm_start": warm_start})
        codec.encode(frames[0])
        codec.reset_stream()
        enc, refs, rows, steps = [], [], [], []
        for fr in frames:
            refs.append(reference_seconds(repeats=1))
            t = time.perf_counter()
            data = codec.encode(fr)
            enc.append(time.perf_counter() - t)
            steps.append(codec.last_timings.get("steps_run", 0.0))
            rows.append(scores(fr, _vsgp(param).use_sensors([fr.sensor]).decode(data)))
        o = np.array(rows)
        ref = float(np.median(refs))
        print(
            f"| {'warm' if warm_start else 'cold'} | {np.mean(steps):.1f} | {1000 * np.median(enc):.1f} | "
            f"{np.median(enc) / ref:.3f} | {100 * np.nanmean(o[:, 0]):.2f} | {o[:, 1].mean():.4f} |",
            flush=True,
        )


def errors(dataset: str, dataset_param, n: int, param: dict) -> None:
    """Where the range RMSD comes from: percentiles of ``|r - r_hat|`` over the metric's pairs
    and the share of the squared error carried by the worst 5 % of them."""
    from lwbench import frame_metric

    frames = load_frames(dataset, dataset_param, n)
    _header(dataset, frames)
    print("| frame | pairs | RMSD cm | median cm | p75 | p90 | p95 | p99 | worst 5 % share of squared error |")
    print("|---|---|---|---|---|---|---|---|---|")
    metric = frame_metric("ranges")
    codec = _vsgp(param)
    for fr in frames:
        decoded = codec.decode(codec.encode(fr))
        e = np.abs(metric.range_differences(_evaluation(fr, decoded)))
        if not len(e):
            print(f"| {fr.index} | 0 | – | – | – | – | – | – | – |", flush=True)
            continue
        sq = np.sort(e**2)
        pct = " | ".join(f"{100 * v:.1f}" for v in np.percentile(e, [50, 75, 90, 95, 99]))
        print(
            f"| {fr.index} | {len(e):,} | {100 * np.sqrt(sq.mean()):.1f} | {pct} | "
            f"{sq[-max(1, len(sq) // 20) :].sum() / max(sq.sum(), 1e-300):.2f} |",
            flush=True,
        )


def register(cli: typer.Typer) -> None:
    """Add ``lwbench vsgp-bench`` and its subcommands."""
    bench = typer.Typer(
        help="VSGP's figures (docs/vsgp.md): speed against a float64 reference, accuracy, rate-distortion, "
        "warm starts, the variance floor, the range error's make-up; Markdown tables.",
        no_args_is_help=True,
    )

    @bench.command("speed")
    def speed_command(
        dataset: Dataset,
        dataset_param: DatasetParams = None,
        frames: Frames = 10,
        param: Params = None,
        setting: Annotated[list[str] | None, typer.Option(
            "--setting", help="K=V,K=V: one row per setting (repeat; '' = defaults; 'old:K=V' measures "
            "package vsgp_old's codec).")] = None,
        repeats: Annotated[int, typer.Option("--repeats", min=1, help="Best of this many calls per frame.")] = 1,
    ) -> None:
        """Encode/decode ms and their ratio to the reference, bytes, ratio, range RMSD, coverage; ms per stage."""
        speed(dataset, dataset_param, frames, _assignments(param, "--param"), list(setting or []), repeats)

    @bench.command("table")
    def table_command(
        dataset: Dataset,
        dataset_param: DatasetParams = None,
        frames: Frames = 10,
        param: Params = None,
        m: Annotated[str, typer.Option("--m", help="Inducing points M, one row each (comma-separated).")]
        = "200,300,400,500,600",
    ) -> None:
        """The speed table's row for each number of inducing points."""
        table(dataset, dataset_param, frames, _assignments(param, "--param"), _values(m, "--m", int))

    @bench.command("rd")
    def rd_command(
        dataset: Dataset,
        dataset_param: DatasetParams = None,
        frames: Frames = 10,
        param: Params = None,
        vsgp: Annotated[list[str] | None, typer.Option(
            "--vsgp", help="KEY=V1,V2,...: a vsgp sweep (repeat).")] = None,
        rangeimage: Annotated[list[str] | None, typer.Option(
            "--rangeimage", help="KEY=V1,V2,...: a rangeimage sweep (repeat).")] = None,
    ) -> None:
        """Bytes against range RMSD for vsgp and rangeimage sweeps on the same frames."""
        rd(dataset, dataset_param, frames, _assignments(param, "--param"), list(vsgp or []), list(rangeimage or []))

    @bench.command("warm")
    def warm_command(
        dataset: Dataset, dataset_param: DatasetParams = None, frames: Frames = 10, param: Params = None
    ) -> None:
        """Cold against warm-started encodes of a sequence in order."""
        warm(dataset, dataset_param, frames, _assignments(param, "--param"))

    @bench.command("threshold")
    def threshold_command(
        dataset: Dataset,
        dataset_param: DatasetParams = None,
        frames: Frames = 10,
        param: Params = None,
        v_floor: Annotated[str, typer.Option(
            "--v-floor", help="Variance floors, one row each (comma-separated).")] = "0.01,0.03,0.1,0.2,0.3",
    ) -> None:
        """The variance filter's floor: each frame encoded once, decoded with every --v-floor."""
        threshold(dataset, dataset_param, frames, _assignments(param, "--param"), _values(v_floor, "--v-floor", float))

    @bench.command("errors")
    def errors_command(
        dataset: Dataset, dataset_param: DatasetParams = None, frames: Frames = 10, param: Params = None
    ) -> None:
        """Percentiles of the range error over the metric's pairs, per frame, and the worst 5 %'s share."""
        errors(dataset, dataset_param, frames, _assignments(param, "--param"))

    cli.add_typer(bench, name="vsgp-bench")
