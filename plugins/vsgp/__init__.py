"""``vsgp``: variational sparse GP over the occupancy surface (Ali et al., paper 000 §IV).

The scout models ``f = r_oc - r`` over (azimuth, elevation) with a zero-mean GP, RQ-ARD kernel,
and sends M inducing inputs with their posterior occupancy plus six hyper-parameters; the base
predicts the surface on the sensor's grid and drops cells whose predictive variance says
"free space". See ``encoder.py`` / ``decoder.py`` for why each step is done the way it is and
``docs/vsgp.md`` for the measurements behind the defaults.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from lwbench import (
    DEVICE_PARAM,
    Frame,
    Param,
    PayloadError,
    RepresentationCodec,
    SensorModel,
    checked_cloud,
    hookimpl,
    resolve_device,
)

from .wire import BODY_FORMATS, MAX_INDUCING, pack_body, unpack_body

if TYPE_CHECKING:  # the GP modules need torch: imported on first encode/decode, not at discovery
    import torch

    from .encoder import FitConfig

__all__ = ["VSGPCodec"]


def _el_span(sensor: SensorModel) -> tuple[float, float]:
    e = sensor.elevations_rad
    return float(e[0]), float(e[-1])


class VSGPCodec(RepresentationCodec):
    """Scan -> (inducing inputs, occupancy, hyper-parameters) -> occupancy surface -> cloud.

    ``last_timings`` holds the seconds spent in each stage of the latest encode/decode call
    (projection, layout, refine, fit, serialize / parse, predict, sampling), for benchmarks.
    """

    name = "vsgp"
    in_default_run = True
    version = "1"
    description = "variational sparse GP of the occupancy surface (RQ-ARD, collapsed Titsias bound)"
    supports_gpu = True
    params = (
        Param("num_inducing", "int", 500, "inducing points M (3 values each in the payload)",
              low=1, high=MAX_INDUCING),
        Param("r_oc", "float", None, "occupancy radius in m (default: the sensor's max range)", low=0.01),
        Param("steps", "int", 0, "max Adam steps on the collapsed bound (0: sensor-derived hyper-parameters)",
              low=0, high=1000),
        Param("lr", "float", 0.1, "Adam learning rate (on the GPyTorch raw parameters)", low=1e-5, high=10.0),
        Param("tol", "float", 1e-3, "stop when a step improves the bound by less (nats per point)", low=0.0),
        Param("subsample", "int", 2048, "occupied cells used by the hyper-parameter steps", low=16),
        Param("fit_stride", "int", 4, "q(u) is fitted on every n-th azimuth column of occupied cells", low=1),
        Param("adapt", "float", 0.7, "inducing layout: share of points placed by range variation along "
              "a beam (0: evenly, as in the paper)", low=0.0, high=1.0),
        Param("learn_inducing", "bool", False, "also move the inducing inputs by gradient steps"),
        Param("body", "str", "float32", "payload body format", choices=BODY_FORMATS),
        Param("k_m", "float", 0.1, "variance threshold: weight of the grid's mean variance",
              low=-100.0, high=100.0),
        Param("k_std", "float", 0.0, "variance threshold: weight of the grid's variance std", low=-100.0,
              high=100.0),
        Param("v_floor", "float", 0.03, "variance threshold floor, as a share of the prior variance: cells "
              "below it are always kept (0: the paper's rule alone)", low=0.0, high=1.0),
        Param("upsample", "int", 1, "decode onto a grid this many times finer per axis", low=1, high=8),
        Param("stride", "int", 0, "decode: exact prediction every n-th column, interpolated between "
              "(0: auto from the azimuth lengthscale)", low=0),
        Param("seed", "int", 0, "seed of the hyper-parameter subsample", low=0),
        DEVICE_PARAM,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.last_timings: dict[str, float] = {}

    def _device(self) -> torch.device:
        return resolve_device(self.config["device"])

    def fit_config(self) -> FitConfig:
        """The encoder settings these parameters select."""
        from .encoder import FitConfig

        c = self.config
        return FitConfig(num_inducing=c["num_inducing"], adapt=c["adapt"], steps=c["steps"], lr=c["lr"],
                         tol=c["tol"], subsample=c["subsample"], fit_stride=c["fit_stride"],
                         learn_inducing=c["learn_inducing"], seed=c["seed"])

    def encode(self, frame: Frame) -> bytes:
        t0 = time.perf_counter()
        sensor = frame.sensor
        r_oc = float(self.config["r_oc"] or sensor.max_range)
        ranges = sensor.project(frame.points).ranges
        t1 = time.perf_counter()
        from .encoder import fit_scan

        res = fit_scan(ranges, sensor, r_oc, self.fit_config(), self._device())
        t2 = time.perf_counter()
        body = pack_body(self.config["body"], res.z, res.u, res.hyper.as_list(), r_oc, _el_span(sensor))
        meta = {"sensor": self.sensor_meta(sensor), "body": self.config["body"]}
        out = self.make_payload(frame, meta, body)
        self.last_timings = {"projection": t1 - t0, **res.timings, "serialize": time.perf_counter() - t2,
                             "steps_run": float(res.steps_run)}
        return out

    def decode(self, data: bytes) -> np.ndarray:
        t0 = time.perf_counter()
        payload = self.read_payload(data)
        fmt = self.meta_field(payload, "body", str)
        sensor = self.read_sensor(payload)
        import torch

        from .decoder import reconstruct
        from .gp import Hyper

        z, u, hyper, r_oc = unpack_body(fmt, payload.body, _el_span(sensor))
        timings = {"parse": time.perf_counter() - t0}
        try:
            pts = reconstruct(z, u, Hyper(*hyper), r_oc, sensor, upsample=self.config["upsample"],
                              k_m=self.config["k_m"], k_std=self.config["k_std"],
                              v_floor=self.config["v_floor"], stride=self.config["stride"],
                              device=self._device(), timings=timings)
        except torch.linalg.LinAlgError as exc:
            raise PayloadError(f"vsgp payload: inducing points do not define a valid GP ({exc})") from None
        self.last_timings = timings
        return checked_cloud(pts, self.name, max_range=sensor.max_range)  # no point past its sensor's reach


@hookimpl
def lwbench_codecs() -> list[type[VSGPCodec]]:
    return [VSGPCodec]
