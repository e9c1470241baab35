"""``gmm``: a scan as a Gaussian mixture -- the GMM baseline of the VSGP paper (§II, §V).

Encode fits K full-covariance Gaussians to the scan's points in the sensor frame
(:class:`~lwbench_plugins.gmm.mixture.TorchGaussianMixture`) and sends 10 numbers per
component. Decode draws as many points as the scan had, each inside its component's 3-sigma
ellipsoid (gira3d's sampler), and can put them back on the sensor's rays.

Body layout (little endian)::

    dtype     u8    0 = float32, 1 = float16
    n_points  u32   points to draw on decode: the scan's count times ``samples`` (default 1)
    k_occ     u32   components of the occupied-space mixture
    k_free    u32   components of the free-space mixture (0 = option off)
    params    (k_occ + k_free) x 10 x dtype, per component:
              weight, mean x y z, lower Cholesky factor L00 L10 L11 L20 L21 L22

so ``len(body) = 13 + 10 * (k_occ + k_free) * itemsize``. The six covariance numbers are the
Cholesky factor of the covariance (``Sigma = L L^T``) rather than its upper triangle: the
same count as the paper's "6 FP for covariance", but any rounding (float16!) of ``L`` still
gives a positive-definite covariance, while rounding the entries of a flat surface patch's
covariance easily makes it indefinite.

Free space (option ``free_components``): the two-model framework of Tabib / O'Meadhra fits a
second mixture to samples of the free space the rays crossed. Here: one sample per return,
uniform along its ray between the sensor and ``free_margin`` before the hit. Decode keeps a
drawn point only where the occupied mixture's density beats the free one (equal priors: both
were fitted to the same number of samples), which removes draws from the tails that reach
into the empty tunnel.
"""

from __future__ import annotations

import functools
import struct
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from lwbench import (
    DEVICE_PARAM,
    MAX_COORDINATE,
    MAX_GENERATED_POINTS,
    Frame,
    Param,
    PayloadError,
    RepresentationCodec,
    check_count,
    check_work,
    checked_cloud,
    resolve_device,
)

if TYPE_CHECKING:  # torch is imported where it is used: discovering plugins must stay fast
    import torch

    from .mixture import TorchGaussianMixture

__all__ = ["GMMCodec", "body_size"]

_HEAD = struct.Struct("<BIII")
_DTYPES = {"float32": (0, np.dtype("<f4")), "float16": (1, np.dtype("<f2"))}
_BY_CODE = {code: dt for code, dt in _DTYPES.values()}
_FLOATS_PER_COMPONENT = 10
# Draws a decoder may be asked for: the body does not bound them (a 121-byte payload, K = 1,
# asked for 2**26 points and passed 10 GB), so lwbench's budget for generated points does.
_MAX_POINTS = MAX_GENERATED_POINTS
# What one decode may cost, in (point, component) density evaluations (5-19 ns each through
# mixture_log_prob's GEMM on one core of this project's 2-core machine at load 2.5-6): 2**25.
# A draw (multinomial, normal, truncation, the 3x3 product) costs about as much as _DRAW_COST
# evaluations (1.4 M draws took 0.78 s, 0.99 s re-projected onto an OS1-128, load 5.8), so a
# header asking for at most this budget decodes in ~0.65 s of CPU at most: 838 k draws (samples=4
# on a 124 k-point KITTI scan is 499 k), or e.g. 51 k draws under 100 + 100 components
# (docs/gmm.md's free-space table).
_MAX_DECODE_WORK = 1 << 25
_DRAW_COST = 40


def decode_work(n: int, k_occ: int, k_free: int) -> int:
    """The evaluations a decode of ``n`` draws costs (free-space filtering scores every draw
    under both mixtures): what :data:`_MAX_DECODE_WORK` bounds, on both sides of the link."""
    return n * (_DRAW_COST + (k_occ + k_free if k_free else 0))


def component_reach(rows: np.ndarray, truncate: float) -> float:
    """The farthest from the sensor a truncated draw of these ``(K, 10)`` rows can land: a draw is
    ``mu + L z`` with ``|z| <= truncate``, so within ``|mu| + truncate * ||L||_F`` (m)."""
    if not len(rows):
        return 0.0
    rows = np.asarray(rows, dtype=np.float64)
    return float((np.linalg.norm(rows[:, 1:4], axis=1) + truncate * np.linalg.norm(rows[:, 4:], axis=1)).max())


