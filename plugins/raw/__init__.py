"""``raw``: lossless float32 x,y,z -- the reference every ratio and error is measured against."""

from __future__ import annotations

import numpy as np

from lwbench import Frame, RepresentationCodec, hookimpl, pack_points, unpack_points


class RawCodec(RepresentationCodec):
    """Sends the scan as it is: 12 bytes per point plus the shared header."""

    name = "raw"
    in_default_run = True
    description = "lossless float32 x,y,z (the reference)"

    def encode(self, frame: Frame) -> bytes:
        return self.make_payload(frame, {}, pack_points(frame.points, "float32", codec=self.name))

    def decode(self, data: bytes) -> np.ndarray:
        return unpack_points(self.read_payload(data).body, self.name)


@hookimpl
def lwbench_codecs() -> list[type[RawCodec]]:
    return [RawCodec]
