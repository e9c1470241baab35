"""Run one `lwbench run` and measure what issue 31 asks of it: peak RSS of the whole process tree
(the driver and every worker, summed, sampled every 0.5 s), wall time of each phase (from the
run's own progress lines), and the disk beside the store against the stored payload bytes.

    python tools/scale_run.py --store /tmp/s100.sqlite -- --dataset sim --dataset-param scene=town \\
        --dataset-param frames=100 --dataset-param cache=false --codec raw --codec random --codec draco

Prints one JSON line (and writes it to --out when given). psutil is the one extra it needs.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil


def tree_rss(proc: psutil.Process) -> int:
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def phase_seconds(log: str) -> dict[str, float]:
    """``lwbench: <phase> done: N/N in 3m10s`` lines -> {phase: seconds}."""
    out = {}
    for m in re.finditer(r"lwbench: (.+?) done: \S+ in (?:(\d+)h)?(?:(\d+)m)?(\d+)?s?", log):
        h, mnt, s = (int(x) if x else 0 for x in m.groups()[1:])
        out[m.group(1).strip()] = 3600 * h + 60 * mnt + s
    return out


def payload_bytes(store: Path) -> tuple[int, int]:
    """(bytes of every stored payload, bytes of the gallery clouds) of a store."""
    from lwbench.results.store import ResultStore
    from lwbench.run.record import DECODED, PAYLOAD

    payloads = gallery = 0
    with ResultStore(store, readonly=True) as results:
        for row in results.rows(kind="frame"):
            p = results.artifact_digest(row.evaluation, PAYLOAD)
            if p is not None:
                payloads += int(row.metrics.get("bytes") or 0)
            d = results.artifact_digest(row.evaluation, DECODED)
            if d is not None:
                gallery += results.files.path(d).stat().st_size
    return payloads, gallery


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", required=True, type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("args", nargs=argparse.REMAINDER, help="-- then the `lwbench run` arguments")
    a = ap.parse_args()
    args = [x for x in a.args if x != "--"]
    cmd = [sys.executable, "-m", "lwbench.cli", "run", "--store", str(a.store), *args]
    env = {**__import__("os").environ, "LWBENCH_PROGRESS_S": "30"}
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    ps = psutil.Process(proc.pid)
    peak = [0]
    phase = ["start"]
    by_phase: dict[str, int] = {}
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            rss = tree_rss(ps)
            peak[0] = max(peak[0], rss)
            by_phase[phase[0]] = max(by_phase.get(phase[0], 0), rss)
            time.sleep(0.5)

    lines: list[str] = []

    def read_stderr() -> None:
        # The phase each sample belongs to, from the run's own progress lines.
        for line in proc.stderr:
            lines.append(line)
            if "lwbench: frames" in line:
                phase[0] = "frames"
            elif "lwbench: sequence metrics" in line:
                phase[0] = "sequence"

    sampler = threading.Thread(target=sample, daemon=True)
    reader = threading.Thread(target=read_stderr, daemon=True)
    sampler.start()
    reader.start()
    proc.stdout.read()  # the board: not measured
    proc.wait()
    reader.join()
    done.set()
    sampler.join()
    err = "".join(lines)
    wall = time.monotonic() - t0
    clouds = a.store.with_name(a.store.stem + ".clouds")
    disk = sum(p.stat().st_size for p in clouds.rglob("*") if p.is_file()) if clouds.is_dir() else 0
    payloads, gallery = payload_bytes(a.store) if a.store.is_file() else (0, 0)
    record = {
        "args": args, "rc": proc.returncode, "wall_s": round(wall, 1), "peak_tree_rss_mb": round(peak[0] / 2**20),
        "peak_tree_rss_mb_by_phase": {k: round(v / 2**20) for k, v in by_phase.items()},
        "phases_s": phase_seconds(err), "disk_beside_store_mb": round(disk / 2**20, 1),
        "payload_mb": round(payloads / 2**20, 1), "gallery_mb": round(gallery / 2**20, 1),
        "disk_over_payloads_plus_gallery": round(disk / max(payloads + gallery, 1), 3),
        "store_mb": round(a.store.stat().st_size / 2**20, 1) if a.store.is_file() else 0,
    }
    line = json.dumps(record)
    print(line)
    if a.out:
        with a.out.open("a") as fh:
            fh.write(line + "\n")
    if proc.returncode != 0:
        print(err[-3000:], file=sys.stderr)
        sys.exit(proc.returncode)


if __name__ == "__main__":
    main()
