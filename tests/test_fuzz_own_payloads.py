"""No codec writes a payload its own decoder refuses (issue 25; decoders' bounds of issue 23).

A decoder refuses coordinates no LiDAR returns (``lwbench.checked_cloud``: beyond 10 km, or its
payload's sensor's reach) and work beyond a budget; an encoder must then refuse the scan with a
clear ``ValueError`` (or another lwbench error) -- never write bytes its decoder refuses.

- the kit's scans, every declared parameter choice: the conformance kit's ``own_payloads`` check
  (``lwbench.testing.check_codec_decodes_own_payloads``, run by test_codec_conformance.py);
- here: scans holding points beyond the bounds (20 km, 2.5x the sensor's max range) and the
  first frame of every folder of ``shared/data/real`` (``real_data``, skipped without it), each
  codec encoded and decoded as a receiver does (a fresh instance handed the scan's sensor).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_codec_conformance import FAST_PARAMS

from lwbench import Frame, LwbenchError, PayloadError, open_dataset
from lwbench.registry import get_registry
from lwbench.testing import check_frames


def room_scan() -> Frame:
    return check_frames()["room"]

REGISTRY = get_registry()
CODECS = sorted(name for name, cls in REGISTRY.codecs.items() if not cls.needs)


def round_trip(name: str, frame: Frame, params: dict | None = None) -> np.ndarray | None:
    """The decoded cloud, or ``None`` when the encoder refused the scan (with a message)."""
    cls = REGISTRY.codec(name)
    params = dict(FAST_PARAMS.get(name, {}), **(params or {}))
    encoder = cls(**params)
    try:
        data = encoder.encode(frame)
    except (LwbenchError, ValueError) as exc:
        assert not isinstance(exc, PayloadError), f"{name}: the encoder raised a PayloadError ({exc})"
        assert str(exc), f"{name}: refused the scan without a message"
        return None
    decoder = cls(**params).use_sensors([frame.sensor, *encoder.sensors])
    try:
        return decoder.decode(data)
    except PayloadError as exc:
        pytest.fail(f"{name}: the decoder refuses the encoder's own payload ({exc})")


def _with_far_points(distance: float) -> Frame:
    room = room_scan()
    room = room.subset(np.arange(0, len(room), 8))
    far = np.array([[distance, 0.0, 0.0], [0.0, -distance, 1.0], [0.6 * distance, 0.8 * distance, 0.0]], np.float32)
    return Frame(np.concatenate([room.points, far]), room.sensor)


def _keep_all(name: str) -> dict:
    """A selector keeps every point (so the far ones are in its payload)."""
    return {"ratio": 1.0} if any(p.name == "ratio" for p in REGISTRY.codec(name).all_params()) else {}


VARIANTS = [(c, _keep_all(c)) for c in CODECS] + [("gmm", {"reproject": True})]


@pytest.mark.heavy
@pytest.mark.parametrize(("codec", "params"), VARIANTS, ids=[f"{c}{p or ''}" for c, p in VARIANTS])
@pytest.mark.parametrize("where", ["20 km", "2.5x max range"])
def test_a_scan_beyond_the_decoders_bound_is_refused_at_encode_or_decodes(codec, params, where):
    sensor_range = room_scan().sensor.max_range
    frame = _with_far_points(20_000.0 if where == "20 km" else 2.5 * sensor_range)
    out = round_trip(codec, frame, params)
    if out is not None:
        assert np.isfinite(out).all() and np.linalg.norm(out, axis=1).max() <= 10_000.0 * 1.0001


def test_the_serializers_refusals_say_why():
    """raw at 20 km: a ValueError naming the bound; quantized beyond 32 bits: one naming the step."""
    from lwbench import pack_points

    with pytest.raises(ValueError, match="farther than 10000 m"):
        REGISTRY.codec("raw")().encode(_with_far_points(20_000.0))
    wide = np.array([[0.0, 0.0, 0.0], [5000.0, 0.0, 0.0]], np.float32)
    with pytest.raises(ValueError, match="more than 32 bits"):
        pack_points(wide, "quantized", 1e-6)
    with pytest.raises(ValueError, match="random: a quantized extent .* more than 32 bits"):
        REGISTRY.codec("random")(ratio=1.0, encoding="quantized", quant_step=1e-6).encode(
            Frame(wide, room_scan().sensor)
        )


def test_gmm_refuses_a_decode_budget_it_cannot_keep_before_fitting():
    """A header asking for more than ~1 s of decoding is refused by the decoder, so the encoder
    refuses such settings first (and says which knob)."""
    frame = room_scan()
    n = len(frame)
    with pytest.raises(ValueError, match="lower samples or free_components"):
        REGISTRY.codec("gmm")(n_components=8, free_components=8, samples=16.0, max_iter=2).encode(
            Frame(np.tile(frame.points, (max(1, 60_000 // n), 1)), frame.sensor)
        )


def _real_folders() -> list[str]:
    from _real import real_data_dir

    root = real_data_dir()
    if not root.is_dir():
        return ["(absent)"]
    return sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


@pytest.mark.heavy
@pytest.mark.parametrize("folder", _real_folders())
def test_every_codec_decodes_its_own_payload_of_each_real_first_frame(real_data, folder):
    frame = open_dataset(real_data / folder).frame(0)
    failures = []
    for codec in CODECS:
        try:
            out = round_trip(codec, frame)
        except pytest.fail.Exception as exc:
            failures.append(str(exc))
            continue
        if out is not None:
            assert np.isfinite(out).all(), codec
    assert not failures, "\n".join(failures)
