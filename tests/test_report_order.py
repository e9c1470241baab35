"""Issue 23: the HTML report's click-sort keeps the board's order -- flagged rows last, as the
terminal's table -- instead of a second one of its own.

The page's sort function (``lwbench.results.report.BOARD_ORDER_JS``) runs under node on the rows the page
holds (read back from its HTML), and every click on a metric column, in either direction, must
give the order ``build_leaderboard(sort=that id, descending=...)`` gives: per dataset, rows with
a quality flag after the others, missing values last, then the values, then the label."""

from __future__ import annotations

import json
import shutil
import subprocess
from html.parser import HTMLParser

import pytest

from lwbench.registry import get_registry
from lwbench.results.leaderboard import build_leaderboard
from lwbench.results.report import BOARD_ORDER_JS, write_report
from lwbench.results.store import ResultRow, ResultStore

NODE = shutil.which("node")
REGISTRY = get_registry()
INFO = REGISTRY.metric_info()

# Two datasets; quality-flagged rows (low coverage), a caveat (sensor guessed), a missing value,
# an infinite one (lossless PSNR) and ties, so every rule of the order has something to decide.
CONFIGS = {
    "raw": dict(bytes=1000.0, ratio=1.0, coverage=1.0, range_rmsd=0.0, chamfer=0.0, d1_psnr=float("inf")),
    "draco": dict(bytes=300.0, ratio=3.3, coverage=1.0, range_rmsd=0.002, chamfer=0.001, d1_psnr=80.0),
    "rangeimage": dict(bytes=200.0, ratio=5.0, coverage=0.999, range_rmsd=None, chamfer=0.003, d1_psnr=70.0),
    "random": dict(bytes=100.0, ratio=10.0, coverage=0.1, range_rmsd=0.0, chamfer=0.02, d1_psnr=60.0),
    "voxel": dict(bytes=100.0, ratio=10.0, coverage=0.05, range_rmsd=0.0, chamfer=0.03, d1_psnr=61.0),
}


class _Board(HTMLParser):
    """The #board table's rows as the page's script reads them."""

    def __init__(self) -> None:
        super().__init__()
        self.heads: list[dict] = []
        self.rows: list[dict] = []
        self._cell: dict | None = None
        self._in_head = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "th":
            self._in_head = True
            self.heads.append({"type": a.get("data-type"), "title": a.get("title", ""), "text": ""})
        elif tag == "tr" and "data-group" in a:
            self.rows.append({"group": int(a["data-group"]), "last": int(a["data-last"]), "values": [], "texts": []})
        elif tag == "td" and self.rows:
            self._cell = {"v": a.get("data-v"), "text": ""}

    def handle_data(self, data):
        if self._cell is not None:
            self._cell["text"] += data
        elif self._in_head:
            self.heads[-1]["text"] += data

    def handle_endtag(self, tag):
        if tag == "th":
            self._in_head = False
        if tag == "td" and self._cell is not None:
            v = self._cell["v"]
            value = None if v in (None, "") else float(v.replace("Infinity", "inf"))
            self.rows[-1]["values"].append(value)
            self.rows[-1]["texts"].append(self._cell["text"])
            self._cell = None


def _node_orders(rows: list[dict], clicks: list[tuple[int, bool, bool]]) -> list[list[int]]:
    """The row indices each (column, ascending, numeric) click gives, computed by node."""
    data = [{**r, "index": i, "values": [None if v is None else v for v in r["values"]]} for i, r in enumerate(rows)]
    # JSON has no Infinity: pass infinities as strings and turn them back in JS.
    for r in data:
        r["values"] = [
            ("inf" if v > 0 else "-inf") if v is not None and abs(v) == float("inf") else v for v in r["values"]
        ]
    script = (
        BOARD_ORDER_JS
        + f"""
const rows = {json.dumps(data)}.map(r => ({{...r, values: r.values.map(v => v === 'inf' ? Infinity
                                                                           : v === '-inf' ? -Infinity : v)}}));
const clicks = {json.dumps(clicks)};
console.log(JSON.stringify(clicks.map(([col, asc, num]) =>
  boardOrder(rows, col, asc, num, 0, 1).map(r => r.index))));
"""
    )
    out = subprocess.run([NODE, "-e", script], capture_output=True, text=True, timeout=60, check=True)
    return json.loads(out.stdout)


@pytest.mark.heavy
@pytest.mark.skipif(NODE is None, reason="node is not installed (the page's script runs under it here)")
def test_every_click_sorts_as_the_board_does(tmp_path):
    store_path = tmp_path / "r.sqlite"
    with ResultStore(store_path) as store:
        for ds, guessed in (("street", False), ("tunnel", True)):
            for codec, metrics in CONFIGS.items():
                for frame in range(2):
                    store.put(
                        ResultRow(
                            "frame", ds, f"{ds}:1", frame, codec, "1", {}, "ok", metrics, 0, sensor_guessed=guessed
                        )
                    )
    page = write_report(store_path, tmp_path / "out", REGISTRY)
    board = _Board()
    board.feed(page.read_text())
    assert "sensor guessed: the dataset&#x27;s beam table was guessed" in page.read_text()  # said once, under it
    labels = [(r["texts"][0], r["texts"][1]) for r in board.rows]
    with ResultStore(store_path, readonly=True) as store:
        default = build_leaderboard(store, info=INFO)
        assert labels == [(e.dataset, e.label) for e in default]  # the page opens in the board's order
        assert [r["last"] for r in board.rows] == [int(e.ranked_last) for e in default]
        clicks, expected = [], []
        for col, head in enumerate(board.heads):
            metric = head["title"].split(":")[0]
            if head["type"] != "num" or metric not in INFO:
                continue
            for asc in (True, False):
                clicks.append((col, asc, True))
                entries = build_leaderboard(store, info=INFO, sort=metric, descending=not asc)
                expected.append([(e.dataset, e.label) for e in entries])
    assert len(clicks) >= 10  # bytes, ratio, range_rmsd, coverage, chamfer, ... both ways
    for (col, asc, _), order, want in zip(clicks, _node_orders(board.rows, clicks), expected, strict=True):
        assert [labels[i] for i in order] == want, (board.heads[col]["text"], "asc" if asc else "desc")
    # Flagged rows stay last whichever way a column is clicked; the caveat moves nothing.
    flagged = {(e.dataset, e.label) for e in default if e.ranked_last}
    assert flagged == {(ds, c) for ds in ("street", "tunnel") for c in ("random", "voxel")}
    assert all(e.flags[-1:] == ["sensor_guessed"] for e in default if e.dataset == "tunnel")
