"""``vsgp``: variational sparse GP over the occupancy surface (Ali et al., paper 000 §IV).

The scout models the occupancy ``f`` of each return over (azimuth, elevation) with sparse GPs
(RQ-ARD kernel) -- local ones over tiles of the scan by default (``grid.py``), or one GP over the
whole scan as in the paper (``mode=paper``) -- and sends each tile's inducing points (azimuth,
beam, posterior occupancy) plus its hyper-parameters; the base predicts the surface on the
scan's own grid and drops cells whose predictive variance says "free space". With
``residual=TAU`` the surface becomes a predictor and a residual layer follows it (``residuals.py``):
every return decoded within ``TAU``. See ``encoder.py`` / ``decoder.py`` for why each step is done
the way it is and ``docs/vsgp.md`` for the measurements behind the defaults, which
``lwbench vsgp-bench`` (``bench.py``) reproduces.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lwbench import (
    DEVICE_PARAM,
    Frame,
    Param,
    ParameterError,
    PayloadError,
    RepresentationCodec,
    hookimpl,
    resolve_device,
)

from .wire import BODY_FORMATS, MAX_INDUCING, MAX_TILE_INDUCING, TRANSFORMS, body_size, pack_body, unpack_body

if TYPE_CHECKING:  # the GP modules need torch: imported on first encode/decode, not at discovery
    import torch

    from .decoder import DecodeConfig
    from .encoder import FitConfig, FitResult
    from .gp import Hyper

__all__ = ["VSGPCodec", "PAPER_STEPS"]

#: Hyper-parameter steps ``mode=paper`` takes when ``steps`` is 0 (the paper learns them; its
#: count is not given -- on the sim tunnel the bound keeps rising for 10 steps, docs/vsgp.md).
PAPER_STEPS = 10


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """torch's intra-op threads set to ``n`` for the block (``n = 0``: left as they are)."""
    import torch

    old = torch.get_num_threads()
    if n <= 0 or n == old:
        yield
        return
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


