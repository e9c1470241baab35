"""``lwbench stream``: a set of codecs through the same link caps, one stream at a time.

Each (cap, codec) is its own :func:`~.session.run_stream` -- fresh scout and base processes --
run one after another, so codecs never compete for the CPU. The frames are read once first
(which also fills the simulator's cache before any clock starts) and the raw-scan reference map
is built once. Results: :class:`~.session.StreamRun` per stream, printed as a table, saved as
JSON and drawn as the VSGP paper's Fig. 6d (:func:`fig6d`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lwbench.errors import ParameterError
from lwbench.registry import Registry
from lwbench.run.plan import CodecConfig, DatasetSpec

from .session import StreamRun, StreamSettings, reference_map, run_stream
from .shaper import KB, LinkModel
from .wire import HEADER

__all__ = ["StudyResult", "dropped_text", "fig6d", "latency_split_text", "ratio_lines", "run_study", "table_rows"]


@dataclass
class StudyResult:
    dataset: str
    rate_hz: float
    settings: StreamSettings
    runs: list[StreamRun]

    def to_json(self) -> str:
        out = {"dataset": self.dataset, "rate_hz": self.rate_hz, "settings": asdict(self.settings), "runs": []}
        for r in self.runs:
            t, rate, acc = r.series()
            out["runs"].append({**r.summary(), "link_model": r.link.to_dict(),
                                "series": {"t": t.tolist(), "kbps": rate.tolist(), "bytes": acc.tolist()},
                                "outcomes": [asdict(o) for o in r.outcomes]})
        return json.dumps(out, indent=1)


def run_study(
    registry: Registry,
    dataset: DatasetSpec,
    configs: Sequence[CodecConfig],
    links: Sequence[LinkModel],
    settings: StreamSettings,
    *,
    on_run: Callable[[StreamRun], None] | None = None,
    on_start: Callable[[CodecConfig, LinkModel], None] | None = None,
    on_frame: Callable[[int, int], None] | None = None,
    on_scan: Callable[[int, int], None] | None = None,
) -> StudyResult:
    """Every (link, codec) stream in turn; ``on_frame(done, n)`` while the frames are read first
    (for the simulator: simulated, minutes for a long sequence), ``on_start`` before each stream,
    ``on_scan(done, n)`` while it runs (scans the scout has dealt with)."""
    ds = dataset.build(registry)
    if len(ds) < settings.frames:
        raise ParameterError(f"stream: {dataset.label} has {len(ds)} frames, asked for {settings.frames}")
    frames = []
    for i in range(settings.frames):
        frames.append(ds[i])
        if on_frame is not None:
            on_frame(i + 1, settings.frames)
    rate = frames[0].sensor.rate_hz
    reference = reference_map(frames, settings.voxel)
    runs = []
    for link in links:
        for config in configs:
            if on_start is not None:
                on_start(config, link)
            run = run_stream({"name": dataset.name, "params": dataset.params},
                             {"name": config.name, "params": config.params}, link, settings,
                             rate_hz=rate, reference=reference, on_scan=on_scan)
            runs.append(run)
            if on_run is not None:
                on_run(run)
    return StudyResult(dataset.label, rate, settings, runs)


def table_rows(runs: Sequence[StreamRun]) -> tuple[list[str], list[list[str]]]:
    """The per-codec table: what the issue asks each stream to report."""
    header = ["codec", "link", "KB/s", "total bytes", "on time", "late", "dropped (why)", "lost", "rejected",
              "latency ms (median / p95)", "median ms: encode / queue / transfer / decode",
              "link in a period", "map IoU"]
    rows = []
    for r in runs:
        s = r.summary()
        lat = "–" if s["latency_ms_median"] is None else f"{s['latency_ms_median']:.0f} / {s['latency_ms_p95']:.0f}"
        rows.append([
            r.codec, r.link.label, f"{s['kbps']:,.1f}", f"{s['wire_bytes']:,}", f"{s['on_time']}/{s['frames']}",
            str(s["late"]), dropped_text(s["dropped"], s["dropped_why"]), str(s["lost"]), str(s["rejected"]), lat,
            latency_split_text(s["latency_parts_ms_median"]),
            "–" if s["link_on_time_share"] is None else f"{s['link_on_time_share']:.0%}",
            "–" if s["map_iou"] is None else f"{s['map_iou']:.3f}",
        ])
    return header, rows


STREAM_TABLES = (
    ("what reached the base", ("codec", "link", "KB/s", "total bytes", "on time", "late", "dropped (why)", "lost",
                               "rejected", "map IoU")),
    ("where a scan's time went", ("codec", "link", "latency ms (median / p95)",
                                  "median ms: encode / queue / transfer / decode", "link in a period")),
)
"""The table's columns in two tables, each narrow enough for a 100-column log (one table of all
thirteen was 204 columns, and cut mid-value off a terminal)."""


def dropped_text(dropped: int, why: dict[str, int]) -> str:
    """``38 (encoder busy 38)``: how many frames never reached the base, and what stopped them."""
    if not dropped:
        return "0"
    return f"{dropped} (" + ", ".join(f"{reason} {n}" for reason, n in sorted(why.items(), key=lambda kv: -kv[1])) + ")"


def latency_split_text(parts: dict[str, float]) -> str:
    """The median of each part of a decoded frame's latency (the parts' medians need not add up
    to the latency's median): where the time goes, the scout's CPU, the queue, the link or the base's."""
    keys = ("encode", "queue", "transfer", "decode")
    if not parts:
        return "–"
    return " / ".join("–" if k not in parts else f"{parts[k]:.0f}" for k in keys)


