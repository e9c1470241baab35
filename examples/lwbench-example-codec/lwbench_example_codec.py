"""An example lwbench codec plugin: coordinates as IEEE half floats.

Everything a plugin needs is here: a codec class (declared parameters, ``encode``/``decode``
through lwbench's payload helpers) and a ``@hookimpl`` that returns the class. float16 keeps
about 3 significant digits, so the error grows with range (~4 cm at 50 m): the ``center``
parameter subtracts the scan's mean first, which a user can compare on the leaderboard.
"""

from __future__ import annotations

import numpy as np

from lwbench import Frame, Param, PayloadError, RepresentationCodec, check_count, checked_cloud, hookimpl


class HalfFloatCodec(RepresentationCodec):
    name = "half"
    description = "x,y,z as float16 (example plugin)"
    params = (Param("center", "bool", True, "subtract the scan mean before rounding"),)

    def encode(self, frame: Frame) -> bytes:
        pts = frame.points.astype(np.float64)
        offset = pts.mean(axis=0) if (self.config["center"] and len(pts)) else np.zeros(3)
        body = (pts - offset).astype("<f2").tobytes()
        # The sensor travels as a name (a preset or a 16-hex id of its table, ~25 bytes) under
        # meta["sensor"], where read_sensor() looks for it; the decoder bounds the cloud by its range.
        meta = {"offset": offset.tolist(), "n": len(pts), "sensor": self.sensor_meta(frame.sensor)}
        return self.make_payload(frame, meta, body)

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        # Every count read from a payload is checked before anything is allocated for it, and
        # the decoded cloud must be finite (the conformance kit fuzzes decoders with crafted
        # payloads: only PayloadError may escape).
        n = check_count(self.meta_field(payload, "n", int), "point count", codec=self.name,
                        body=len(payload.body), bytes_each=6, exact=True)
        offset = self.meta_field(payload, "offset", list)
        if len(offset) != 3 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in offset):
            raise PayloadError("half: the offset is not three numbers")
        sensor = self.read_sensor(payload)  # meta["sensor"], resolved among the sensors handed to the decoder
        pts = np.frombuffer(payload.body, dtype="<f2").reshape(n, 3).astype(np.float64) + np.asarray(offset, float)
        return checked_cloud(pts, self.name, max_range=sensor.max_range)


@hookimpl
def lwbench_codecs() -> list[type[HalfFloatCodec]]:
    return [HalfFloatCodec]
