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


def test_the_page_is_self_contained_and_every_plot_has_files(report):
    page = (report / "index.html").read_text()
    assert not re.search(r"""(src|href)=["']https?://""", page), "the page must open with no network"
    assert page.count("<tr") == 1 + 6  # header + six configurations
    assert "data:image/png;base64," in page  # the gallery, embedded
    for name in ("rd_chamfer", "rd_range_rmsd", "rd_d1_psnr", "runtime"):
        assert (report / f"{name}.png").stat().st_size > 1000 and (report / f"{name}.svg").exists()
    assert "low coverage" in page  # the quality flags travel into the report
    assert page.count('data-last="1"') == 2  # the two random selections rank last (and are grey)


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
