"""Test plugins that misbehave on purpose: hang, die, leak, segfault (registered through
``LWBENCH_PLUGINS=_hostile_plugins`` with this folder on ``PYTHONPATH``, so that ``lwbench run``
subprocesses and worker processes load them like any plugin).

Each codec is the raw codec except on the frame given by ``on_frame`` (every frame with -2),
where ``encode`` does its one bad thing. :class:`HostileDecoder` is the fuzz harness's target.
"""

from __future__ import annotations

import ctypes
import os
import signal
import time

import numpy as np

from lwbench import Frame, Param, RepresentationCodec, hookimpl, pack_points, unpack_points


class _Misbehaving(RepresentationCodec):
    params = (Param("on_frame", "int", 1, "the frame to misbehave on (-2: every frame)"),)

    def encode(self, frame: Frame) -> bytes:
        if self.config["on_frame"] in (frame.index, -2):
            self.misbehave()
        return self.make_payload(frame, {}, pack_points(frame.points))

    def decode(self, data: bytes) -> np.ndarray:
        return unpack_points(self.read_payload(data).body, self.name)

    def misbehave(self) -> None:
        raise NotImplementedError


class HangingCodec(_Misbehaving):
    name = "test-hang"

    def misbehave(self) -> None:
        time.sleep(3600)


class SegfaultingCodec(_Misbehaving):
    name = "test-segfault"

    def misbehave(self) -> None:
        ctypes.string_at(0)  # reads address 0: SIGSEGV


class ExitingCodec(_Misbehaving):
    name = "test-exit"

    def misbehave(self) -> None:
        os._exit(3)


class LeakingCodec(_Misbehaving):
    name = "test-leak"

    def misbehave(self) -> None:
        hoard = []
        while True:  # touches every page, so the memory is really held
            hoard.append(np.ones(64 << 20, np.uint8))


class HostileDecoder(RepresentationCodec):
    """A decoder that does what ``mode`` says: ok, hang, crash, bomb (allocate without bound),
    slow (a second and a half of CPU) or far (a point 20 km away: no LiDAR's return)."""

    name = "test-hostile-decoder"
    params = (Param("mode", "str", "ok"),)

    def encode(self, frame: Frame) -> bytes:
        return self.make_payload(frame, {}, b"")

    def decode(self, data: bytes) -> np.ndarray:
        mode = self.config["mode"]
        if mode == "hang":
            time.sleep(3600)
        elif mode == "crash":
            os.kill(os.getpid(), signal.SIGSEGV)
        elif mode == "bomb":
            hoard = []
            while True:
                hoard.append(np.ones(64 << 20, np.uint8))
        elif mode == "slow":
            t = time.process_time()
            while time.process_time() - t < 1.5:
                pass
        elif mode == "far":
            return np.array([[2e4, 0.0, 0.0], [1.0, 0.0, 0.0]], np.float32)
        return np.zeros((1, 3), np.float32)


@hookimpl
def lwbench_codecs() -> list[type[RepresentationCodec]]:
    return [HangingCodec, SegfaultingCodec, ExitingCodec, LeakingCodec, HostileDecoder]
