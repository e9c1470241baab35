"""``lwbench report``: the page is self-contained, and -- in a real browser (Debian's chromium,
headless) -- loads without console errors and sorts its table when a header is clicked."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lwbench.cli import app

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def report(tmp_path_factory, kitti_folder) -> Path:
    root = tmp_path_factory.mktemp("report")
    store = root / "r.sqlite"
    res = CliRunner().invoke(app, ["run", "--dataset", str(kitti_folder), "--frames", "2", "--store", str(store),
                                   "--codec", "raw", "--codec", "draco", "--param", "draco.quantization_bits=12,14,16",
                                   "--codec", "random", "--param", "random.ratio=0.1,0.5"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["report", "--store", str(store), "--out", str(root / "out")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return root / "out"


@pytest.mark.heavy
def test_the_page_is_self_contained_and_every_plot_has_files(report):
    page = (report / "index.html").read_text()
    assert not re.search(r"""(src|href)=["']https?://""", page), "the page must open with no network"
    assert page.count("<tr") == 1 + 6  # header + six configurations
    assert "data:image/png;base64," in page  # the gallery, embedded
    for name in ("rd_chamfer", "rd_range_rmsd", "rd_d1_psnr", "runtime"):
        assert (report / f"{name}.png").stat().st_size > 1000 and (report / f"{name}.svg").exists()
    assert "low coverage" in page  # the quality flags travel into the report
    assert page.count('data-last="1"') == 2  # the two random selections rank last (and are grey)


@pytest.mark.heavy
@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed here (Debian: apt-get install chromium)")
def test_the_page_in_a_headless_browser(report, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (the dev extra) is not installed")
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=CHROMIUM,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run"],
        )
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto((report / "index.html").as_uri())
        codecs = page.locator("#board tbody tr td:first-child")
        before = codecs.all_inner_texts()
        header = page.locator("#board th", has_text="bytes")
        header.click()
        ascending = page.locator("#board tbody tr td:first-child").all_inner_texts()
        header.click()
        descending = page.locator("#board tbody tr td:first-child").all_inner_texts()
        page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
        browser.close()
    assert not errors, errors
    assert sorted(before) == sorted(ascending) == sorted(descending)
    # Fewest / most bytes first -- among the unflagged rows: the random selections (low coverage)
    # stay last either way, as on the terminal's board (issue 23).
    assert ascending[0].startswith("draco(quantization_bits=12") and descending[0] == "raw"
    assert [c.split("(")[0] for c in ascending[-2:]] == [c.split("(")[0] for c in descending[-2:]] == ["random"] * 2
    assert ascending[-2].startswith("random(ratio=0.1") and descending[-2].startswith("random(ratio=0.5")
    assert descending[:4] == list(reversed(ascending[:4]))
    assert (tmp_path / "report.png").stat().st_size > 10_000


def _wide_board_page(tmp_path: Path) -> Path:
    """A board as wide as a real sweep makes it: two datasets, VSGP labels with four parameters
    off their defaults, every default column filled, and long flags (issue 33: such a board ran
    past a 1,400 px window)."""
    from lwbench.registry import get_registry
    from lwbench.results.leaderboard import LeaderboardEntry
    from lwbench.results.report import _STYLE, _table

    info = get_registry().metric_info()
    cols = [i for i, m in info.items() if m.default or getattr(m, "role", "") == "rate"]
    entries = []
    for ds in ("sim:tunnel(frames=40, seed=7, sensor=vlp16)", "kitti:/data/drives/2011_09_26_drive_0001_sync"):
        for m in (100, 300, 500):
            stats = {c: {"mean": 1234.5678 + m, "std": 1.0} for c in cols}
            entries.append(LeaderboardEntry(
                ds, "vsgp", {"num_inducing": m, "residual": 0.25, "upsample": 2.0, "variance_threshold": 0.125},
                frames=40, stats=stats, flags=["low_coverage", "sensor_guessed"]))
    page = tmp_path / "wide.html"
    page.write_text(f"<!doctype html><html><head><meta charset='utf-8'><style>{_STYLE}</style></head>"
                    f"<body>{_table(entries, info)}</body></html>")
    return page


@pytest.mark.heavy
@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed here (Debian: apt-get install chromium)")
def test_a_wide_board_never_widens_the_page_past_a_1400px_window(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (the dev extra) is not installed")
    page_file = _wide_board_page(tmp_path)
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--disable-gpu"])
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(page_file.as_uri())
        page_width = page.evaluate("document.documentElement.scrollWidth")
        board = page.evaluate("(() => { const b = document.querySelector('div.board'); "
                              "return [b.scrollWidth, b.clientWidth]; })()")
        cells = page.evaluate("Array.from(document.querySelectorAll('#board td.text')).map(c => c.offsetWidth)")
        browser.close()
    assert page_width <= 1400, f"the page is {page_width} px wide in a 1,400 px window"
    assert board[0] <= board[1], f"the board needs {board[0]} px, its box is {board[1]} px: it scrolls"
    assert cells and max(cells) <= 22 * 16 + 20  # labels and flags wrap at 22rem (+ padding)