def ratio_lines(runs: Sequence[StreamRun]) -> list[str]:
    """The first codec's bytes on the wire over each other codec's, at each cap where both ran --
    per frame (payload and framing: the compression the link sees) and in total (which also
    counts the frames each side did not get to send). The first codec named is the reference
    (the VSGP paper's Fig. 6d streams raw first: raw/vsgp ~ 96 there)."""
    codecs = list(dict.fromkeys(r.codec for r in runs))
    if len(codecs) < 2:
        return []
    a = codecs[0]
    lines = []
    for b in codecs[1:]:
        out = []
        for link in dict.fromkeys(r.link for r in runs):
            x = next((r for r in runs if r.link == link and r.codec == a), None)
            y = next((r for r in runs if r.link == link and r.codec == b), None)
            xs, ys = x.summary() if x else None, y.summary() if y else None
            if xs and ys and y.wire_bytes and xs["payload_bytes_mean"] and ys["payload_bytes_mean"]:
                # a frame on the wire: its payload and the 25-byte framing header
                per_frame = (xs["payload_bytes_mean"] + HEADER) / (ys["payload_bytes_mean"] + HEADER)
                out.append(f"{link.label}: {per_frame:.1f} per frame, {x.wire_bytes / y.wire_bytes:.1f} in total "
                           f"({a} sent {x.frames_sent}, {b} {y.frames_sent} of {len(y.outcomes)} frames)")
        if out:
            lines.append(f"{a}/{b} bytes on the wire -- " + "; ".join(out))
    return lines


def fig6d(runs: Sequence[StreamRun], out: Path, name: str = "fig6d", title: str = "") -> list[Path]:
    """Rate over time and accumulated data per codec, log scale (the paper's Fig. 6d), PNG + SVG."""
    from lwbench.plotting import pyplot, save_png_svg

    plt = pyplot()
    fig, (ax_rate, ax_acc) = plt.subplots(1, 2, figsize=(10, 3.8))
    for r in runs:
        t, rate, acc = r.series()
        if not len(t):
            continue
        label = f"{r.codec} ({r.kbps:,.1f} KB/s, {r.wire_bytes / 1e6:.3g} MB)"
        # per-second rate, as ifstat samples it
        per_s = max(1, int(round(1.0 / r.bin_s)))
        k = len(rate) // per_s * per_s
        if k:  # each second's mean, held over that second
            sec = rate[:k].reshape(-1, per_s).mean(axis=1)
            x, y = np.arange(len(sec) + 1) * per_s * r.bin_s, np.append(sec, sec[-1])
        else:
            x, y = np.append(t - r.bin_s, t[-1]), np.append(rate, rate[-1])
        line, = ax_rate.step(x, y, where="post", label=label)
        ax_acc.plot(t, acc / KB, color=line.get_color(), label=label)
    for ax, ylabel in ((ax_rate, "rate on the wire (KB/s)"), (ax_acc, "accumulated data (KB)")):
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
    caps = sorted({r.link.rate_kbps for r in runs if r.link.rate_kbps is not None})
    for cap in caps:
        ax_rate.axhline(cap, color="grey", ls="--", lw=0.8)
    ax_acc.legend(fontsize=7, loc="lower right")
    fig.suptitle(title or "lwbench stream: scout -> base", fontsize=10)
    fig.tight_layout()
    save_png_svg(fig, out, name)
    plt.close(fig)
    return [out / f"{name}.png", out / f"{name}.svg"]
