"""Bundles: a store's rows as one portable, self-describing file, so that results from many
machines and teams meet on one board (``lwbench export`` / ``lwbench import``,
``lwbench leaderboard --store A --store B``).

Format: **JSON lines**, gzip-compressed when the name ends in ``.gz``. Chosen over Parquet
because a bundle must be read where lwbench is not installed -- ``pandas.read_json(path,
lines=True)``, ``jq``, a text editor -- with nothing beyond the standard library here (pyarrow
is a 100 MB dependency), written and read one row at a time (memory does not grow with the
rows), and diffable. Line 1 is the header::

    {"kind": "lwbench bundle", "format": 1, "lwbench_version": ..., "exported": ..., "source": ...,
      "machines": {label: {"reference_ms", "reference"}}, "metric_declarations": [...]}

then one ``{"row": {...}, "suites": [...]}`` per result row (provenance, machine, versions,
the metrics' values, each row's key -- recomputed and checked on import), and a last line
``{"end": N, "sha256": ...}`` over the row lines: a truncated or edited bundle is refused.
Decoded clouds and payloads are not exported (they stay beside the store that made them).
"""

from __future__ import annotations

import gzip
import hashlib
import io
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TextIO

from lwbench.errors import StoreError
from lwbench.reference import REFERENCE_WORKLOAD

from .store import ResultRow, ResultStore, row_from_dict, row_to_dict

__all__ = ["BUNDLE_FORMAT", "Bundle", "export_bundle", "import_bundle", "is_bundle", "open_results", "read_bundle"]

BUNDLE_FORMAT = 1
KIND = "lwbench bundle"


def _open(path: Path, mode: str, gz: bool | None = None) -> TextIO:
    if path.suffix == ".gz" if gz is None else gz:
        return io.TextIOWrapper(gzip.open(path, mode + "b"), encoding="utf-8")
    return open(path, mode, encoding="utf-8")


