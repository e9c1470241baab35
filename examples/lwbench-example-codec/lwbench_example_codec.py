"""An example lwbench codec plugin: coordinates as IEEE half floats.

Everything a plugin needs is here: a codec class (declared parameters, ``encode``/``decode``
through lwbench's payload helpers) and a ``@hookimpl`` that returns the class. float16 keeps
about 3 significant digits, so the error grows with range (~4 cm at 50 m): the ``center``
parameter subtracts the scan's mean first, which a user can compare on the leaderboard.
"""

from __future__ import annotations

import numpy as np

from lwbench import Frame, Param, PayloadError, RepresentationCodec, hookimpl


class HalfFloatCodec(RepresentationCodec):
    name = "half"
    description = "x,y,z as float16 (example plugin)"
    params = (Param("center", "bool", True, "subtract the scan mean before rounding"),)

    def encode(self, frame: Frame) -> bytes:
        pts = frame.points.astype(np.float64)
        offset = pts.mean(axis=0) if (self.config["center"] and len(pts)) else np.zeros(3)
        body = (pts - offset).astype("<f2").tobytes()
        return self.make_payload(frame, {"offset": offset.tolist(), "n": len(pts)}, body)

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        n = self.meta_field(payload, "n", int)
        offset = np.asarray(self.meta_field(payload, "offset", list), dtype=np.float64)
        if len(payload.body) != 6 * n or offset.shape != (3,):
            raise PayloadError("half: body size does not match the point count")
        pts = np.frombuffer(payload.body, dtype="<f2").reshape(n, 3).astype(np.float64) + offset
        return pts.astype(np.float32)


@hookimpl
def lwbench_codecs() -> list[type[HalfFloatCodec]]:
    return [HalfFloatCodec]
