#!/usr/bin/env python3
"""Build MPEG's G-PCC reference codec (TMC13's `tmc3`) out of tree, cached by the source's hash.

Used by `.ci/run` (and by hand) for the `gpcc` codec; needs only Python, cmake and a C++ compiler,
imports nothing of lwbench.

    python3 .ci/build_tmc3.py [SOURCE]      # default SOURCE: ../shared/third_party/mpeg-pcc-tmc13

The binary goes to `$XDG_CACHE_HOME/lwbench/tmc3/<12 hex of the source's sha256>/build/tmc3/tmc3`
(`~/.cache/...` by default); an existing binary for the same hash is reused, no build. On success
the binary's path is the last line of stdout (so `LWBENCH_TMC3=$(... | tail -1)`); exit status 0.
Without the source: nothing is built, a line on stderr, exit status 2. A failed build prints the
tail of its log on stderr and exits 1. The source tree is read only and never copied.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SOURCE = ROOT.parent / "shared" / "third_party" / "mpeg-pcc-tmc13"


def source_hash(src: Path) -> str:
    h = hashlib.sha256()
    for path in sorted(p for p in src.rglob("*") if p.is_file()):
        rel = path.relative_to(src).as_posix()
        if rel.startswith("build/"):
            continue
        h.update(rel.encode() + b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:12]


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "lwbench" / "tmc3"


def main(argv: list[str]) -> int:
    src = Path(argv[1]) if len(argv) > 1 else DEFAULT_SOURCE
    if not (src / "CMakeLists.txt").is_file():
        print(f"build_tmc3: no TMC13 source at {src}: tmc3 not built", file=sys.stderr)
        return 2
    out = cache_dir() / source_hash(src)
    binary = out / "build" / "tmc3" / "tmc3"
    if binary.is_file() and os.access(binary, os.X_OK):
        print(f"build_tmc3: cached {binary}", file=sys.stderr)
        print(binary)
        return 0
    out.mkdir(parents=True, exist_ok=True)
    log = out / "build.log"
    jobs = os.environ.get("TMC3_JOBS", "2")
    with open(log, "w") as fh:
        for cmd in (
            ["cmake", "-S", str(src), "-B", str(out / "build"), "-DCMAKE_BUILD_TYPE=Release"],
            ["cmake", "--build", str(out / "build"), f"-j{jobs}", "--target", "tmc3"],
        ):
            fh.write("$ " + " ".join(cmd) + "\n")
            fh.flush()
            rc = subprocess.call(cmd, stdout=fh, stderr=subprocess.STDOUT)
            if rc != 0:
                break
    if rc != 0 or not binary.is_file():
        tail = log.read_text(errors="replace").splitlines()[-40:]
        print(f"build_tmc3: build failed (log {log}); last lines:", file=sys.stderr)
        print("\n".join(tail), file=sys.stderr)
        return 1
    print(f"build_tmc3: built {binary}", file=sys.stderr)
    print(binary)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
