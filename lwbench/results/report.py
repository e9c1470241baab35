"""``lwbench report``: one self-contained HTML page (no network needed) of what a store holds.

- the leaderboard as a sortable table (click a header), with the quality flags;
- rate-distortion curves, one plot per id a metric declares a ``distortion`` (range RMSD,
  Chamfer, D1 PSNR, ATE, occupancy IoU, whichever the store has) against the first ``rate`` id
  (bytes), each codec's efficient points joined;
- runtime bars (the ``runtime`` ids: encode / decode / select, mean with the std over frames);
- a gallery: per codec, one decoded frame beside the original -- a top-down view and a range
  image, coloured by range -- so a person sees what a codec loses.

Every plot is also written as PNG and SVG beside the page, for papers. Images are embedded
(base64 PNG, inline SVG) and the page's script is inline: it opens from a file, offline.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench.metric import MetricId
from lwbench.noise_floor import FloorIds, draw_floor
from lwbench.plotting import pyplot, save_png_svg
from lwbench.registry import Registry
from lwbench.results.leaderboard import FLAG_NOTES, LeaderboardEntry, build_leaderboard, format_value, header_name
from lwbench.results.rd import curves_from_entries
from lwbench.results.store import ResultStore
from lwbench.run.record import DECODED, ORIGINAL, original_key

__all__ = ["BOARD_ORDER_JS", "write_report", "ids_with_role"]


def ids_with_role(info: Mapping[str, MetricId], role: str) -> tuple[str, ...]:
    """The ids whose metric declares them ``role`` (``rate``, ``distortion``, ``runtime``), in
    board order: what the report draws, without knowing any metric by name."""
    return tuple(i for i, m in info.items() if getattr(m, "role", "") == role)


@dataclass
class Figure:
    name: str
    title: str
    svg: str  # inline markup


def rd_figures(entries: list[LeaderboardEntry], info: Mapping[str, MetricId], out: Path) -> list[Figure]:
    rates = ids_with_role(info, "rate")
    if not rates:
        return []
    plt = pyplot()
    figures = []
    floor_ids = FloorIds.from_info(info)
    for distortion in ids_with_role(info, "distortion"):
        curves = curves_from_entries(entries, distortion, rate=rates[0], info=info)
        curves = {k: c for k, c in curves.items() if c.points}
        if not curves:
            continue
        datasets = sorted({ds for ds, _ in curves})
        for ds in datasets:
            fig, ax = plt.subplots(figsize=(7.0, 4.0))
            # Distances span decades: a log axis, on which an exact (0) point cannot stand.
            log_y = info[distortion].better == "lower" and info[distortion].unit == "m"
            dropped = []
            drawn = 0
            for (d, codec), c in sorted(curves.items()):
                if d != ds:
                    continue
                r, v = c.rates, c.distortions
                finite = np.isfinite(r) & np.isfinite(v)
                r, v = r[finite], v[finite]
                if log_y:
                    if (v <= 0).any():
                        dropped.append(codec)
                    r, v = r[v > 0], v[v > 0]
                if len(v):
                    ax.plot(r, v, marker="o", ms=4, lw=1.4, label=codec)
                    drawn += 1
            if not drawn:  # every point exact or undefined: no plot, not an empty frame (issue 33)
                plt.close(fig)
                continue
            ax.set_xscale("log")
            if log_y:
                ax.set_yscale("log")
                if dropped:
                    ax.text(1.01, 0.0, f"exact (0), not drawn:\n{', '.join(dropped)}", transform=ax.transAxes,
                            fontsize=7, color="#555", va="bottom")
            if floor_ids is not None:  # the installed metrics declare the floor's quantities
                draw_floor(ax, [e for e in entries if e.dataset == ds], distortion, rates[0], floor_ids)
            ax.set_xlabel(f"{header_name(rates[0], info)} per frame")
            ax.set_ylabel(header_name(distortion, info))
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
            ax.set_title(f"{distortion} on {ds}", fontsize=9)
            name = f"rd_{distortion}" + ("" if len(datasets) == 1 else f"_{datasets.index(ds)}")
            figures.append(Figure(name, f"{distortion} against {rates[0]} ({ds})", save_png_svg(fig, out, name)))
            plt.close(fig)
    return figures


def runtime_figure(entries: list[LeaderboardEntry], out: Path, info: Mapping[str, MetricId]) -> Figure | None:
    runtime = ids_with_role(info, "runtime")
    rows = [e for e in entries if any(e.value(k) is not None for k in runtime)]
    if not rows:
        return None
    plt = pyplot()
    labels = [e.label if len({x.dataset for x in rows}) == 1 else f"{e.label} · {e.dataset}" for e in rows]
    fig, ax = plt.subplots(figsize=(7.0, 0.28 * len(rows) + 1.2))
    y = np.arange(len(rows))
    h = 0.8 / len(runtime)
    for k, key in enumerate(runtime):
        means = [e.value(key) or 0.0 for e in rows]
        stds = [e.value(key, "std") or 0.0 for e in rows]
        ax.barh(y + (k - (len(runtime) - 1) / 2) * h, means, h, xerr=stds, label=key.removesuffix("_ms"), capsize=2)
    ax.set_yticks(y, labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (mean ± std over frames)")
    ax.grid(True, axis="x", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    svg = save_png_svg(fig, out, "runtime")
    plt.close(fig)
    return Figure("runtime", "Runtime per frame", svg)


def _raster(values_xy: np.ndarray, values: np.ndarray, extent: tuple[float, float, float, float],
            shape: tuple[int, int]) -> np.ndarray:
    """Per-pixel minimum of ``values`` (NaN where empty): a fast picture of 10^5 points."""
    x0, x1, y0, y1 = extent
    h, w = shape
    cx = ((values_xy[:, 0] - x0) / (x1 - x0) * w).astype(np.int64)
    cy = ((values_xy[:, 1] - y0) / (y1 - y0) * h).astype(np.int64)
    ok = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
    img = np.full(h * w, np.inf)
    np.minimum.at(img, cy[ok] * w + cx[ok], values[ok])
    img[~np.isfinite(img)] = np.nan
    return img.reshape(h, w)


def _views(points: np.ndarray, half: float, el_span: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    from lwbench.geometry import spherical

    r, az, el = spherical(points)
    top = _raster(points[:, :2], r, (-half, half, -half, half), (220, 220))
    rimg = _raster(np.stack([az, el], axis=1), r, (-math.pi, math.pi, *el_span), (48, 720))
    return top, rimg


def gallery_image(original: np.ndarray, decoded: np.ndarray, title: str) -> str:
    """A PNG (base64) of the original and decoded cloud: top-down and range image, by range."""
    plt = pyplot()
    r = np.linalg.norm(original, axis=1)
    half = float(np.percentile(np.abs(original[:, :2]), 98)) * 1.05 or 1.0
    from lwbench.geometry import spherical

    _, _, el = spherical(original)
    el_span = (float(el.min()) - 1e-3, float(el.max()) + 1e-3)
    vmax = float(np.percentile(r, 99)) or 1.0
    fig, axes = plt.subplots(2, 2, figsize=(9.0, 4.6), gridspec_kw={"height_ratios": [3, 1]})
    for col, (name, pts) in enumerate((("original", original), ("decoded", decoded))):
        top, rimg = _views(np.asarray(pts, np.float64), half, el_span) if len(pts) else (
            np.full((220, 220), np.nan), np.full((48, 720), np.nan))
        axes[0, col].imshow(top, origin="lower", cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
        axes[0, col].set_title(f"{name}: {len(pts):,} points", fontsize=9)
        axes[1, col].imshow(rimg, origin="lower", cmap="viridis", vmin=0, vmax=vmax, aspect="auto",
                            interpolation="nearest")
        axes[1, col].set_xlabel("range image (azimuth x elevation)", fontsize=8)
        for ax in axes[:, col]:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(title, fontsize=10)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _gallery(store: ResultStore, entries: list[LeaderboardEntry]) -> list[tuple[str, str]]:
    """One (title, png) per dataset and codec: the codec's most default configuration."""
    chosen: dict[tuple[str, str], LeaderboardEntry] = {}
    for e in entries:
        key = (e.dataset_id, e.codec)
        if e.evaluations and (key not in chosen or len(e.label) < len(chosen[key].label)):
            chosen[key] = e
    out = []
    for (ds_id, _), e in sorted(chosen.items(), key=lambda kv: (kv[1].dataset, kv[1].codec)):
        frame = min(e.evaluations)
        original = store.artifact(original_key(ds_id, frame), ORIGINAL)
        decoded = store.artifact(e.evaluations[frame], DECODED)
        if original is None or decoded is None:
            continue
        title = f"{e.label} · {e.dataset} · frame {frame}"
        out.append((title, gallery_image(original, decoded, title)))
    return out


