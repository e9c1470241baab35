"""The scout's transmit path: a bounded frame queue, the link model, a real TCP socket.

Two threads. The *shaper* takes the oldest queued frame, cuts it into packets, waits for each
packet's tokens (:class:`~.shaper.TokenBucket`) and hands it to the *writer* with a release time
(now + delay); the writer writes packets to the socket when their time comes. The queue keeps
the newest ``depth`` frames (as ROS 2's keep-last QoS): a frame pushed out by a newer one is
dropped, never sent late. When the base is gone (a write fails, a reconnect is refused) frames
are dropped as ``base_down`` until a reconnect succeeds; every new connection starts with the
HELLO (the stream header), so a restarted base learns the sensor table again.

Everything that happens to a frame is reported through ``log`` (one dict per event), and the
bytes that went on the wire are binned by release time (``bin_s``) for the rate-over-time plot.
"""

from __future__ import annotations

import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from .shaper import LinkModel, TokenBucket
from .wire import END, FRAME, HEADER, HELLO, pack, pack_json

__all__ = ["Transmitter"]


@dataclass
class _Queued:
    seq: int
    due: float
    payload: bytes
    queued_at: float


@dataclass
class _WireStats:
    bin_s: float
    t0: float
    bins: dict[int, int] = field(default_factory=dict)
    bytes: int = 0
    last: float = 0.0

    def add(self, t: float, n: int) -> None:
        k = int((t - self.t0) // self.bin_s)
        self.bins[k] = self.bins.get(k, 0) + n
        self.bytes += n
        self.last = max(self.last, t)


class Transmitter:
    """Frames in (:meth:`offer`), packets out over a socket to ``address`` (see module docstring)."""

    def __init__(self, address: tuple[str, int], link: LinkModel, hello: dict, *, depth: int,
                 log: Callable[[dict], None], t0: float, bin_s: float = 0.1) -> None:
        self.address, self.link, self.hello, self.depth, self.log = address, link, hello, depth, log
        self.bucket = TokenBucket(link.rate, link.bucket)
        self.rng = link.rng()
        self.stats = _WireStats(bin_s, t0)
        self._queue: deque[_Queued] = deque()
        self._cv = threading.Condition()
        self._packets: deque[tuple[float, bytes, int | None]] = deque()  # (release, bytes, seq ending here)
        self._pcv = threading.Condition()
        self._sock: socket.socket | None = None
        self._broken = False
        self._stop = False
        self._abort = False
        self.midframe = False  # the shaper stopped inside a frame (the stream must not go on)
        self._shaper = threading.Thread(target=self._shape, name="shaper", daemon=True)
        self._writer = threading.Thread(target=self._write, name="writer", daemon=True)

    # -- connection ---------------------------------------------------------------------------
    def connect(self, timeout: float = 0.5) -> bool:
        """Open a connection to the base (True on success) and queue the HELLO on it."""
        try:
            sock = socket.create_connection(self.address, timeout=timeout)
        except OSError:
            return False
        sock.settimeout(10.0)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._pcv:
            self._sock, self._broken = sock, False
        self.log({"ev": "connected", "t": time.monotonic()})
        self._send_now(pack_json(HELLO, 0, 0.0, self.hello))
        return True

    def _connected(self) -> bool:
        with self._pcv:
            return self._sock is not None and not self._broken

    def _send_now(self, data: bytes) -> None:
        """Control bytes (HELLO, END) through the bucket like any other, but not counted as a frame."""
        for i in range(0, len(data), self.link.mtu):
            chunk = data[i : i + self.link.mtu]
            t = self.bucket.take(len(chunk))
            self.stats.add(t, len(chunk))
            self._push(t + self.link.delay_ms / 1000, chunk, None)

    def _push(self, release: float, chunk: bytes, seq: int | None) -> None:
        limit = max(4 * self.link.bucket, 1 << 20)
        with self._pcv:
            while sum(len(c) for _, c, _ in self._packets) > limit and not self._abort:
                self._pcv.wait(0.05)
            self._packets.append((release, chunk, seq))
            self._pcv.notify_all()

    # -- frames in ----------------------------------------------------------------------------
    def start(self) -> None:
        self._shaper.start()
        self._writer.start()

    def offer(self, seq: int, due: float, payload: bytes) -> None:
        """A frame ready to send; the oldest waiting frame is dropped if the queue is full."""
        with self._cv:
            while len(self._queue) >= self.depth:
                old = self._queue.popleft()
                self.log({"ev": "dropped_queue", "seq": old.seq})
            self._queue.append(_Queued(seq, due, payload, time.monotonic()))
            self._cv.notify_all()

    def _next(self) -> _Queued | None:
        with self._cv:
            while not self._queue and not self._stop:
                self._cv.wait(0.05)
            return self._queue.popleft() if self._queue else None

    def _shape(self) -> None:
        while not self._abort:
            item = self._next()
            if item is None:
                if self._stop:
                    return
                continue
            if not self._connected() and not self.connect():
                self.log({"ev": "base_down", "seq": item.seq})
                continue
            self._send_frame(item)

    def _send_frame(self, item: _Queued) -> None:
        data = bytearray(pack(FRAME, item.seq, item.due, item.payload))
        corrupted = self.link.corrupt > 0 and self.rng.random() < self.link.corrupt
        if corrupted:  # one bit of the payload, never of the framing header
            bit = int(self.rng.integers(0, 8 * len(item.payload)))
            data[HEADER + bit // 8] ^= 1 << (bit % 8)
        n_packets = -(-len(data) // self.link.mtu)
        lost = self.link.loss > 0 and bool((self.rng.random(n_packets) < self.link.loss).any())
        tx_start = None
        delay = self.link.delay_ms / 1000
        for k in range(n_packets):
            if self._abort:
                self.midframe = k > 0 and not lost
                self.log({"ev": "unsent", "seq": item.seq, "partial": k > 0})
                return
            chunk = bytes(data[k * self.link.mtu : (k + 1) * self.link.mtu])
            t = self.bucket.take(len(chunk))
            tx_start = t if tx_start is None else tx_start
            self.stats.add(t, len(chunk))
            if not lost:  # a lost frame's packets used the link but never reach the base
                self._push(t + delay, chunk, item.seq if k == n_packets - 1 else None)
        event = {"seq": item.seq, "queued": item.queued_at, "tx_start": tx_start, "tx_end": time.monotonic(),
                 "wire_bytes": len(data)}
        self.log({"ev": "lost" if lost else "sent", "corrupted": corrupted, **event})

    def _write(self) -> None:
        while True:
            with self._pcv:
                while not self._packets and not (self._stop and self._shaper_done()) and not self._abort:
                    self._pcv.wait(0.05)
                if self._abort or not self._packets:
                    return
                release, chunk, _ = self._packets[0]
            wait = release - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, 0.05))
                continue
            with self._pcv:
                self._packets.popleft()
                self._pcv.notify_all()
                sock, broken = self._sock, self._broken
            if sock is None or broken:
                continue  # the base is gone: these bytes are lost with the connection
            try:
                sock.sendall(chunk)
            except OSError:
                self._drop_connection()

    def _shaper_done(self) -> bool:
        return not self._shaper.is_alive()

    def _drop_connection(self) -> None:
        with self._pcv:
            sock, self._sock, self._broken = self._sock, None, True
        if sock is not None:
            sock.close()
            self.log({"ev": "disconnected", "t": time.monotonic()})

    # -- the end ------------------------------------------------------------------------------
    def close(self, deadline: float, summary: dict) -> None:
        """Let queued frames go until ``deadline``, report the rest as unsent, then send END
        (a control message, not shaped) and wait for the base to close the connection."""
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        self._shaper.join(max(0.0, deadline - time.monotonic()))
        if self._shaper.is_alive():  # still inside a frame at the deadline: stop there
            self._abort = True
            self._shaper.join(5.0)
        with self._cv:
            for item in self._queue:
                self.log({"ev": "unsent", "seq": item.seq, "partial": False})
            self._queue.clear()
        self._writer.join(0.0 if self._abort else max(1.0, deadline - time.monotonic() + 1.0))
        self._abort = True
        self._writer.join(2.0)
        if self._writer.is_alive():  # stuck in a write: the socket may hold half a packet
            self.midframe = True
        if self.midframe or not self._connected():
            # A frame cut off halfway would swallow the END: say END on a fresh connection.
            self._drop_connection()
            for _ in range(50):  # a restarted base may still be starting: up to ~5 s
                try:
                    self._sock = socket.create_connection(self.address, timeout=0.5)
                    break
                except OSError:
                    time.sleep(0.1)
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.settimeout(5.0)
            sock.sendall(pack_json(END, 0, 0.0, summary))
            sock.shutdown(socket.SHUT_WR)
            while sock.recv(4096):  # the base closes once it has the END: then every byte arrived
                pass
        except OSError:
            pass
        finally:
            sock.close()