def export_bundle(store: ResultStore, path: str | Path, *, dataset: str | None = None) -> int:
    """Write every row of ``store`` (of ``dataset`` only, if given) -- its own and those it
    imported -- to the bundle ``path``; returns the number of rows. Written to a temporary name
    and renamed, so a killed export never leaves a half bundle under the real name."""
    from lwbench.version import __version__

    path = Path(path)
    suites = store.suites_of()
    machines: dict[str, dict[str, Any]] = {}
    tmp = path.with_name(path.name + ".part")
    digest = hashlib.sha256()
    n = 0
    with _open(tmp, "w", gz=path.suffix == ".gz") as out:
        for r in store.rows(dataset=dataset):  # the header names the machines: a first pass
            m = machines.setdefault(r.machine, {"reference": REFERENCE_WORKLOAD, "reference_ms": []})
            if r.extra.get("reference_ms"):
                m["reference_ms"].append(float(r.extra["reference_ms"]))
        for m in machines.values():
            refs = sorted(m["reference_ms"])
            m["reference_ms"] = refs[len(refs) // 2] if refs else None  # the median worker's
        header = {"kind": KIND, "format": BUNDLE_FORMAT, "lwbench_version": __version__,
                  "exported": datetime.now(timezone.utc).isoformat(timespec="seconds"), "source": str(store.path),
                  "dataset": dataset, "machines": machines, "metric_declarations": store.metric_declarations()}
        out.write(json.dumps(header, sort_keys=True) + "\n")
        for r in store.rows(dataset=dataset):  # the second pass writes them, one at a time
            line = json.dumps({"row": row_to_dict(r), "suites": suites.get(r.key, [])}, sort_keys=True,
                              default=str) + "\n"
            digest.update(line.encode())
            out.write(line)
            n += 1
        out.write(json.dumps({"end": n, "sha256": digest.hexdigest()}) + "\n")
    tmp.replace(path)
    return n


@dataclass
class Bundle:
    """A bundle read back: its header and rows (each with the suites that asked for it)."""

    path: Path
    header: dict[str, Any]
    rows: list[tuple[ResultRow, list[str]]] = field(default_factory=list)

    @property
    def machines(self) -> dict[str, dict[str, Any]]:
        return self.header.get("machines", {})


def _lines(path: Path) -> Iterator[str]:
    try:
        with _open(path, "r") as fh:
            yield from fh
    except FileNotFoundError:
        raise StoreError(f"no bundle at {path}") from None
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise StoreError(f"{path} cannot be read as a bundle: {exc}") from None


def read_bundle(path: str | Path) -> Bundle:
    """Read and check a bundle: its header, every row's key against the row's content, and the
    closing line's count and checksum (a truncated, edited or foreign file is a ``StoreError``)."""
    path = Path(path)
    lines = _lines(path)
    try:
        header = json.loads(next(lines))
    except (StopIteration, json.JSONDecodeError):
        raise StoreError(f"{path} is not an lwbench bundle (no header line)") from None
    if not isinstance(header, dict) or header.get("kind") != KIND:
        raise StoreError(f"{path} is not an lwbench bundle")
    if header.get("format") != BUNDLE_FORMAT:
        raise StoreError(f"{path}: bundle format {header.get('format')!r}, this lwbench reads {BUNDLE_FORMAT}")
    bundle = Bundle(path, header)
    digest = hashlib.sha256()
    end = None
    for number, line in enumerate(lines, start=2):
        try:
            item = json.loads(line)
        except json.JSONDecodeError:
            raise StoreError(f"{path}: line {number} is not JSON (truncated or edited)") from None
        if "end" in item:
            end = item
            break
        digest.update(line.encode())
        try:
            bundle.rows.append((row_from_dict(item["row"]), list(item.get("suites", []))))
        except (KeyError, TypeError) as exc:
            raise StoreError(f"{path}: line {number} is not a result row ({exc})") from None
        except StoreError as exc:
            raise StoreError(f"{path}: line {number}: {exc}") from None
    if end is None:
        raise StoreError(f"{path}: the bundle ends without its closing line (truncated)")
    if end.get("end") != len(bundle.rows) or end.get("sha256") != digest.hexdigest():
        raise StoreError(f"{path}: {len(bundle.rows)} row(s) do not match the closing line's count and checksum "
                         "(the bundle was edited or damaged)")
    return bundle


def import_bundle(path: str | Path, store: ResultStore) -> int:
    """Add a bundle's rows to ``store`` as imported rows (one per machine and key: see
    :meth:`ResultStore.import_rows`), with its metric declarations and suites; returns the row
    count. The whole bundle is checked before anything is written."""
    bundle = read_bundle(path)
    store.declare_metrics(bundle.header.get("metric_declarations", []))
    n = store.import_rows((r for r, _ in bundle.rows), bundle=Path(path).name)
    by_suite: dict[str, list[str]] = {}
    for r, suites in bundle.rows:
        for s in suites:
            by_suite.setdefault(s, []).append(r.key)
    for suite, keys in by_suite.items():
        store.tag_suite(suite, keys)
    return n


def is_bundle(path: str | Path) -> bool:
    """Whether ``path`` names a bundle (by its name: ``.jsonl`` or ``.jsonl.gz``)."""
    name = Path(path).name
    return name.endswith(".jsonl") or name.endswith(".jsonl.gz")


def open_results(paths: list[Path] | tuple[Path, ...]) -> ResultStore:
    """One store to read from any mix of stores and bundles: a single store is opened read-only
    as it is; otherwise an in-memory store holds every source's rows as imported rows (one per
    machine and key) with their metric declarations and suites -- what ``lwbench leaderboard
    --store A --store B`` and ``lwbench report`` over several bundles read."""
    if len(paths) == 1 and not is_bundle(paths[0]):
        return ResultStore(paths[0], readonly=True)
    combined = ResultStore(":memory:")
    for path in paths:
        if is_bundle(path):
            import_bundle(path, combined)
            continue
        with ResultStore(path, readonly=True) as source:
            combined.declare_metrics(source.metric_declarations())
            combined.import_rows(source.rows(), bundle=Path(path).name)
            by_suite: dict[str, list[str]] = {}
            for key, suites in source.suites_of().items():
                for s in suites:
                    by_suite.setdefault(s, []).append(key)
            for suite, keys in by_suite.items():
                combined.tag_suite(suite, keys)
    return combined
