"""The base process: receives payloads, decodes them, builds the occupancy map live.

``python -m lwbench.link.base CONFIG.json`` (started -- and restarted -- by :mod:`.session`).
It warms its decoder up on a synthetic scan, listens on 127.0.0.1 (the configured port, or any;
it prints ``listening PORT``) and serves one scout connection at a time:

- HELLO: the stream header; its sensor table is handed to the decoder, so payloads naming it by
  id decode;
- FRAME: the payload is checked and decoded (:func:`lwbench.run.evaluate.decoded_cloud`); a
  payload that fails -- corrupted on the wire, say -- is *rejected* and counted, never put in the
  map. A decoded cloud is saved (``frames/SEQ.npy``), logged, and inserted into the
  :class:`~lwbench.occupancy.OccupancyMap` by a second thread, so the map never holds
  up the next frame's reception;
- END: the map is finished and written (``map.npy``: occupied voxel keys), and the base exits.

A restarted base (the ``--restart-base-at`` fault) rebuilds its map from the clouds it had
logged, then resumes with whatever frame arrives next. Every event is a JSON line in
``base.jsonl``.
"""

from __future__ import annotations

import json
import queue
import signal
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np

__all__ = ["main"]


def _warm_up(codec_cls, params: dict) -> None:
    """Encode and decode a small synthetic scan once: first-call costs (imports, JIT) are paid
    before the stream starts, as on a base that has been running."""
    from lwbench.synthetic import tunnel_scan

    frame = tunnel_scan(0)
    frame = frame.subset(np.arange(0, len(frame), 8))
    codec = codec_cls(**params)
    codec.decode(codec.encode(frame))


class Base:
    def __init__(self, cfg: dict) -> None:
        from lwbench.registry import get_registry

        self.cfg = cfg
        self.work = Path(cfg["workdir"])
        (self.work / "frames").mkdir(parents=True, exist_ok=True)
        self.codec_cls = get_registry().codec(cfg["codec"]["name"])
        self.params = cfg["codec"]["params"]
        self.decoder = self.codec_cls(**self.params)
        self.log_file = open(self.work / "base.jsonl", "a", buffering=1)
        self.lock = threading.Lock()
        self.map = None
        self.maps: queue.Queue = queue.Queue()
        self.mapper = threading.Thread(target=self._map_worker, daemon=True)

    def log(self, event: dict) -> None:
        with self.lock:
            self.log_file.write(json.dumps(event) + "\n")

    # -- the map ------------------------------------------------------------------------------
    def _new_map(self, stream: dict) -> None:
        from lwbench.occupancy import OccupancyMap
        from lwbench.streamfile import StreamHeader

        header = StreamHeader.from_dict(stream, "HELLO")
        (sensor,) = header.sensor_models("HELLO")
        self.decoder.use_sensors([sensor])
        if self.map is None:
            self.map = OccupancyMap(sensor, float(self.cfg["voxel"]))

    def _map_worker(self) -> None:
        while True:
            item = self.maps.get()
            if item is None:
                return
            seq, points, pose = item
            t = time.monotonic()
            self.map.insert(points, pose)
            self.log({"ev": "mapped", "seq": seq, "map_ms": (time.monotonic() - t) * 1e3})

    def resume(self) -> int:
        """After a restart: the stream header and the clouds logged so far, back into the map."""
        hello = self.work / "hello.json"
        if not hello.is_file():
            return 0
        self._new_map(json.loads(hello.read_text()))
        done = 0
        for line in (self.work / "base.jsonl").read_text().splitlines():
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue  # the line being written when the base was killed
            if event.get("ev") == "frame" and event.get("status") == "ok" and event.get("pose") is not None:
                points = np.load(self.work / "frames" / f"{event['seq']:06d}.npy", allow_pickle=False)
                self.map.insert(points, np.asarray(event["pose"]))
                done += 1
        return done

    # -- receiving ----------------------------------------------------------------------------
    def frame(self, seq: int, due: float, body: bytes, recv_end: float) -> None:
        from lwbench.payload import Payload
        from lwbench.run.evaluate import decoded_cloud

        event: dict = {"ev": "frame", "seq": seq, "due": due, "recv_end": recv_end, "bytes": len(body)}
        try:
            payload = Payload.from_bytes(body, expect_codec=self.codec_cls.name)
            points = decoded_cloud(self.codec_cls.name, self.decoder.decode(body))
        except Exception as exc:  # noqa: BLE001 - a bad payload is rejected and counted, whatever the error
            error = f"{type(exc).__name__}: {exc}"
            self.log({**event, "status": "rejected", "dec_end": time.monotonic(), "error": error})
            return
        dec_end = time.monotonic()
        pose = None if payload.pose is None else payload.pose
        np.save(self.work / "frames" / f"{seq:06d}.npy", points, allow_pickle=False)
        self.log({**event, "status": "ok", "dec_end": dec_end, "points": int(len(points)),
                  "pose": None if pose is None else pose.tolist()})
        if pose is not None and self.map is not None:
            self.maps.put((seq, points, pose))

    def finish(self) -> None:
        self.maps.put(None)
        self.mapper.join()
        keys = self.map.occupied() if self.map is not None else np.zeros(0, np.int64)
        np.save(self.work / "map.npy", keys, allow_pickle=False)
        self.log({"ev": "end", "t": time.monotonic(), "occupied": int(len(keys)),
                  "scans": 0 if self.map is None else self.map.scans})

    def serve(self, server: socket.socket) -> None:
        from .wire import END, FRAME, HELLO, WireError, read_message

        server.settimeout(float(self.cfg["base_timeout_s"]))
        while True:
            try:
                conn, _ = server.accept()
            except TimeoutError:
                self.log({"ev": "timeout", "t": time.monotonic()})
                return self.finish()
            conn.settimeout(float(self.cfg["base_timeout_s"]))
            self.log({"ev": "accepted", "t": time.monotonic()})
            try:
                while True:
                    msg = read_message(conn)
                    if msg is None:
                        self.log({"ev": "closed", "t": time.monotonic()})
                        break
                    if msg.kind == HELLO:
                        stream = msg.json()["stream"]
                        if self.map is None:
                            (self.work / "hello.json").write_text(json.dumps(stream))
                        self._new_map(stream)
                    elif msg.kind == FRAME:
                        self.frame(msg.seq, msg.due, msg.body, time.monotonic())
                    elif msg.kind == END:
                        self.finish()
                        return
            except (WireError, OSError) as exc:
                self.log({"ev": "broken", "t": time.monotonic(), "error": f"{type(exc).__name__}: {exc}"})
            finally:
                conn.close()


class _Finish(Exception):
    """SIGTERM from the session: the END never came (the scout ended while this base was down)."""


def _on_term(signum, frame) -> None:
    raise _Finish


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    cfg = json.loads(Path(args[0]).read_text())  # threads: OMP_NUM_THREADS, set by the session
    base = Base(cfg)
    _warm_up(base.codec_cls, base.params)
    t = time.monotonic()
    resumed = base.resume()
    base.mapper.start()
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", int(cfg.get("port", 0))))
    server.listen(1)
    port = server.getsockname()[1]
    base.log({"ev": "start", "t": time.monotonic(), "port": port, "resumed": resumed,
              "resume_s": time.monotonic() - t})
    print(f"listening {port}", flush=True)
    signal.signal(signal.SIGTERM, _on_term)
    try:
        base.serve(server)
    except _Finish:
        base.log({"ev": "terminated", "t": time.monotonic()})
        base.finish()
    finally:
        server.close()
    print("done", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