def _table(entries: list[LeaderboardEntry], info: Mapping[str, MetricId]) -> str:
    """The board as a table the page's script sorts: each row says its dataset group
    (``data-group``, in the board's dataset order) and whether a quality flag ranks it last
    (``data-last``), so a click sorts within the same order the terminal's board keeps."""
    # The board's default columns and every rate (bits per point beside the bytes).
    wanted = [i for i, m in info.items() if m.default or getattr(m, "role", "") == "rate"]
    cols = [c for c in wanted if any(e.value(c) is not None for e in entries)]
    many = len({e.dataset for e in entries}) > 1
    columns = [("dataset", "text", "")] if many else []
    columns += [("codec", "text", "configuration"), ("frames", "num", ""), ("fail", "num", "failed rows")]
    columns += [(header_name(c, info), "num", f"{c}: {getattr(info.get(c), 'better', '')} is better") for c in cols]
    columns.append(("flags", "text", "quality flags (grey rows rank last) and notes on the data"))
    # The unit under the id, as the terminal's board puts it: a header is as wide as its id.
    head = "".join(f'<th data-type="{t}" title="{html.escape(d)}">{html.escape(n).replace(" [", "<br>[")}</th>'
                   for n, t, d in columns)
    groups = {ds: i for i, ds in enumerate(dict.fromkeys(e.dataset for e in entries))}
    rows = []
    for e in entries:
        cells = [*([html.escape(e.dataset)] if many else []), html.escape(e.label)]
        tds = "".join(f'<td class="text">{c}</td>' for c in cells)
        tds += f'<td data-v="{e.frames}">{e.frames}</td><td data-v="{e.failures}">{e.failures}</td>'
        for c in cols:
            v = e.shown(c)
            if v is None or math.isnan(v):
                text = "n/m" if e.value(c) is not None else "–"
                tds += f'<td data-v="">{text}</td>'
            elif math.isinf(v):  # lossless PSNR: ranks as the board ranks it, first when higher is better
                tds += f'<td data-v="{"Infinity" if v > 0 else "-Infinity"}">{format_value(v)}</td>'
            else:
                std = e.value(c, "std")
                tip = f' title="± {std:.4g}"' if std else ""
                tds += f'<td data-v="{v!r}"{tip}>{format_value(v)}</td>'
        last = int(e.ranked_last)
        rows.append(f'<tr class="{"flagged" if last else ""}" data-group="{groups[e.dataset]}" data-last="{last}">'
                    f'{tds}<td class="text">{html.escape(e.flags_text)}</td></tr>')
    # In a box that scrolls sideways when it must: the page itself never does (issue 33: a sweep's
    # labels and flags, each on one line, made the board wider than a 1,400 px window).
    return (f'<div class="board"><table id="board"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table></div>')