@functools.cache
def _tril():
    import torch

    return torch.tril_indices(3, 3)


def body_size(k_occ: int, k_free: int, dtype: str = "float32") -> int:
    """Bytes of the body for the given component counts (the formula tests check)."""
    return _HEAD.size + _FLOATS_PER_COMPONENT * (k_occ + k_free) * _DTYPES[dtype][1].itemsize


def _pack(gm: TorchGaussianMixture) -> np.ndarray:
    """``(K, 10)`` float64 rows: weight, mean, lower Cholesky entries."""
    import torch

    tril = _tril()
    chol = torch.as_tensor(gm.cholesky_)[:, tril[0], tril[1]].numpy()
    return np.concatenate([gm.weights_[:, None], gm.means_, chol], axis=1)


def _unpack(rows: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rows back to (weights, means, lower Cholesky factors), checked, float64."""
    import torch

    rows = torch.as_tensor(rows, dtype=torch.float64)
    if not torch.isfinite(rows).all():
        raise PayloadError("gmm payload: non-finite component parameters")
    w, mu = rows[:, 0], rows[:, 1:4]
    chol = torch.zeros(len(rows), 3, 3, dtype=torch.float64)
    tril = _tril()
    chol[:, tril[0], tril[1]] = rows[:, 4:]
    diag = torch.diagonal(chol, dim1=-2, dim2=-1)
    if len(rows) and ((w < 0).any() or float(w.sum()) <= 0 or (diag <= 0).any()):
        raise PayloadError("gmm payload: negative weights or a non-positive Cholesky diagonal")
    return w, mu, chol


def free_space_samples(points: np.ndarray, margin: float, gen: torch.Generator) -> torch.Tensor:
    """One point per return, uniform on its ray between the sensor and ``margin`` before the hit."""
    import torch

    p = torch.as_tensor(points, dtype=torch.float64)
    r = torch.linalg.vector_norm(p, dim=1, keepdim=True).clamp_min(1e-9)
    reach = (r - margin).clamp_min(0) / r
    t = torch.rand(len(p), 1, dtype=torch.float64, generator=gen) * reach
    return p * t


class GMMCodec(RepresentationCodec):
    """K-component Gaussian mixture of the scan, decoded by (truncated) sampling."""

    name = "gmm"
    # 2: free-space filtering through one GEMM (log densities differ by < 2e-7, which may flip a
    # draw on the boundary); decodes bounded to ~1 s of CPU
    version = "2"
    description = "Gaussian mixture (K x 10 floats), decoded by 3-sigma sampling (VSGP paper's baseline)"
    supports_gpu = True
    params = (
        Param("n_components", "int", 200, "mixture components K (the paper pairs 200 with VSGP M=500)",
              low=1, high=100_000),
        Param("max_iter", "int", 100, "EM iterations at most", low=1, high=10_000),
        Param("tol", "float", 1e-3, "EM stops when the mean log-likelihood changes less", low=0.0),
        Param("reg_covar", "float", 1e-6, "added to covariance diagonals (m^2)", low=1e-12, high=1.0),
        Param("kmeans_iter", "int", 10, "Lloyd iterations after k-means++", low=0, high=1000),
        Param("fit_points", "int", 0, "fit on a random subset of this many points (0 = all)", low=0),
        Param("dtype", "str", "float32", "precision of the 10 numbers per component",
              choices=tuple(_DTYPES)),
        Param("truncate", "float", 3.0, "decode draws stay inside this many sigma", low=0.5, high=10.0),
        Param("samples", "float", 1.0, "points drawn on decode per point of the scan (more draws "
              "fill more range-image cells when reproject is on)", low=0.0, high=16.0),
        Param("reproject", "bool", False,
              "re-project decoded points onto the sensor's range image (one per cell, nearest)"),
        Param("free_components", "int", 0, "components of the free-space mixture (0 = off)",
              low=0, high=100_000),
        Param("free_margin", "float", 0.2, "free-space samples stop this far (m) before each return",
              low=0.0),
        Param("seed", "int", 0, "seed of initialisation and decode sampling", low=0),
        DEVICE_PARAM,
    )

    # -- encode ------------------------------------------------------------------------------
    @classmethod
    def test_params(cls) -> dict[str, Any]:
        # 8 components, 20 EM steps on 4,000 points: ~0.3 s a scan instead of ~20 s at the defaults.
        return {"n_components": 8, "max_iter": 20, "fit_points": 4000}

    def _fit(self, points: torch.Tensor | np.ndarray, k: int, gen_seed: int) -> np.ndarray:
        from .mixture import TorchGaussianMixture

        cfg = self.config
        gm = TorchGaussianMixture(
            k,
            tol=cfg["tol"],
            reg_covar=cfg["reg_covar"],
            max_iter=cfg["max_iter"],
            kmeans_iter=cfg["kmeans_iter"],
            random_state=gen_seed,
            device=resolve_device(cfg["device"]),
        )
        with warnings.catch_warnings():  # hitting max_iter is the configured budget, not an error
            warnings.simplefilter("ignore")
            gm.fit(points)
        return _pack(gm)

    def encode(self, frame: Frame) -> bytes:
        """Fit the mixture(s). Fallbacks: fewer points than K -> K = N; no points -> K = 0."""
        cfg = self.config
        pts = frame.points
        n = len(pts)
        n_draw = int(round(cfg["samples"] * n))
        if n_draw > _MAX_POINTS:
            # Refused before fitting (EM on 10 M points would run for many minutes): a decoder
            # draws at most _MAX_POINTS, so a payload asking for more could never be decoded.
            raise ValueError(
                f"gmm: {n:,} points x samples {cfg['samples']:g} = {n_draw:,} draws on decode, more than the "
                f"{_MAX_POINTS:,} a decoder accepts (lower samples, or split the scan)"
            )
        seed = [cfg["seed"], frame.index]
        rng = np.random.default_rng(seed)
        fit_pts = pts
        if cfg["fit_points"] and n > cfg["fit_points"]:
            fit_pts = pts[np.sort(rng.choice(n, cfg["fit_points"], replace=False))]
        init_seed = int(rng.integers(2**31))
        k_occ = min(cfg["n_components"], len(fit_pts))
        k_free = min(cfg["free_components"], len(fit_pts))
        self._check_work(n_draw, k_occ, k_free)  # before fitting: EM is the expensive part
        rows = [self._fit(fit_pts, k_occ, init_seed)] if k_occ else []
        if k_free:
            import torch

            gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
            free = free_space_samples(fit_pts, cfg["free_margin"], gen)
            rows.append(self._fit(free, k_free, init_seed))
        dt_code, dt = _DTYPES[cfg["dtype"]]
        params = np.concatenate(rows) if rows else np.zeros((0, _FLOATS_PER_COMPONENT))
        if cfg["dtype"] == "float16":
            tiny = np.finfo(np.float16).tiny
            params[:, [4, 6, 9]] = np.maximum(params[:, [4, 6, 9]], tiny)  # keep L's diagonal > 0
        self._check_reach(params.astype(dt), k_occ)
        body = _HEAD.pack(dt_code, n_draw, k_occ, k_free) + params.astype(dt).tobytes()
        meta = {"truncate": cfg["truncate"], "seed": cfg["seed"], "reproject": cfg["reproject"]}
        if cfg["reproject"]:
            meta["sensor"] = self.sensor_meta(frame.sensor)
        return self.make_payload(frame, meta, body)

    @staticmethod
    def _check_work(n_draw: int, k_occ: int, k_free: int) -> None:
        """``ValueError`` before writing a payload whose decode takes more work than a decoder accepts."""
        work = decode_work(n_draw, k_occ, k_free)
        if work > _MAX_DECODE_WORK:
            raise ValueError(
                f"gmm: {n_draw:,} draws{f' filtered by {k_occ + k_free} components' if k_free else ''} would take "
                f"{work:,} evaluations to decode, more than the {_MAX_DECODE_WORK:,} a decoder accepts (lower "
                "samples or free_components, or split the scan)"
            )

    def _check_reach(self, rows: np.ndarray, k_occ: int) -> None:
        """``ValueError`` before writing a payload whose draws could land beyond any LiDAR's reach
        (the decoder holds its draws to :data:`lwbench.MAX_COORDINATE` before re-projecting)."""
        with np.errstate(over="ignore", invalid="ignore"):
            reach = component_reach(rows[:k_occ], self.config["truncate"])
        if not reach <= MAX_COORDINATE:
            raise ValueError(
                f"gmm: a component's {self.config['truncate']:g}-sigma draws reach {reach:.3g} m from the sensor, "
                f"beyond the {MAX_COORDINATE:g} m a decoder accepts (the scan holds points no LiDAR returns: crop them)"
            )

    # -- decode ------------------------------------------------------------------------------
    def mixtures(self, data: bytes) -> tuple[tuple[torch.Tensor, ...], tuple[torch.Tensor, ...] | None, int]:
        """The decoded occupied and free-space mixtures (weights, means, lower Cholesky factors,
        float64) and the scan's point count, checked; ``PayloadError`` on anything malformed."""
        return self._read(self.read_payload(data))

    @staticmethod
    def _read(payload) -> tuple[tuple[torch.Tensor, ...], tuple[torch.Tensor, ...] | None, int]:
        body = payload.body
        if len(body) < _HEAD.size:
            raise PayloadError(f"gmm payload: body of {len(body)} bytes is shorter than its header")
        code, n, k_occ, k_free = _HEAD.unpack_from(body, 0)
        dt = _BY_CODE.get(code)
        if dt is None:
            raise PayloadError(f"gmm payload: unknown dtype code {code}")
        per = _FLOATS_PER_COMPONENT * dt.itemsize
        check_count(k_occ + k_free, "component count", codec="gmm", body=len(body) - _HEAD.size,
                    bytes_each=per, exact=True)
        n = check_count(n, "points to draw", codec="gmm", limit=_MAX_POINTS)
        if n > 0 and k_occ == 0:
            raise PayloadError(f"gmm payload: {n} points from {k_occ} components is not decodable")
        # Drawing, and scoring every draw under both mixtures when there is a free-space one.
        check_work(decode_work(n, k_occ, k_free), "drawing (and free-space filtering)", codec="gmm",
                   limit=_MAX_DECODE_WORK)
        rows = np.frombuffer(body, dtype=dt, offset=_HEAD.size).reshape(-1, _FLOATS_PER_COMPONENT)
        with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf patterns are refused by _unpack
            rows = rows.astype(np.float64)
        free = _unpack(rows[k_occ:]) if k_free else None
        return _unpack(rows[:k_occ]), free, n

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        truncate = float(self.meta_field(payload, "truncate", (int, float)))
        seed = self.meta_field(payload, "seed", int)
        reproject = self.meta_field(payload, "reproject", bool)
        if not 0 < truncate <= 100 or not 0 <= seed < 2**63:
            raise PayloadError("gmm payload: truncate or seed out of range")
        (w, mu, chol), free, n = self._read(payload)
        import torch

        from .mixture import mixture_log_prob, sample_mixture

        gen = torch.Generator().manual_seed(seed)
        x, _ = sample_mixture(w, mu, chol, n, gen, truncate)
        if free is not None:
            x = x[mixture_log_prob(w, mu, chol, x) >= mixture_log_prob(*free, x)]
        # A payload that names its sensor is held to its reach (huge means or factors would put
        # points kilometres away, or overflow float32); one that does not, to any LiDAR's. Draws
        # that are re-projected are held to any LiDAR's first: re-projection keeps only those
        # within the sensor's range window (a scan's returns beyond its sensor's max range are
        # modelled too -- the encoder wrote them, so the decoder must not refuse their draws).
        sensor = self.read_sensor(payload) if reproject or "sensor" in payload.meta else None
        max_range = None if sensor is None else sensor.max_range
        pts = checked_cloud(x.numpy(), self.name, max_range=None if reproject else max_range)
        if reproject:
            pts = sensor.unproject(sensor.project(pts).ranges)
        return checked_cloud(pts, self.name, max_range=max_range)
