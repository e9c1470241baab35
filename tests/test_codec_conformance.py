"""The contract every registered codec and dataset must keep -- checked with the same kit a
third-party plugin runs in its own tests (:mod:`lwbench.testing`).

Parametrized over the registry, so a new plugin is checked the moment it is installed, one test
per (codec, check): valid declarations; bytes on the wire that parse as an lwbench payload for
this codec; a fresh instance decoding from the bytes alone to a finite float32 cloud; determinism;
truncated, bit-flipped, foreign and empty payloads raising ``PayloadError``; every payload written
with each declared choice decoding; empty scans handled or refused clearly; selectors meeting their
budget; every frame metric scoring the result; a bounded fuzz campaign. Every registered metric
is held to its contract too (``check_metric``). Each
runs on :func:`lwbench.testing.check_frames`: an off-grid room, the same with exact duplicate
points, and a 32-beam ring scan whose derived table has coincident beams -- what ordinary real
scans hold (``test_real_conformance.py`` adds the real samples where they exist).
"""

from __future__ import annotations

import numpy as np
import pytest

from lwbench import Frame, InvalidFrameError, RepresentationCodec, get_sensor
from lwbench.registry import get_registry
from lwbench.testing import (
    ConformanceError,
    check_codec_budget,
    check_codec_decodes_own_payloads,
    check_metric,
    codec_checks,
    dataset_checks,
    parametrize_with_checks,
)

# Smaller settings for the slow learners, so the whole suite stays fast; the contract does not
# depend on model size.
REGISTRY = get_registry()
# Each codec declares the settings a quick harness runs it with (Codec.test_params).
FAST_PARAMS = {name: cls.test_params() for name, cls in REGISTRY.codecs.items() if cls.test_params()}
CODECS = [(cls, FAST_PARAMS.get(name)) for name, cls in sorted(REGISTRY.codecs.items())]
METRICS = sorted({**REGISTRY.frame_metrics, **REGISTRY.sequence_metrics}.items())


@pytest.mark.heavy
@parametrize_with_checks(CODECS)
def test_codec_contract(plugin, check):
    check(plugin)


@pytest.mark.heavy
@pytest.mark.parametrize("metric", [m for _, m in METRICS], ids=[n for n, _ in METRICS])
def test_metric_contract(metric):
    check_metric(metric)


class _WritesWhatItCannotRead(RepresentationCodec):
    """Encodes a 'grid' flag its decoder refuses (VSGP's guessed-sensor bug, in miniature)."""

    name = "test-unreadable"
    from lwbench import Param

    params = (Param("grid", "bool", False, "a mode whose payloads the decoder refuses"),)

    def encode(self, frame):
        return self.make_payload(frame, {"grid": self.config["grid"]}, frame.points.astype("<f4").tobytes())

    def decode(self, data):
        from lwbench import PayloadError, checked_cloud

        payload = self.read_payload(data)
        if payload.meta["grid"]:
            raise PayloadError("test-unreadable payload: the grid would take too many evaluations")
        return checked_cloud(np.frombuffer(payload.body, "<f4").reshape(-1, 3), self.name)


def test_the_kit_catches_a_codec_whose_decoder_refuses_its_own_payloads_and_skips_what_does_not_apply():
    with pytest.raises(ConformanceError, match="own_payloads: room with {'grid': True}: the decoder refuses"):
        check_codec_decodes_own_payloads(_WritesWhatItCannotRead)
    pairs = dict(codec_checks(_WritesWhatItCannotRead))
    assert {"declared", "payloads", "own_payloads", "corrupt", "selection", "budget", "fuzz"} <= set(pairs)
    with pytest.raises(pytest.skip.Exception, match="not a selection codec"):
        pairs["selection"]()
    with pytest.raises(pytest.skip.Exception, match="declares no ratio/points budget"):
        pairs["budget"]()
    check_codec_budget(REGISTRY.codec("random"))  # applies, and holds


def _dataset_params(name: str, kitti_folder, tmp_path) -> dict:
    if name == "rosbag":  # the same scans, in a bag this test writes
        from lwbench.bags import frames_to_clouds, write_bag

        frames = list(REGISTRY.dataset("kitti")(path=str(kitti_folder)))
        return {"path": str(write_bag(tmp_path / "bag", frames_to_clouds(frames), sensor=frames[0].sensor))}
    return {"sim": {"scene": "indoor", "frames": 2}, "kitti": {"path": str(kitti_folder)},
            "files": {"path": str(kitti_folder / "velodyne" / "000000.bin")}}.get(name, {})


@pytest.mark.parametrize("dataset", sorted(REGISTRY.datasets))
def test_dataset_contract(dataset, kitti_folder, tmp_path):
    for _, check in dataset_checks(REGISTRY.dataset(dataset), _dataset_params(dataset, kitti_folder, tmp_path)):
        check()


def test_nan_scan_never_reaches_a_codec():
    pts = np.ones((10, 3), np.float32)
    pts[0] = np.nan
    with pytest.raises(InvalidFrameError):
        Frame(pts, get_sensor("vlp16"))
