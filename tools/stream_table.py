"""The Markdown table of docs/stream.md from a ``stream.json`` that ``lwbench stream`` wrote.

Usage: python tools/stream_table.py OUT/stream.json
"""

from __future__ import annotations

import argparse
import json


def main(path: str) -> None:
    d = json.load(open(path))
    print(
        "| codec | link | KB/s | total bytes | on time | late | dropped | lost | rejected "
        "| latency ms (median / p95) | encode / queue / transfer / decode ms (median) | link in a period | map IoU |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in d["runs"]:
        p = r["latency_parts_ms_median"]
        parts = " / ".join(f"{p[k]:.0f}" for k in ("encode", "queue", "transfer", "decode")) if p else "–"
        lat = "–" if r["latency_ms_median"] is None else f"{r['latency_ms_median']:.0f} / {r['latency_ms_p95']:.0f}"
        link = "–" if r.get("link_on_time_share") is None else f"{r['link_on_time_share']:.0%}"
        iou = "–" if r["map_iou"] is None else f"{r['map_iou']:.3f}"
        print(
            f"| {r['codec']} | {r['link']} | {r['kbps']:,.1f} | {r['wire_bytes']:,} | {r['on_time']}/{r['frames']} "
            f"| {r['late']} | {r['dropped']} | {r['lost']} | {r['rejected']} | {lat} | {parts} | {link} | {iou} |"
        )


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stream_json", help="a stream.json from lwbench stream --out")
    main(ap.parse_args().stream_json)
