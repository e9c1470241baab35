"""Matplotlib, set up once for every figure lwbench writes (the report, ``lwbench view``, the
stream's Fig. 6d): headless (Agg), deterministic SVG ids, one font size, PNG + SVG for papers."""

from __future__ import annotations

import io
from pathlib import Path

__all__ = ["pyplot", "save_png_svg"]


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed), imported only when a figure
    is drawn: matplotlib costs ~0.5 s to import, which ``lwbench list`` should not pay."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"svg.hashsalt": "lwbench", "figure.dpi": 100, "font.size": 9})
    return plt


def save_png_svg(fig, out: Path, name: str, *, dpi: int = 150) -> str:
    """Write ``out/name.png`` and ``out/name.svg`` (no date in the SVG: the same figure gives the
    same bytes); return the SVG markup, for pages that inline it."""
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / f"{name}.png", bbox_inches="tight", dpi=dpi)
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    svg = buf.getvalue()
    (out / f"{name}.svg").write_text(svg)
    return svg[svg.index("<svg"):]
