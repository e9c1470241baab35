"""The scout process: scans at the sensor's rate, encoded live, sent through the link model.

``python -m lwbench.link.scout CONFIG.json PORT`` (started by :mod:`.session`). It loads its
frames and warms the encoder up *before* the clock starts (the paper's scout is a running
system, not a cold start), connects, prints ``ready T0`` and then, for ``t >= T0``: scan ``i`` is
due at ``T0 + i / rate``. The encoder takes the newest scan due when it is free -- scans it had
no time for are dropped (``encoder_busy``), as a sensor topic of depth 1 does -- and hands the
payload to the :class:`~.transmit.Transmitter` (with ``encode: ahead`` every scan is encoded
and timed before the clock starts, and in the stream a payload is ready its measured encode time
after the encoder takes it up -- the same timeline, without the scout's encoding competing with
the base for one machine's cores). After the last scan it lets the link drain for
``drain_s`` and says END. Every event is one JSON line in ``scout.jsonl``.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

from .shaper import LinkModel
from .transmit import Transmitter

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    cfg = json.loads(Path(args[0]).read_text())
    port = int(args[1])
    work = Path(cfg["workdir"])  # threads: OMP_NUM_THREADS, set by the session

    from lwbench.registry import get_registry
    from lwbench.run.plan import DatasetSpec
    from lwbench.streamfile import StreamHeader

    reg = get_registry()
    ds = DatasetSpec(cfg["dataset"]["name"], cfg["dataset"]["params"]).build(reg)
    n = int(cfg["frames"])
    frames = [ds[i] for i in range(n)]
    codec_cls = reg.codec(cfg["codec"]["name"])
    encoder = codec_cls(**cfg["codec"]["params"])
    encoder.encode(frames[0])  # warm-up (imports, JIT, allocator): untimed, as the runner does
    encoder.reset_stream()  # a codec with state across a stream (vsgp's warm_start) starts it cold
    ahead: list[tuple[bytes, float]] = []
    if cfg.get("encode", "live") == "ahead":
        # Every scan encoded (and timed) now; in the stream each payload is ready its measured
        # encode time after the encoder takes it up: the scout does not compete with the base.
        for f in frames:
            t = time.perf_counter()
            payload = encoder.encode(f)
            ahead.append((payload, time.perf_counter() - t))
    rate = float(cfg["rate_hz"])
    period = 1.0 / rate
    header = StreamHeader.for_sensors(codec_cls.name, cfg["codec"]["params"], [frames[0].sensor])
    hello = {"stream": header.to_dict(), "frames": n, "rate_hz": rate}

    lock = threading.Lock()
    log_file = open(work / "scout.jsonl", "a", buffering=1)

    def log(event: dict) -> None:
        with lock:
            log_file.write(json.dumps(event) + "\n")

    t0 = time.monotonic() + float(cfg.get("lead_s", 0.5))
    link = LinkModel.from_dict(cfg["link"])
    tx = Transmitter(("127.0.0.1", port), link, hello, depth=int(cfg["queue"]), log=log, t0=t0)
    for _ in range(100):
        if tx.connect():
            break
        time.sleep(0.1)
    else:
        print("error could not connect to the base", flush=True)
        return 2
    tx.start()
    print(f"ready {t0!r}", flush=True)

    i = 0
    while i < n:
        now = time.monotonic()
        due = t0 + i * period
        if now < due:
            time.sleep(due - now)
        else:
            newest = min(n - 1, int((now - t0) / period))
            for j in range(i, newest):
                log({"ev": "encoder_busy", "seq": j})
            i = newest
            due = t0 + i * period
        start = time.monotonic()
        try:
            if ahead:
                payload, seconds = ahead[i]
                time.sleep(max(0.0, start + seconds - time.monotonic()))
            else:
                payload = encoder.encode(frames[i])
        except Exception as exc:  # noqa: BLE001 - a codec failure is this frame's outcome
            log({"ev": "encode_failed", "seq": i, "error": f"{type(exc).__name__}: {exc}"})
            i += 1
            continue
        end = time.monotonic()
        log({"ev": "encoded", "seq": i, "due": due, "enc_start": start, "enc_end": end, "bytes": len(payload),
             "raw_bytes": frames[i].raw_bytes})
        tx.offer(i, due, payload)
        i += 1
    stop = t0 + n * period + float(cfg["drain_s"])
    tx.close(stop, {"frames": n})
    bins = tx.stats
    log({"ev": "wire", "t0": t0, "bin_s": bins.bin_s, "bins": {str(k): v for k, v in sorted(bins.bins.items())},
         "bytes": bins.bytes, "last": bins.last, "stop": time.monotonic()})
    log_file.close()
    print("done", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