# The order a click on column ``col`` gives -- the board's own (lwbench.results.leaderboard's sort key):
# dataset group, rows a quality flag ranks last after the others, missing values last, the
# column's values in the clicked direction, then the configuration's label. A click on the
# dataset column orders the groups. Pure, so tests run it under node.
BOARD_ORDER_JS = """
function boardOrder(rows, col, asc, num, groupCol, labelCol) {
  const key = r => num ? r.values[col] : r.texts[col];
  const dir = asc ? 1 : -1;
  return rows.slice().sort((a, b) => {
    if (a.group !== b.group) return (a.group - b.group) * (col === groupCol ? dir : 1);
    if (a.last !== b.last) return a.last - b.last;
    const x = key(a), y = key(b);
    if ((x === null) !== (y === null)) return x === null ? 1 : -1;
    if (x !== null && col !== groupCol && x !== y) return (x < y ? -1 : 1) * dir;
    const p = a.texts[labelCol], q = b.texts[labelCol];
    return p < q ? -1 : p > q ? 1 : 0;
  });
}
"""

_SCRIPT = BOARD_ORDER_JS + """
(() => {
  const body = document.querySelector('#board tbody');
  const heads = Array.from(document.querySelectorAll('#board th'));
  const groupCol = heads.length && heads[0].textContent === 'dataset' ? 0 : -1;
  const rows = Array.from(body.rows).map(r => ({
    el: r, group: +r.dataset.group, last: +r.dataset.last,
    values: Array.from(r.cells).map(c => (c.dataset.v === undefined || c.dataset.v === '') ? null
                                                                                     : parseFloat(c.dataset.v)),
    texts: Array.from(r.cells).map(c => c.textContent),
  }));
  heads.forEach((th, col) => {
    th.addEventListener('click', () => {
      const asc = th.dataset.sorted !== 'asc';
      heads.forEach(h => delete h.dataset.sorted);
      th.dataset.sorted = asc ? 'asc' : 'desc';
      boardOrder(rows, col, asc, th.dataset.type === 'num', groupCol, groupCol + 1)
        .forEach(r => body.appendChild(r.el));
    });
  });
})();
"""

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5rem; color: #222; }
table { border-collapse: collapse; font-size: 0.82rem; }
th, td { border: 1px solid #ccc; padding: 0.2rem 0.45rem; text-align: right; white-space: nowrap; }
div.board { max-width: 100%; overflow-x: auto; }
td.text { white-space: normal; min-width: 7rem; max-width: 22rem; overflow-wrap: anywhere; text-align: left; }
th { background: #f3f3f3; cursor: pointer; user-select: none; }
th[data-sorted="asc"]::after { content: " ▲"; } th[data-sorted="desc"]::after { content: " ▼"; }
td:first-child, th:first-child { text-align: left; }
tr.flagged { color: #888; }
figure { display: inline-block; margin: 0.5rem 1rem 1rem 0; vertical-align: top; }
figure svg { max-width: 620px; height: auto; }
.gallery img { max-width: 900px; display: block; margin-bottom: 1rem; }
"""


def _json_in_html(data) -> str:
    """JSON that cannot end its <script> element early."""
    return json.dumps(data).replace("</", "<\\/")


def write_report(sources: Path | list[Path], out: Path, registry: Registry, *, dataset: str | None = None) -> Path:
    """Write ``out/index.html`` and the plots' PNG/SVG files; return the page's path. ``sources``:
    a store, or several stores and bundles (``lwbench export``) -- one page for many machines,
    with a line per machine where they differ, and the suites the rows were run for."""
    from lwbench.results.bundle import open_results
    from lwbench.results.leaderboard import board_info

    sources = [sources] if isinstance(sources, Path) else list(sources)
    out.mkdir(parents=True, exist_ok=True)
    with open_results(sources) as store:
        info = board_info(store, registry.metric_declarations())
        machines = {r.machine for r in store.rows()}
        suites = sorted({s for names in store.suites_of().values() for s in names})
        entries = build_leaderboard(store, dataset=dataset, info=info, by_machine=len(machines) > 1)
        gallery = _gallery(store, entries)
    store_path = ", ".join(str(p) for p in sources)
    figures = rd_figures(entries, info, out)
    runtime = runtime_figure(entries, out, info)
    if runtime is not None:
        figures.append(runtime)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>lwbench report</title>",
        f"<style>{_STYLE}</style></head><body>",
        "<h1>lwbench report</h1>",
        f"<p>{len(entries)} configuration(s) on {len({e.dataset for e in entries})} dataset(s), from "
        f"<code>{html.escape(str(store_path))}</code>. Means over frames (hover a value for its std); "
        "rows a quality flag ranks last are grey and stay last; click a column to sort.</p>",
        *([f"<p>Machines: {html.escape(', '.join(sorted(machines)))} (a line per machine: quality is the same "
           "for the same configuration, runtimes are each machine's; the <code>*_x</code> columns are runtimes "
           "as multiples of each machine's reference workload).</p>"] if len(machines) > 1 else []),
        *([f"<p>Suite(s): {html.escape(', '.join(suites))}</p>"] if suites else []),
        "<h2>Leaderboard</h2>",
        _table(entries, info),
        *(f"<p class='note'>{html.escape(note)}</p>" for flag, note in FLAG_NOTES.items()
          if any(flag in e.flags for e in entries)),
        "<h2>Rate-distortion and runtime</h2>",
        *(f"<figure><figcaption>{html.escape(f.title)}</figcaption>{f.svg}</figure>" for f in figures),
        "<h2>Gallery</h2><div class='gallery'>",
        *(f"<img alt='{html.escape(t)}' title='{html.escape(t)}' src='data:image/png;base64,{png}'>"
          for t, png in gallery),
        "</div>",
        f"<script>{_SCRIPT}</script>",
        f"<script type='application/json' id='data'>{_json_in_html([e.as_dict() for e in entries])}</script>",
        "</body></html>",
    ]
    page = out / "index.html"
    page.write_text("\n".join(parts))
    return page
