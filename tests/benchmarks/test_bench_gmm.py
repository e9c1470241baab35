"""Fit time of the torch Gaussian mixture vs scikit-learn, K = 200, one ~26k-point tunnel scan.

The issue's target: at least 3x faster than ``sklearn.mixture.GaussianMixture`` on the same
points, in one run, with an equal or better mean log-likelihood. scikit-learn is timed once in
the same process right before ours; both run on one thread (torch and BLAS), because this
2-core machine is shared and two spinning threads per process measure the neighbours' load,
not the code. ``extra_info`` holds both times, the ratio and both log-likelihoods.

    python -m pytest tests/benchmarks/test_bench_gmm.py -m benchmark --benchmark-enable -s
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
import torch
from lwbench_plugins.gmm import GMMCodec, TorchGaussianMixture
from lwbench_plugins.gmm.mixture import _moments_from_labels
from sklearn.mixture import GaussianMixture
from threadpoolctl import threadpool_limits

from lwbench import Frame, get_sensor

pytestmark = pytest.mark.benchmark


def tunnel_scan(seed: int = 0) -> np.ndarray:
    """VLP-16 (every other azimuth column: 28,800 rays) in a wavy 2.5 m tunnel with a floor,
    1 cm range noise, 10 m max range -- the MEASURED.md setting, without the simulator."""
    sensor = get_sensor("vlp16")
    rng = np.random.default_rng(seed)
    d = sensor.ray_directions()[:, ::2].reshape(-1, 3)
    rho = np.hypot(d[:, 1], d[:, 2])
    radius = 2.5 * (1 + 0.08 * np.sin(3 * np.arctan2(d[:, 2], d[:, 1])))
    t = radius / np.maximum(rho, 1e-9)
    with np.errstate(divide="ignore"):
        t = np.minimum(t, np.where(d[:, 2] < 0, -1.5 / d[:, 2], np.inf))
    t = t + rng.normal(0, 0.01, len(t))
    ok = (t > sensor.min_range) & (t < sensor.max_range)
    return (d[ok] * t[ok, None]).astype(np.float32)


@pytest.fixture
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    with threadpool_limits(1):
        yield
    torch.set_num_threads(before)


def _initial_params(x: np.ndarray, k: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Our k-means++ + Lloyd start as (weights, means, precisions) for scikit-learn's *_init."""
    gm = TorchGaussianMixture(k, max_iter=1, random_state=seed)
    x64 = torch.as_tensor(x, dtype=torch.float64)
    xc = x64 - x64.mean(0)
    labels = gm._initial_labels(xc.float(), gm._generator())
    nk, means, covs, n = _moments_from_labels(xc, labels, k, gm.reg_covar)  # what our fit starts from
    return (nk / nk.sum()).numpy(), (means + x64.mean(0)).numpy(), np.linalg.inv(covs.numpy())


def test_fit_k200_vs_sklearn_same_start(benchmark, one_thread):
    """Both run 100 EM iterations from the same start (ours: its own k-means++ + Lloyd, which
    is inside its timed fit; scikit-learn: handed those parameters, so its k-means is *not*
    in its time). EM from one start is deterministic, so the log-likelihoods must agree; the
    EM-to-EM speed is the fair comparison. With their own initialisations the two land in
    different local optima (spread ~0.1-0.2 nats per point across seeds at K = 200 for both)."""
    x = tunnel_scan()
    k = 200
    w0, m0, p0 = _initial_params(x, k, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        ref = GaussianMixture(k, max_iter=100, weights_init=w0, means_init=m0, precisions_init=p0)
        ref.fit(x.astype(np.float64))
        sk_s = time.perf_counter() - t0
        ours = benchmark.pedantic(
            lambda: TorchGaussianMixture(k, max_iter=100, random_state=0).fit(x), rounds=1, iterations=1
        )
    ours_s = benchmark.stats.stats.min
    ll_ours, ll_ref = ours.score(x), ref.score(x)
    benchmark.extra_info.update(
        points=len(x), sklearn_s=round(sk_s, 2), ours_s=round(ours_s, 2), speedup=round(sk_s / ours_s, 2),
        ll_ours=round(ll_ours, 5), ll_sklearn=round(ll_ref, 5),
        iters_ours=ours.n_iter_, iters_sklearn=int(ref.n_iter_),
    )
    print(benchmark.extra_info)
    assert sk_s / ours_s >= 3.0
    assert ll_ours >= ll_ref - 1e-3


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_fit_k200_vs_sklearn_own_init(benchmark, one_thread, seed):
    """Each with its own initialisation and the same seed (scikit-learn's time includes its
    k-means): recorded for the closing note; only the speed is asserted, because which of the
    two lands in the better local optimum changes from seed to seed (see docs/gmm.md)."""
    x = tunnel_scan()
    k = 200
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        ref = GaussianMixture(k, max_iter=100, random_state=seed).fit(x.astype(np.float64))
        sk_s = time.perf_counter() - t0
        ours = benchmark.pedantic(
            lambda: TorchGaussianMixture(k, max_iter=100, random_state=seed).fit(x), rounds=1, iterations=1
        )
    ours_s = benchmark.stats.stats.min
    benchmark.extra_info.update(
        points=len(x), sklearn_s=round(sk_s, 2), ours_s=round(ours_s, 2), speedup=round(sk_s / ours_s, 2),
        ll_ours=round(ours.score(x), 4), ll_sklearn=round(ref.score(x), 4),
    )
    print(benchmark.extra_info)
    assert sk_s / ours_s >= 3.0


@pytest.mark.parametrize("k", [50, 200])
def test_codec_encode_decode(benchmark, one_thread, k):
    """Encode (fit) + decode (28k truncated draws) of one scan through the codec."""
    frame = Frame(tunnel_scan(), get_sensor("vlp16"))
    codec = GMMCodec(n_components=k, device="cpu")

    def roundtrip() -> np.ndarray:
        return GMMCodec().decode(codec.encode(frame))

    out = benchmark.pedantic(roundtrip, rounds=1, iterations=1)
    assert out.shape == frame.points.shape
