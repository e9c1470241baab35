"""One stream, end to end: a scout process and a base process on 127.0.0.1, measured.

:func:`run_stream` writes a JSON config, starts the base (``python -m lwbench.link.base``) and the
scout (``python -m lwbench.link.scout``), injects the base-restart fault if asked (``SIGKILL``,
then a new base on the same port), waits -- every wait bounded -- and reads both processes'
event logs back into one :class:`StreamRun`: each frame's fate and latency, the bytes on the
wire over time, and the base's final map against the map from the raw scans.

A frame is **on time** when the base has decoded it before the next scan is due (latency
<= one sensor period), **late** after that; otherwise it was **dropped** (the encoder was busy,
the queue pushed it out, the base was down, or the link was still busy with it when the stream
ended), **lost** (a packet lost on the link) or **rejected** (the base's decoder refused it: a
payload corrupted on the wire). Latency = encode (from the scan's due time, waiting for the
encoder included) + queue + transfer (shaping, delay, socket) + decode.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lwbench.errors import LwbenchError, ParameterError

from .shaper import KB, LinkModel

__all__ = ["FrameOutcome", "StreamRun", "StreamSettings", "reference_map", "run_stream"]


@dataclass(frozen=True)
class StreamSettings:
    """How a stream runs (the link itself is a :class:`~.shaper.LinkModel`)."""

    frames: int = 40
    queue: int = 5  # frames the scout keeps waiting for the link (ROS 2 sensor-data QoS: keep last 5)
    drain_s: float = 2.0  # after the last scan, how long the link may go on
    threads: int = 1  # torch/OpenMP threads per process: the scout and the base are two machines
    voxel: float = 0.2
    restart_at: float | None = None  # s after the first scan: the base is killed and restarted
    restart_down_s: float = 0.5
    lead_s: float = 0.5
    start_timeout_s: float = 300.0
    encode: str = "live"  # or "ahead": encoded and timed before the clock starts (see .scout)

    def __post_init__(self) -> None:
        if self.encode not in ("live", "ahead"):
            raise ParameterError(f"--encode must be live or ahead, got {self.encode!r}")
        if self.frames < 1 or self.queue < 1 or self.drain_s < 0 or self.threads < 1 or self.voxel <= 0:
            raise ParameterError("need frames >= 1, queue >= 1, drain >= 0, threads >= 1, voxel > 0")


@dataclass
class FrameOutcome:
    seq: int
    status: str  # on_time | late | dropped | lost | rejected | failed
    reason: str = ""
    latency: float | None = None  # s
    parts: dict[str, float] = field(default_factory=dict)  # encode, queue, transfer, decode (s)
    payload_bytes: int | None = None


@dataclass
class StreamRun:
    codec: str
    link: LinkModel
    rate_hz: float
    outcomes: list[FrameOutcome]
    wire_bytes: int
    wire_bins: dict[int, int]
    bin_s: float
    duration: float  # s from the first scan's due time to the end of sending
    iou: float | None
    map_voxels: int
    reference_voxels: int
    base_starts: int
    corrupted_sent: int
    events: dict[str, int] = field(default_factory=dict)

    frames_sent: int = 0  # frames whose packets all went on the wire (delivered or not)

    def count(self, *status: str) -> int:
        return sum(o.status in status for o in self.outcomes)

    @property
    def kbps(self) -> float:
        return self.wire_bytes / KB / self.duration if self.duration > 0 else 0.0

    def link_on_time(self) -> float | None:
        """Of the frames the scout encoded, the share that crossed the link -- queue and transfer --
        within one period: whether the link carries this codec at this cap, whatever the CPUs
        at either end take to encode and decode (the latency's other parts)."""
        encoded = [o for o in self.outcomes if o.payload_bytes is not None]
        if not encoded:
            return None
        ok = [o for o in encoded if o.parts and o.parts["queue"] + o.parts["transfer"] <= 1.0 / self.rate_hz]
        return len(ok) / len(encoded)

    def latencies(self) -> np.ndarray:
        return np.array([o.latency for o in self.outcomes if o.latency is not None])

    def summary(self) -> dict[str, Any]:
        lat = self.latencies()
        parts = {k: float(np.median([o.parts[k] for o in self.outcomes if k in o.parts]) * 1e3)
                 for k in ("encode", "queue", "transfer", "decode") if any(k in o.parts for o in self.outcomes)}
        n = len(self.outcomes)
        return {
            "codec": self.codec, "link": self.link.label, "cap_kbps": self.link.rate_kbps, "frames": n,
            "rate_hz": self.rate_hz, "kbps": self.kbps, "wire_bytes": self.wire_bytes,
            "payload_bytes_mean": float(np.mean([o.payload_bytes for o in self.outcomes if o.payload_bytes]))
            if any(o.payload_bytes for o in self.outcomes) else None,
            "on_time": self.count("on_time"), "late": self.count("late"), "dropped": self.count("dropped"),
            "lost": self.count("lost"), "rejected": self.count("rejected"), "failed": self.count("failed"),
            "on_time_share": self.count("on_time") / n if n else None,
            "link_on_time_share": self.link_on_time(),
            "latency_ms_median": float(np.median(lat) * 1e3) if len(lat) else None,
            "latency_ms_p95": float(np.percentile(lat, 95) * 1e3) if len(lat) else None,
            "latency_parts_ms_median": parts,
            "map_iou": self.iou, "map_voxels": self.map_voxels, "reference_voxels": self.reference_voxels,
            "base_starts": self.base_starts, "corrupted_sent": self.corrupted_sent, "frames_sent": self.frames_sent,
            "dropped_why": {r: sum(o.reason == r for o in self.outcomes if o.status == "dropped")
                            for r in sorted({o.reason for o in self.outcomes if o.status == "dropped"})},
        }

    def series(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time (s, bin ends), rate (KB/s over the bin) and accumulated bytes: Fig. 6d's curves."""
        if not self.wire_bins:
            return np.zeros(0), np.zeros(0), np.zeros(0)
        k = np.arange(0, max(self.wire_bins) + 1)
        b = np.array([self.wire_bins.get(int(i), 0) for i in k], dtype=np.float64)
        return (k + 1) * self.bin_s, b / KB / self.bin_s, np.cumsum(b)


# ------------------------------------------------------------------------------ the reference
def wire_pose(pose: np.ndarray | None) -> np.ndarray | None:
    """A pose as a payload carries it (6 x float32), so reference and base place scans alike."""
    if pose is None:
        return None
    from lwbench.payload import Payload

    return Payload.from_bytes(Payload("x", {}, b"", pose).to_bytes()).pose


def reference_map(frames: list, voxel: float) -> np.ndarray | None:
    """The map the base would build from every raw scan (None without poses)."""
    from lwbench.occupancy import occupied_voxels

    if any(f.pose is None for f in frames):
        return None
    poses = np.stack([wire_pose(f.pose) for f in frames])
    return occupied_voxels([f.points for f in frames], poses, frames[0].sensor, voxel)


# ---------------------------------------------------------------------------------- processes
class _Child:
    """A child process whose stdout lines are collected by a thread (waits never block forever)."""

    def __init__(self, name: str, args: list[str], env: dict, work: Path) -> None:
        self.name = name
        self.stderr_path = work / f"{name}.stderr"
        self._err = open(self.stderr_path, "a")
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=self._err, text=True, env=env,
                                     cwd=work, start_new_session=True)
        self.lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.strip())
        self.lines.put(None)

    def tail(self) -> str:
        self._err.flush()
        text = self.stderr_path.read_text(errors="replace").strip().splitlines()
        return " | ".join(text[-3:]) if text else "(no output)"

    def expect(self, prefix: str, timeout: float) -> str:
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise LwbenchError(f"stream: the {self.name} did not say {prefix!r} within {timeout:.0f} s")
            try:
                line = self.lines.get(timeout=min(left, 1.0))
            except queue.Empty:
                continue
            if line is None:
                self.proc.wait(5)
                raise LwbenchError(f"stream: the {self.name} exited ({self.proc.returncode}): {self.tail()}")
            if line.startswith(prefix):
                return line[len(prefix):].strip()

    def wait(self, timeout: float) -> bool:
        try:
            self.proc.wait(max(timeout, 0.0))
            return True
        except subprocess.TimeoutExpired:
            return False

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)  # its own session: the child and nothing else
            self.proc.wait(10)
        self._err.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _read_log(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue  # a line cut off when its process was killed
    return out


# ---------------------------------------------------------------------------------- the run
def run_stream(
    dataset: dict[str, Any],
    codec: dict[str, Any],
    link: LinkModel,
    settings: StreamSettings,
    *,
    rate_hz: float,
    reference: np.ndarray | None,
    workdir: Path | None = None,
    on_scan: Callable[[int, int], None] | None = None,
) -> StreamRun:
    """Stream ``settings.frames`` frames of ``dataset`` ({name, params}) encoded by ``codec``
    ({name, params}: a resolved configuration) through ``link``; bounded in time, always
    cleans up its processes. ``reference``: :func:`reference_map` of the same frames.
    ``on_scan(done, n)``: about once a second, how many scans the scout has dealt with (encoded,
    skipped while its encoder was busy, or failed)."""
    own = workdir is None
    tmp = tempfile.TemporaryDirectory(prefix="lwbench-stream-") if own else None
    work = Path(tmp.name) if tmp is not None else Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    try:
        return _run(dataset, codec, link, settings, rate_hz, reference, work, on_scan)
    finally:
        if tmp is not None:
            tmp.cleanup()


def _scout_progress(work: Path) -> int:
    """Scans the scout has dealt with so far, from its log (one event per scan: encoded, skipped
    or failed; the log is line-buffered, so a line is whole or absent)."""
    try:
        text = (work / "scout.jsonl").read_text()
    except OSError:
        return 0
    return sum(text.count(f'"ev": "{ev}"') for ev in _SCAN_EVENTS)


_SCAN_EVENTS = ("encoded", "encoder_busy", "encode_failed")


def _run(dataset, codec, link, settings, rate_hz, reference, work: Path, on_scan=None) -> StreamRun:
    length = settings.frames / rate_hz
    if settings.restart_at is not None and not 0 <= settings.restart_at < length:
        raise ParameterError(
            f"--restart-base-at must fall inside the stream (0 to {length:g} s), got {settings.restart_at}"
        )
    port = _free_port()
    cfg = {
        "dataset": dataset, "codec": codec, "link": link.to_dict(), "frames": settings.frames,
        "rate_hz": rate_hz, "queue": settings.queue, "drain_s": settings.drain_s, "threads": settings.threads,
        "voxel": settings.voxel, "lead_s": settings.lead_s, "workdir": str(work), "port": port,
        "encode": settings.encode,
        # The base gives up waiting after this long without a message (a scout that died).
        "base_timeout_s": settings.frames / rate_hz + settings.drain_s + 60.0,
    }
    (work / "config.json").write_text(json.dumps(cfg, indent=1))
    env = {**os.environ, "OMP_NUM_THREADS": str(settings.threads), "MKL_NUM_THREADS": str(settings.threads),
           "PYTHONWARNINGS": "ignore"}
    py = [sys.executable, "-m"]
    children: list[_Child] = []
    base_starts = 0
    try:
        base = _Child("base", [*py, "lwbench.link.base", str(work / "config.json")], env, work)
        children.append(base)
        base_starts += 1
        scout = _Child("scout", [*py, "lwbench.link.scout", str(work / "config.json"), str(port)], env, work)
        children.append(scout)
        base.expect("listening", settings.start_timeout_s)
        t0 = float(scout.expect("ready", settings.start_timeout_s))
        length = settings.frames / rate_hz + settings.drain_s
        if settings.restart_at is not None:
            time.sleep(max(0.0, t0 + settings.restart_at - time.monotonic()))
            base.kill()
            time.sleep(settings.restart_down_s)
            base = _Child("base", [*py, "lwbench.link.base", str(work / "config.json")], env, work)
            children.append(base)
            base_starts += 1
            base.expect("listening", settings.start_timeout_s)
        budget = max(0.0, t0 + length - time.monotonic()) + 60.0
        end = time.monotonic() + budget
        while not scout.wait(min(1.0, end - time.monotonic())):
            if time.monotonic() >= end:
                raise LwbenchError(f"stream: the scout did not finish within {budget:.0f} s")
            if on_scan is not None:
                on_scan(_scout_progress(work), settings.frames)
        if on_scan is not None:
            on_scan(_scout_progress(work), settings.frames)
        if scout.proc.returncode != 0:
            raise LwbenchError(f"stream: the scout failed ({scout.proc.returncode}): {scout.tail()}")
        if not base.wait(10.0):
            # The END did not reach it (the scout ended while it was down): ask it to finish.
            base.proc.terminate()
            if not base.wait(30.0):
                raise LwbenchError("stream: the base did not finish within 40 s of the scout's end")
    finally:
        for c in children:
            c.kill()
    return _collect(work, codec["name"], link, settings, rate_hz, t0, reference, base_starts)


def _collect(work: Path, codec: str, link: LinkModel, settings: StreamSettings, rate_hz: float, t0: float,
             reference: np.ndarray | None, base_starts: int) -> StreamRun:
    period = 1.0 / rate_hz
    scout, base = _read_log(work / "scout.jsonl"), _read_log(work / "base.jsonl")
    by_seq: dict[int, dict[str, dict]] = {}
    events: dict[str, int] = {}
    wire = next((e for e in scout if e["ev"] == "wire"), None)
    for e in scout + base:
        events[e["ev"]] = events.get(e["ev"], 0) + 1
        if "seq" in e and e["ev"] != "wire":
            by_seq.setdefault(int(e["seq"]), {})[e["ev"]] = e
    outcomes = []
    for seq in range(settings.frames):
        ev = by_seq.get(seq, {})
        enc = ev.get("encoded", {})
        out = FrameOutcome(seq, "dropped", payload_bytes=enc.get("bytes"))
        got = ev.get("frame")
        if got is not None and got["status"] == "ok":
            sent = ev.get("sent", {})
            out.latency = got["dec_end"] - got["due"]
            out.status = "on_time" if out.latency <= period else "late"
            if enc and sent:
                out.parts = {"encode": enc["enc_end"] - got["due"], "queue": sent["tx_start"] - enc["enc_end"],
                             "transfer": got["recv_end"] - sent["tx_start"], "decode": got["dec_end"] - got["recv_end"]}
        elif got is not None:
            out.status, out.reason = "rejected", got.get("error", "")
        elif "lost" in ev:
            out.status, out.reason = "lost", "a packet lost on the link"
        elif "encode_failed" in ev:
            out.status, out.reason = "failed", ev["encode_failed"]["error"]
        else:
            out.reason = next((why for key, why in (
                ("encoder_busy", "encoder busy"), ("dropped_queue", "queue full"), ("base_down", "base down"),
                ("unsent", "link busy at the end"), ("sent", "in flight when the base went down"),
            ) if key in ev), "never encoded")
        outcomes.append(out)
    if wire is not None:
        bins = {int(k): int(v) for k, v in wire["bins"].items()}
        wire_bytes, bin_s = int(wire["bytes"]), float(wire["bin_s"])
        duration = max(settings.frames * period, float(wire["last"]) - t0)
    else:
        bins, wire_bytes, bin_s, duration = {}, 0, 0.1, settings.frames * period
    keys = np.load(work / "map.npy", allow_pickle=False) if (work / "map.npy").is_file() else None
    iou = None
    if keys is not None and reference is not None:
        from lwbench.occupancy import compare_occupancy

        iou = compare_occupancy(reference, keys)["iou"]
        iou = 0.0 if iou is None and len(reference) else iou
    return StreamRun(
        codec, link, rate_hz, outcomes, wire_bytes, bins, bin_s, duration, iou,
        0 if keys is None else int(len(keys)), 0 if reference is None else int(len(reference)), base_starts,
        sum(1 for e in scout if e["ev"] in ("sent", "lost") and e.get("corrupted")), events,
        sum(1 for e in scout if e["ev"] in ("sent", "lost")),
    )
