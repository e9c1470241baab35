"""Aggregating stored rows into a leaderboard: one line per (dataset, codec configuration).

Frame metrics are summarised over the frames that succeeded (mean, std, median, p95); sequence
metrics have one value per configuration. ``failures`` counts failed rows of either kind, so a
codec that crashes on half the frames cannot hide behind a good mean.

What a metric id means -- its unit, whether lower or higher is better, whether it is a default
column -- comes from the metric that declared it (:class:`lwbench.MetricId`, through the
registry): lwbench knows no metric by name, so a third-party metric sorts and prints correctly.

Rows are never averaged across ways of scoring: when the store holds rows of one configuration
scored by different metric versions / parameters or produced by different codec releases, only
the newest scoring is used (the others are counted in ``stale``).

Quality guard: a configuration is *flagged* when it has failed rows, when it was scored on
other frames than the rest of its dataset, and when a metric's :class:`~lwbench.metric.Guard`
says so -- each metric declares what its values mean for the whole configuration (the range
metric: covering less than 90 % of the returns -- ``--min-coverage`` -- flags it; localization:
failed ICP registrations flag it, and originals that already fail ICP make its pose figures
"not meaningful"). Flags travel in every format (a ``flags`` list in JSON) and the default order
puts unflagged configurations first, so a codec cannot rank first by throwing the scan away.

One flag is about the data, not the codec: ``sensor_guessed`` (shown ``sensor guessed``) when the
rows were scored on a sensor model the loader guessed (no ring field, no scan order, no sensor
file: :attr:`lwbench.Dataset.sensor_guessed`, stored with each row). The range metrics pair
returns within windows sized by that beam table, so their figures are as right as the guess. It
is a *caveat* (:data:`CAVEATS`), not a quality flag: it moves no row (every configuration of such
a dataset carries it; ranking them all last would only hide their quality flags) and keeps
nothing off the rate-distortion curves.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.errors import LwbenchError
from lwbench.metric import HIGHER, LOWER, Guard, MetricId
from lwbench.params import config_label
from lwbench.results.declarations import board_info, normalized_runtime_ids
from lwbench.results.store import ResultRow, ResultStore

__all__ = [
    "board_info",
    "CAVEATS",
    "FLAG_NOTES",
    "FLAG_TEXT",
    "LeaderboardEntry",
    "build_leaderboard",
    "check_metric_ids",
    "header_name",
    "headline_metric",
    "table_rows",
    "to_csv",
    "to_json",
    "to_markdown",
]

STATS = ("mean", "std", "median", "p95")

#: The flags the board itself raises (the others come with a metric's Guard, and their text too).
FLAG_TEXT = {"failed_rows": "failed rows", "frames_differ": "other frames", "sensor_guessed": "sensor guessed"}
#: Flags about the data, not the codec: shown like the others, but they move no row.
CAVEATS = frozenset({"sensor_guessed"})
#: What a board flag means, said once under a table that shows it.
FLAG_NOTES = {
    "sensor_guessed": "sensor guessed: the dataset's beam table was guessed from the data (no ring field, scan "
    "order or sensor file), and the range metrics pair returns on it (a note on the data: it moves no row) -- "
    "name the sensor (--dataset-param sensor=PRESET|sensor.json) for exact figures; docs/metrics.md",
}


@dataclass
class LeaderboardEntry:
    dataset: str
    codec: str
    params: dict
    frames: int = 0
    failures: int = 0
    stats: dict[str, dict[str, float | None]] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    defaults: dict = field(default_factory=dict, repr=False)
    dataset_id: str = ""
    flags: list[str] = field(default_factory=list)
    stale: int = 0
    frame_set: tuple[int, ...] = ()
    swept: tuple[str, ...] = ()  # parameters that take several values among this codec's entries
    evaluations: dict[int, str] = field(default_factory=dict, repr=False)  # frame -> evaluation key
    voided: set[str] = field(default_factory=set)  # ids whose figures a raised guard makes meaningless
    flag_texts: dict[str, str] = field(default_factory=dict, repr=False)  # flag -> its text on the board
    machine: str = ""  # the one machine of this entry's rows (a board split --by-machine)
    machines: tuple[str, ...] = ()  # the machines whose rows it pools (quality once per key, runtimes each)

    @property
    def full_label(self) -> str:
        return config_label(self.codec, self.params)

    @property
    def label(self) -> str:
        """The codec with the parameters that differ from its declared defaults, plus any that
        are swept on this board (so ``ratio=0.1`` of a 0.1/0.2 sweep is not a bare name). The
        defaults come from the rows themselves, so the label is the same on every machine."""
        shown = {
            k: v
            for k, v in self.params.items()
            if k in self.swept or k not in self.defaults or self.defaults[k] != v
        }
        label = config_label(self.codec, shown)
        return f"{label} @{self.machine}" if self.machine else label

    def value(self, metric: str, stat: str = "mean") -> float | None:
        return self.stats.get(metric, {}).get(stat)

    def shown(self, metric: str, stat: str = "mean") -> float | None:
        """The value a table shows: ``None`` for figures a raised guard made meaningless."""
        if metric in self.voided:
            return None
        return self.value(metric, stat)

    def flag_text(self, flag: str) -> str:
        return self.flag_texts.get(flag) or FLAG_TEXT.get(flag, flag)

    @property
    def ranked_last(self) -> bool:
        """Whether a quality flag sends this configuration after the unflagged ones (a caveat
        about the data -- :data:`CAVEATS` -- does not)."""
        return any(f not in CAVEATS for f in self.flags)

    @property
    def flags_text(self) -> str:
        return ", ".join(self.flag_text(f) for f in self.flags)

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "dataset": self.dataset,
            "dataset_id": self.dataset_id,
            "codec": self.codec,
            "params": self.params,
            "frames": self.frames,
            "failures": self.failures,
            "label": self.label,
            "flags": list(self.flags),
            "machines": list(self.machines),
        }
        for metric, s in self.stats.items():
            out[metric] = _finite_or_none(s.get("mean"))
            for stat in STATS[1:]:
                out[f"{metric}_{stat}"] = _finite_or_none(s.get(stat))
        return out


def _finite_or_none(v: float | None) -> float | None:
    return v if v is not None and math.isfinite(v) else None


def _summarise(values: list[float]) -> dict[str, float | None]:
    if not values:
        return dict.fromkeys(STATS)
    arr = np.asarray(values, dtype=np.float64)
    finite = arr[np.isfinite(arr)]
    # The empirical quantile (no interpolation) stays defined when values are +inf (lossless
    # PSNR), where interpolating would give inf - inf = NaN; std is over the finite values.
    return {
        "mean": float(arr.mean()),
        "std": float(finite.std()) if len(arr) > 1 and len(finite) == len(arr) else None,
        "median": float(np.percentile(arr, 50, method="inverted_cdf")),
        "p95": float(np.percentile(arr, 95, method="inverted_cdf")),
    }


def _newest_scoring(rows: list[ResultRow]) -> tuple[list[ResultRow], int]:
    """Per (kind, part), only the rows of the most recently written scoring; and how many rows
    were left out (scored by other metric versions/parameters or other codec releases)."""
    by_part: dict[tuple[str, str], dict[str, list[ResultRow]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        way = json.dumps([r.codec_version, r.plugin_version, r.scoring], sort_keys=True, default=str)
        by_part[(r.kind, r.part)][way].append(r)
    kept: list[ResultRow] = []
    stale = 0
    for ways in by_part.values():
        newest = max(ways.values(), key=lambda rs: (max(r.created for r in rs), len(rs)))
        kept += newest
        stale += sum(len(rs) for rs in ways.values()) - len(newest)
    return kept, stale


def _guards(info: Mapping[str, MetricId] | None) -> list[tuple[str, Guard]]:
    """Every declared guard, in board order."""
    return [(i, m.guard) for i, m in (info or {}).items() if getattr(m, "guard", None) is not None]


def _flag(entry: LeaderboardEntry, guards: list[tuple[str, Guard]], limits: Mapping[str, float]) -> None:
    """Raise the entry's flags: each guard whose limit its mean passes (those that void other ids
    first: a voided id raises no guard of its own), then failed rows."""
    raised = set()
    for metric, guard in sorted(guards, key=lambda ig: not ig[1].voids):
        limit = limits.get(guard.setting) if guard.setting else None
        if metric not in entry.voided and guard.raised(entry.value(metric), limit):
            raised.add(metric)
            entry.voided |= set(guard.voids)
            entry.flag_texts[guard.flag] = guard.text
    entry.flags += [guard.flag for metric, guard in guards if metric in raised]
    if entry.failures:
        entry.flags.append("failed_rows")


def _mark_swept_and_frames(entries: list[LeaderboardEntry]) -> None:
    by_codec: dict[tuple[str, str], list[LeaderboardEntry]] = defaultdict(list)
    for e in entries:
        by_codec[(e.dataset_id, e.codec)].append(e)
    for group in by_codec.values():
        keys = {k for e in group for k in e.params}
        swept = tuple(sorted(k for k in keys if len({json.dumps(e.params.get(k)) for e in group}) > 1))
        for e in group:
            e.swept = swept
    by_dataset: dict[str, list[LeaderboardEntry]] = defaultdict(list)
    for e in entries:
        if e.frame_set:
            by_dataset[e.dataset_id].append(e)
    for group in by_dataset.values():
        common, _ = Counter(e.frame_set for e in group).most_common(1)[0]
        for e in group:
            if e.frame_set != common:
                e.flags.append("frames_differ")


def headline_metric(info: Mapping[str, MetricId] | None) -> str:
    """The id a board is sorted by when none is asked for: the one its metric declares the
    ``headline`` (the compression ratio), else the first id; ``""`` (by label) with none."""
    info = info or {}
    return next((i for i, m in info.items() if getattr(m, "headline", False)), next(iter(info), ""))


def check_metric_ids(wanted: list[str], available: Mapping[str, Any] | set[str], what: str) -> None:
    """Reject unknown metric ids with the list of valid ones (never a silent empty column)."""
    unknown = [w for w in wanted if w not in available]
    if unknown:
        raise LwbenchError(f"{what}: unknown metric id(s) {', '.join(unknown)}; valid: {', '.join(sorted(available))}")


def build_leaderboard(
    store: ResultStore,
    *,
    dataset: str | None = None,
    sort: str | None = None,
    descending: bool | None = None,
    info: Mapping[str, MetricId] | None = None,
    keys: set[str] | None = None,
    min_coverage: float | None = None,
    flagged_last: bool = True,
    limits: Mapping[str, float] | None = None,
    by_machine: bool = False,
) -> list[LeaderboardEntry]:
    """Entries sorted by ``sort`` (default: :func:`headline_metric`; best first, in the direction
    its metric declares; configurations with a quality flag -- any flag but a caveat,
    :attr:`LeaderboardEntry.ranked_last` -- after the others unless ``flagged_last=False``).
    ``info`` maps metric ids to their declarations (default: the installed metrics',
    ``Registry.metric_info()``) -- sort directions and the quality guards come from there;
    ``limits`` replaces guards' limits by their ``setting`` name (``min_coverage=`` is
    ``limits={"min_coverage": ...}``); ``keys`` restricts the board to those rows (what one run
    asked for).

    Rows of one configuration from several machines (imported bundles) pool: each key's quality
    figures count once (the same data, code and metrics give the same values on every machine),
    runtimes count every machine's rows -- the ``*_x`` figures (runtimes as multiples of each
    machine's reference workload, :mod:`lwbench.reference`) are what compares them;
    ``by_machine=True`` gives each machine its own entry instead."""
    if info is None:
        from lwbench.registry import get_registry

        info = get_registry().metric_info()
    limits = dict(limits or {})
    if min_coverage is not None:
        limits["min_coverage"] = min_coverage
    guards = _guards(info)
    groups: dict[tuple, list[ResultRow]] = defaultdict(list)
    labels: dict[str, str] = {}
    for row in store.rows(dataset=dataset):
        if keys is not None and row.key not in keys:
            continue
        # Group by the data's identity, not its label: the same label over changed data (a new
        # simulator version, edited files) is a different dataset and must not be averaged in.
        machine = row.machine if by_machine else ""
        groups[(row.dataset_id, row.codec, json.dumps(row.params, sort_keys=True), machine)].append(row)
        labels[row.dataset_id] = row.dataset
    ambiguous = {lab for lab in labels.values() if list(labels.values()).count(lab) > 1}
    entries = []
    runtime = {i for i, m in info.items() if getattr(m, "role", "") == "runtime"}
    normalized = normalized_runtime_ids(info)
    for (ds_id, codec, params_json, machine), rows in groups.items():
        ds = labels[ds_id] if labels[ds_id] not in ambiguous else f"{labels[ds_id]} [{ds_id}]"
        entry = LeaderboardEntry(ds, codec, json.loads(params_json), dataset_id=ds_id, machine=machine)
        entry.machines = tuple(sorted({r.machine for r in rows}))
        rows, entry.stale = _newest_scoring(rows)
        every_machine = list({(r.machine, r.key): r for r in reversed(rows)}.values())  # local rows first
        rows = list({r.key: r for r in reversed(rows)}.values())[::-1]  # one row per key: quality counts once
        entry.defaults = next((r.extra["declared_defaults"] for r in rows if "declared_defaults" in r.extra), {})
        per_metric: dict[str, list[float]] = defaultdict(list)
        frames = []
        for r in rows:
            if r.kind == "frame":
                frames.append(r.frame)
                entry.evaluations[r.frame] = r.evaluation
            if r.status != "ok":
                entry.failures += 1
                if r.error and len(entry.errors) < 3:
                    entry.errors.append(f"frame {r.frame}: {r.error}" if r.kind == "frame" else r.error)
                continue
            if r.kind == "frame":
                entry.frames += 1
            for k, v in r.metrics.items():
                if k in runtime:
                    continue  # every machine's, below
                if v is not None:
                    per_metric[k].append(v)
                else:
                    per_metric.setdefault(k, [])
        for r in every_machine:
            if r.status != "ok":
                continue
            reference = r.extra.get("reference_ms")
            for k in runtime & set(r.metrics):
                v = r.metrics[k]
                per_metric.setdefault(k, [])
                if v is None:
                    continue
                per_metric[k].append(v)
                if k in normalized and reference:
                    per_metric[normalized[k]].append(v / reference)
        entry.frame_set = tuple(sorted(frames))
        entry.stats = {k: _summarise(v) for k, v in per_metric.items()}
        _flag(entry, guards, limits)
        if any(r.sensor_guessed for r in rows):
            entry.flags.append("sensor_guessed")
        entries.append(entry)
    _mark_swept_and_frames(entries)
    key = sort or headline_metric(info)
    if sort is not None and entries:
        check_metric_ids([key], {m for e in entries for m in e.stats} | set(info or {}), "--sort")
    better = (info or {}).get(key)
    desc = descending if descending is not None else (getattr(better, "better", HIGHER) != LOWER)

    def sort_key(e: LeaderboardEntry):
        v = e.shown(key)
        missing = v is None or (isinstance(v, float) and math.isnan(v))
        flagged = e.ranked_last and flagged_last
        return (e.dataset, flagged, missing, 0.0 if missing else (-v if desc else v), e.label)

    return sorted(entries, key=sort_key)


def format_value(v: float | None) -> str:
    """A number as every table prints it (3 significant digits, thousands separated)."""
    if v is None:
        return "–"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    a = abs(v)
    if a == 0:
        return "0"
    if a >= 1000:
        return f"{v:,.0f}"
    if a >= 100:
        return f"{v:.1f}"
    if a >= 1:
        return f"{v:.3g}" if a < 10 else f"{v:.2f}"
    return f"{v:.3g}"


def _cell(e: LeaderboardEntry, metric: str, with_std: bool) -> str:
    if metric in e.voided and e.value(metric) is not None:
        return "n/m"  # a guard says this figure means nothing here (the originals fail ICP, say)
    text = format_value(e.value(metric))
    std = e.value(metric, "std")
    if with_std and std is not None and e.value(metric) is not None:
        text += f" ± {format_value(std)}"
    return text


def header_name(metric: str, info: Mapping[str, MetricId] | None) -> str:
    unit = getattr((info or {}).get(metric), "unit", "")
    # Units a reader needs; shares, counts and the ratio are plain numbers.
    return f"{metric} [{unit}]" if unit and unit not in ("share", "pts", "frames", "x") else metric


def _label_parts(label: str) -> tuple[str, list[str]]:
    """``"sim(frames=100,scene=town)"`` -> ``("sim", ["frames=100", "scene=town"])``."""
    if label.endswith(")") and "(" in label:
        head, inner = label[:-1].split("(", 1)
        return head, [part for part in inner.split(",") if part]
    return label, []


def short_dataset_labels(labels: Iterable[str]) -> tuple[dict[str, str], list[str]]:
    """Each dataset label with only what tells it from the others (the parameters that differ),
    and the parameters they all share: on a terminal board two datasets' full labels took 30
    columns and left one metric. Falls back to the full labels where the short ones collide."""
    labels = list(dict.fromkeys(labels))
    parts = {label: _label_parts(label) for label in labels}
    common = set.intersection(*(set(ps) for _, ps in parts.values())) if labels else set()
    short = {}
    for label, (head, ps) in parts.items():
        own = [x for x in ps if x not in common]
        short[label] = f"{head}({','.join(own)})" if own else head
    if len(set(short.values())) < len(labels):
        return {label: label for label in labels}, []
    order = parts[labels[0]][1] if labels else []
    return short, [x for x in order if x in common]


def table_rows(
    entries: list[LeaderboardEntry],
    columns: tuple[str, ...],
    info: Mapping[str, MetricId] | None = None,
    *,
    with_std: bool = False,
    name: Callable[[str, Mapping[str, MetricId] | None], str] = header_name,
    fail_column: bool = True,
    dataset_label: Mapping[str, str] | None = None,
) -> tuple[list[str], list[list[str]]]:
    """Header and formatted cells; the dataset column only when there is more than one, the
    flags column only when some entry is flagged, the ``fail`` column always (``fail_column``)
    or only when some entry has failed rows. ``name`` writes a metric's header; ``dataset_label``
    what the dataset column shows for a dataset (default: its full label)."""
    many = len({e.dataset for e in entries}) > 1
    flagged = any(e.flags for e in entries)
    fails = fail_column or any(e.failures for e in entries)
    header = [
        *(["dataset"] if many else []),
        "codec",
        "frames",
        *(["fail"] if fails else []),
        *(name(c, info) for c in columns),
        *(["flags"] if flagged else []),
    ]
    rows = [
        [
            *([(dataset_label or {}).get(e.dataset, e.dataset)] if many else []),
            e.label,
            str(e.frames),
            *([str(e.failures)] if fails else []),
            *(_cell(e, c, with_std) for c in columns),
            *([e.flags_text] if flagged else []),
        ]
        for e in entries
    ]
    return header, rows


def present_columns(entries: list[LeaderboardEntry], wanted: tuple[str, ...]) -> tuple[str, ...]:
    """The wanted columns that at least one entry has a value for (no all-empty columns)."""
    return tuple(c for c in wanted if any(e.value(c) is not None for e in entries))


def to_markdown(
    entries: list[LeaderboardEntry], columns: tuple[str, ...], info: Mapping[str, MetricId] | None = None
) -> str:
    header, rows = table_rows(entries, columns, info, with_std=True)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def to_csv(entries: list[LeaderboardEntry]) -> str:
    dicts = [e.as_dict() for e in entries]
    fields: list[str] = []
    for d in dicts:
        fields += [k for k in d if k not in fields]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    for d in dicts:
        writer.writerow({k: json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v for k, v in d.items()})
    return buf.getvalue()


def to_json(entries: list[LeaderboardEntry]) -> str:
    return json.dumps([e.as_dict() for e in entries], indent=2)
