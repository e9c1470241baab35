"""The contract every registered codec and dataset must keep -- checked with the same kit a
third-party plugin runs in its own tests (:mod:`lwbench.testing`).

Parametrized over the registry, so a new plugin is checked the moment it is installed, one test
per (codec, check): valid declarations; bytes on the wire that parse as an lwbench payload for
this codec; a fresh instance decoding from the bytes alone to a finite float32 cloud; determinism;
truncated, bit-flipped, foreign and empty payloads raising ``PayloadError``; empty scans handled
or refused clearly; selectors meeting their budget; every frame metric scoring the result. Each
runs on :func:`lwbench.testing.check_frames`: an off-grid room, the same with exact duplicate
points, and a 32-beam ring scan whose derived table has coincident beams -- what ordinary real
scans hold (``test_real_conformance.py`` adds the real samples where they exist).
"""

from __future__ import annotations

import numpy as np
import pytest

from lwbench import Frame, InvalidFrameError, get_sensor
from lwbench.registry import get_registry
from lwbench.testing import codec_checks, dataset_checks

# Smaller settings for the slow learners, so the whole suite stays fast; the contract does not
# depend on model size.
FAST_PARAMS = {"gmm": {"n_components": 8, "max_iter": 20, "fit_points": 4000}, "vsgp": {"num_inducing": 100}}
REGISTRY = get_registry()
CASES = [
    (name, check)
    for name, cls in sorted(REGISTRY.codecs.items())
    for check, _ in codec_checks(cls, FAST_PARAMS.get(name))
]


@pytest.mark.parametrize("codec, check", CASES, ids=[f"{c}-{k}" for c, k in CASES])
def test_codec_contract(codec, check):
    cls = REGISTRY.codec(codec)
    if cls.needs and check != "declared":
        pytest.skip(f"{codec} cannot run on an arbitrary scan: it needs {cls.needs} (tested in its own tests)")
    dict(codec_checks(cls, FAST_PARAMS.get(codec)))[check]()


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
