"""The contract every registered codec must keep (the gate third-party codecs meet too).

Parametrized over the registry, so a new plugin is checked the moment it is installed:
bytes on the wire parse as an lwbench payload for this codec; decoding needs only the bytes
(a fresh instance); encode and decode are deterministic; truncated, bit-flipped and foreign
payloads raise ``PayloadError``; an empty or NaN scan gives a clear error, not a crash deep
inside a library; every frame metric can score what was decoded.

Each codec meets three generated scans: a clean box room, the same room with exact duplicate
points, and a 32-beam scan with a ring field whose derived beam table has coincident beams
(``_scans.py``): what ordinary real scans hold (issue 11 §4), checked here without the real
samples (``test_real_conformance.py`` adds those where they exist).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _scans import hdl32_ring_frame, with_exact_duplicates

from lwbench import (
    Evaluation,
    Frame,
    InvalidFrameError,
    LwbenchError,
    Payload,
    PayloadError,
    SelectionCodec,
    get_sensor,
)
from lwbench.registry import get_registry

# Smaller settings for the slow learners, so the whole suite stays fast; the contract does not
# depend on model size.
FAST_PARAMS = {"gmm": {"n_components": 8, "max_iter": 20}, "vsgp": {"num_inducing": 100}}


def _params(name: str, cls) -> dict:
    declared = {p.name for p in cls.all_params()}
    return {k: v for k, v in FAST_PARAMS.get(name, {}).items() if k in declared}


def box_room() -> Frame:
    """A VLP-16 scan inside a 6 m x 4 m box room: walls, floor and ceiling, every ray a hit."""
    sensor = get_sensor("vlp16")
    dirs = sensor.ray_directions().reshape(-1, 3)
    half = np.array([3.0, 2.0, 1.2])
    with np.errstate(divide="ignore"):
        t = np.min(np.where(np.abs(dirs) > 1e-9, half / np.abs(dirs), np.inf), axis=1)
    rng = np.random.default_rng(0)
    pts = dirs * (t + rng.normal(0, 0.01, len(t)))[:, None]
    return Frame(pts.astype(np.float32), sensor, index=3, intensity=np.full(len(pts), 0.5, np.float32))


SCANS = {
    "box-room": box_room,
    # Every other ray of the room (half the size: the contract does not depend on it) plus
    # exact copies of a quarter of those points.
    "exact-duplicates": lambda: with_exact_duplicates(box_room().subset(np.arange(0, 57_600, 2)), share=0.25),
    "hdl32-ring": hdl32_ring_frame,
}
CODECS = sorted(get_registry().codecs)


@pytest.fixture(scope="module", params=list(SCANS))
def frame(request) -> Frame:
    return SCANS[request.param]()


@pytest.fixture(scope="module", params=CODECS)
def codec(request):
    cls = get_registry().codec(request.param)
    return request.param, cls, _params(request.param, cls)


@pytest.fixture(scope="module")
def encoded(codec, frame):
    name, cls, params = codec
    return name, cls, params, cls(**params).encode(frame)


def test_payload_is_an_lwbench_payload_for_this_codec(encoded):
    name, _, _, data = encoded
    assert isinstance(data, bytes)
    assert Payload.from_bytes(data).codec_id == name


def test_decode_from_the_bytes_alone_is_a_finite_cloud(encoded):
    _, cls, params, data = encoded
    cloud = cls(**params).decode(data)
    assert cloud.ndim == 2 and cloud.shape[1] == 3 and cloud.dtype == np.float32
    assert len(cloud) > 0 and np.isfinite(cloud).all()


def test_encode_and_decode_are_deterministic(encoded, frame):
    _, cls, params, data = encoded
    assert cls(**params).encode(frame) == data
    np.testing.assert_array_equal(cls(**params).decode(data), cls(**params).decode(data))


def test_corrupt_payloads_raise_the_payload_error(encoded):
    name, cls, params, data = encoded
    decoder = cls(**params)
    for bad in (data[: len(data) // 2], data[:-1], data[:-1] + bytes([data[-1] ^ 1])):
        with pytest.raises(PayloadError):
            decoder.decode(bad)
    other = "raw" if name != "raw" else "random"
    foreign = get_registry().codec(other)().encode(Frame(np.ones((5, 3), np.float32), get_sensor("vlp16")))
    with pytest.raises(PayloadError):
        decoder.decode(foreign)


def test_selection_codecs_select_a_subset(encoded, frame):
    name, cls, params, _ = encoded
    if not issubclass(cls, SelectionCodec):
        pytest.skip(f"{name} is a representation codec")
    idx = cls(**params).select(frame)
    assert len(np.unique(idx)) == len(idx) and 0 < len(idx) <= len(frame)


def test_empty_scan_is_handled_or_refused_clearly(codec):
    name, cls, params = codec
    empty = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
    try:
        data = cls(**params).encode(empty)
    except (LwbenchError, ValueError) as exc:
        assert str(exc), f"{name} refused an empty scan without a message"
        return
    cloud = cls(**params).decode(data)
    assert cloud.shape[1] == 3 and np.isfinite(cloud).all()


def test_every_frame_metric_scores_the_decoded_cloud(encoded, frame):
    """What the runner does after decoding: a metric that raises would be a failure row."""
    _, cls, params, data = encoded
    ev = Evaluation(frame, data, cls(**params).decode(data), cls.kind, {"encode_ms": 1.0, "decode_ms": 1.0})
    for metric_cls in get_registry().frame_metrics.values():
        values = metric_cls().compute(ev)
        assert values, metric_cls.name
        nan = [k for k, v in values.items() if v is not None and math.isnan(v)]
        assert not nan, f"{metric_cls.name} gave NaN for {nan}"


def test_nan_scan_never_reaches_a_codec():
    pts = np.ones((10, 3), np.float32)
    pts[0] = np.nan
    with pytest.raises(InvalidFrameError):
        Frame(pts, get_sensor("vlp16"))