class VSGPCodec(RepresentationCodec):
    """Scan -> per-tile (inducing inputs, occupancy, hyper-parameters) -> occupancy surface -> cloud.

    ``last_timings`` holds the seconds spent in each stage of the latest encode/decode call
    (projection, layout, refine, fit, serialize / parse, predict, sampling), for benchmarks.

    ``warm_start=true`` keeps the previous frame's hyper-parameters in the instance and starts
    the next frame's refinement from them (only with ``steps > 0``): for a scout encoding a
    stream in order. Every payload still decodes alone; the default (off) keeps every encode a
    function of its frame only, as ``lwbench run`` needs (frames in any order, any worker).
    """

    name = "vsgp"
    in_default_run = True
    version = "3"
    description = "variational sparse GP of the occupancy surface (local RQ-ARD GPs, collapsed Titsias bound)"
    supports_gpu = True
    params = (
        Param(
            "num_inducing",
            "int",
            None,
            "inducing points M in all, 3 numbers each in the payload (default: "
            "one per cells_per_point occupied cells of the scan)",
            low=1,
            high=MAX_INDUCING,
        ),
        Param(
            "cells_per_point",
            "float",
            100.0,
            "occupied cells per inducing point when num_inducing is not given "
            "(100: the paper's M = 500 for VLP-16 tunnel scans of up to ~50,000 returns)",
            low=1.0,
            high=1e6,
        ),
        Param(
            "bytes",
            "int",
            None,
            "payload byte budget: M is the largest that fits (overrides num_inducing)",
            low=64,
            high=1 << 20,
        ),
        Param(
            "tile_points",
            "int",
            128,
            "inducing points per local GP (azimuth sector of a band of <= 16 "
            "beams); 0: one GP over the whole scan, as in the paper",
            low=0,
            high=MAX_TILE_INDUCING // 2,
        ),
        Param(
            "mode",
            "str",
            "fast",
            "fast (the defaults) or paper: one GP, every occupied cell, zero mean, "
            "f = r_oc - r, learned hyper-parameters",
            choices=("fast", "paper"),
        ),
        Param(
            "transform",
            "str",
            "linear",
            "occupancy: linear (f = r_oc - r, the paper's) or inverse (f = 1/r)",
            choices=TRANSFORMS,
        ),
        Param(
            "center",
            "bool",
            True,
            "each tile's prior mean is its mean occupancy (false: the paper's zero "
            "mean, which pulls gaps between inducing points to r_oc)",
        ),
        Param("r_oc", "float", None, "occupancy radius in m (default: the sensor's max range)", low=0.01),
        Param(
            "steps",
            "int",
            0,
            "max Adam steps on the collapsed bound (0: sensor-derived hyper-parameters)",
            low=0,
            high=1000,
        ),
        Param("lr", "float", 0.1, "Adam learning rate (on the GPyTorch raw parameters)", low=1e-5, high=10.0),
        Param("tol", "float", 1e-3, "stop when a step improves the bound by less (nats per point)", low=0.0),
        Param("subsample", "int", 2048, "occupied cells of a tile used by the hyper-parameter steps", low=16),
        Param(
            "fit_stride",
            "int",
            0,
            "q(u) is fitted on every n-th column (0: auto, ~12 columns per azimuth lengthscale)",
            low=0,
        ),
        Param(
            "adapt",
            "float",
            0.7,
            "inducing layout: share of points placed by range variation along a beam (0: evenly, as in the paper)",
            low=0.0,
            high=1.0,
        ),
        Param("learn_inducing", "bool", False, "also move the inducing inputs (along their beams) by gradient steps"),
        Param(
            "warm_start",
            "bool",
            False,
            "start each frame's refinement from the previous frame's "
            "hyper-parameters (a stream encoded in order; needs steps > 0)",
        ),
        Param(
            "residual",
            "float",
            0.0,
            "residual layer: every return within this many m of its decoded range, a point "
            "per return (0: off, the paper's codec; on, upsample and the variance rule do not apply)",
            low=0.0,
            high=100.0,
        ),
        Param(
            "predictor",
            "str",
            "gp",
            "what the residual layer corrects: gp (the surface) or none (no GP is sent: the "
            "control that shows what the GP is worth as a predictor)",
            choices=("gp", "none"),
        ),
        Param("body", "str", "float32", "payload body format", choices=BODY_FORMATS),
        Param("k_m", "float", 0.1, "variance threshold: weight of the grid's mean variance", low=-100.0, high=100.0),
        Param("k_std", "float", 0.0, "variance threshold: weight of the grid's variance std", low=-100.0, high=100.0),
        Param(
            "v_floor",
            "float",
            0.1,
            "variance threshold floor, as a share of the prior variance: cells "
            "below it are always kept (0: the paper's rule alone)",
            low=0.0,
            high=1.0,
        ),
        Param("upsample", "int", 1, "decode onto a grid this many times finer per axis", low=1, high=8),
        Param(
            "stride",
            "int",
            0,
            "decode: exact prediction every n-th column, interpolated between "
            "(0: auto from the azimuth lengthscale, widened if the payload's work needs it)",
            low=0,
        ),
        Param("seed", "int", 0, "seed of the hyper-parameter subsample", low=0),
        Param(
            "threads",
            "int",
            1,
            "torch threads inside encode/decode (0: torch's setting): a tile's algebra is "
            "small matrices, where a second thread mostly waits for a core",
            low=0,
            high=256,
        ),
        DEVICE_PARAM,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.last_timings: dict[str, float] = {}
        self._warm: list[Hyper] | None = None

    @classmethod
    def test_params(cls) -> dict[str, Any]:
        return {"num_inducing": 100}

    def _device(self) -> torch.device:
        return resolve_device(self.config["device"])

    def reset_stream(self) -> None:
        """Forget the warm-start state (the next encode starts cold)."""
        self._warm = None

    def fit_config(self) -> FitConfig:
        """The encoder settings these parameters select."""
        from .encoder import FitConfig

        c = self.config
        cfg = FitConfig(
            num_inducing=c["num_inducing"],
            cells_per_point=c["cells_per_point"],
            tile_points=c["tile_points"],
            adapt=c["adapt"],
            transform=c["transform"],
            center=c["center"],
            r_oc=c["r_oc"],
            steps=c["steps"],
            lr=c["lr"],
            tol=c["tol"],
            subsample=c["subsample"],
            fit_stride=c["fit_stride"],
            learn_inducing=c["learn_inducing"],
            seed=c["seed"],
        )
        if c["mode"] == "paper":
            cfg = replace(
                cfg, tile_points=0, fit_stride=1, center=False, transform="linear", steps=c["steps"] or PAPER_STEPS
            )
        return cfg

    def decode_config(self) -> DecodeConfig:
        from .decoder import DecodeConfig

        c = self.config
        return DecodeConfig(
            upsample=c["upsample"], k_m=c["k_m"], k_std=c["k_std"], v_floor=c["v_floor"], stride=c["stride"]
        )

    # -- encode ------------------------------------------------------------------------------
    def _check_config(self) -> None:
        c = self.config
        if c["predictor"] == "none" and not c["residual"] > 0:
            raise ParameterError("vsgp: predictor=none sends no surface; it needs a residual layer (residual > 0)")
        if c["residual"] > 0 and c["bytes"]:
            raise ParameterError(
                "vsgp: bytes= sizes the GP alone and the residual layer's size follows from the scan; "
                "with residual > 0 set the GP's size with num_inducing or cells_per_point"
            )

    def _fit(self, frame: Frame, cfg: FitConfig) -> tuple[FitResult, bytes]:
        from .encoder import empty_body, fit_scan

        if self.config["predictor"] == "none":
            res = empty_body(frame.points, frame.sensor, cfg)
        else:
            warm = self._warm if self.config["warm_start"] else None
            res = fit_scan(frame.points, frame.sensor, cfg, self._device(), warm)
        meta = {"sensor": self.sensor_meta(frame.sensor), "body": self.config["body"]}
        body = pack_body(self.config["body"], res.body)
        if self.config["residual"] > 0:
            section = self._residual_section(frame, res)
            meta["residual"] = len(section)
            body += section
        t = time.perf_counter()
        data = self.make_payload(frame, meta, body)
        res.timings["serialize"] = time.perf_counter() - t
        return res, data

    def _residual_section(self, frame: Frame, res: FitResult) -> bytes:
        """The residual layer against what this codec's decoder will predict (residuals.py)."""
        from .decoder import DecodeConfig, predict_grid
        from .residuals import clamp_prediction, pack_residuals, scan_slots

        t = time.perf_counter()
        sensor = frame.sensor
        pred = predict_grid(res.body, sensor, DecodeConfig(), self._device())
        slots = scan_slots(frame.points, sensor, res.body.phase_codes)
        rows, cols = np.divmod(slots.cell, sensor.n_azimuth)
        section, _ = pack_residuals(
            slots, clamp_prediction(pred.ranges[rows, cols], sensor), self.config["residual"], sensor
        )
        res.timings["residual"] = time.perf_counter() - t
        return section

    def _overhead(self, frame: Frame) -> int:
        meta = {"sensor": self.sensor_meta(frame.sensor), "body": self.config["body"]}
        return len(self.make_payload(frame, meta, b""))

    def _budget_m(self, frame: Frame, cfg: FitConfig, budget: int, per_point: float) -> int:
        """Largest M whose payload (at ``per_point`` bytes a point) fits ``budget`` bytes."""
        from .grid import Tiling

        fmt = "q16" if self.config["body"] == "q16z" else self.config["body"]
        avail = budget - self._overhead(frame) - (4 if self.config["body"] == "q16z" else 0)
        beams = frame.sensor.n_beams
        fixed = body_size(fmt, beams, 1, 0)
        m = max(1, int((avail - fixed) / per_point))
        for _ in range(8):
            tiles = Tiling.plan(frame.sensor, m, cfg.tile_points).n_tiles
            fixed = body_size(fmt, beams, tiles, 0)
            new = int((avail - fixed) / per_point)
            if new == m:
                break
            m = new
        if m < 1:
            raise ParameterError(
                f"vsgp: bytes={budget} is below the payload's fixed size "
                f"({self._overhead(frame) + fixed} bytes for this sensor)"
            )
        return min(m, MAX_INDUCING)

    def _encode_to_budget(self, frame: Frame, cfg: FitConfig) -> tuple[FitResult, bytes]:
        """Fit with the largest M that fits ``bytes``: exact for the fixed-size bodies; for
        ``q16z`` from the compressed size of a first fit, re-fitted until it fits."""
        budget = int(self.config["bytes"])
        fmt = self.config["body"]
        per_point = {"float32": 7.0, "float16": 5.0, "q16": 5.0}.get(fmt, 3.2)
        m = self._budget_m(frame, cfg, budget, per_point)
        for _ in range(6):
            res, data = self._fit(frame, replace(cfg, num_inducing=m))
            if len(data) <= budget or m == 1:
                break
            got = res.body.num_inducing
            per_point = max(per_point, (len(data) - self._overhead(frame)) / max(1, got)) * 1.02
            m = max(1, min(m - 1, self._budget_m(frame, cfg, budget, per_point)))
        if len(data) > budget:
            raise ParameterError(
                f"vsgp: bytes={budget} is below what this scan's smallest payload takes ({len(data)} bytes)"
            )
        return res, data

    def encode(self, frame: Frame) -> bytes:
        with torch_threads(self.config["threads"]):
            return self._encode(frame)

    def _encode(self, frame: Frame) -> bytes:
        self._check_config()
        cfg = self.fit_config()
        res, data = self._encode_to_budget(frame, cfg) if self.config["bytes"] else self._fit(frame, cfg)
        from .decoder import DecodeConfig, decodable

        try:  # the decoder's own bound, with its default settings: never write what it refuses
            decodable(res.body, frame.sensor, DecodeConfig())
        except PayloadError as exc:
            raise ParameterError(
                f"vsgp: this scan's payload could not be decoded ({exc}); use fewer "
                "inducing points per tile (tile_points)"
            ) from None
        if self.config["warm_start"]:
            from .gp import Hyper

            self._warm = [Hyper(*t.hyper) for t in res.body.tiles]
        self.last_timings = {
            **res.timings,
            "steps_run": float(res.steps_run),
            "num_inducing": float(res.body.num_inducing),
            "tiles": float(len(res.body.tiles)),
        }
        return data

    # -- decode ------------------------------------------------------------------------------
    def decode(self, data: bytes) -> np.ndarray:
        with torch_threads(self.config["threads"]):
            return self._decode(data)

    def _decode(self, data: bytes) -> np.ndarray:
        t0 = time.perf_counter()
        payload = self.read_payload(data)
        fmt = self.meta_field(payload, "body", str)
        sensor = self.read_sensor(payload)
        import torch

        from .decoder import reconstruct, reconstruct_residual

        gp_part, section = self._split_residual(payload)
        body = unpack_body(fmt, gp_part, sensor.n_beams, sensor.n_azimuth)
        timings = {"parse": time.perf_counter() - t0}
        try:
            if section is None:
                pts = reconstruct(body, sensor, self.decode_config(), self._device(), timings)
            else:
                pts = reconstruct_residual(body, section, sensor, self._device(), timings)
        except torch.linalg.LinAlgError as exc:
            raise PayloadError(f"vsgp payload: inducing points do not define a valid GP ({exc})") from None
        self.last_timings = timings
        from lwbench import checked_cloud

        return checked_cloud(pts, self.name, max_range=sensor.max_range)  # no point past its sensor's reach

    def _split_residual(self, payload: Any) -> tuple[bytes, bytes | None]:
        """The GP body and the residual section (``None`` without one): the metadata field
        ``residual`` is the section's length, at the end of the body."""
        if "residual" not in payload.meta:
            return payload.body, None
        n = self.meta_field(payload, "residual", int)
        if not 0 < n <= len(payload.body):
            raise PayloadError(f"vsgp payload: residual section of {n} bytes in a body of {len(payload.body)}")
        cut = len(payload.body) - n
        return payload.body[:cut], payload.body[cut:]


@hookimpl
def lwbench_codecs() -> list[type[VSGPCodec]]:
    return [VSGPCodec]


@hookimpl
def lwbench_register_commands(cli) -> None:
    from . import bench

    bench.register(cli)
