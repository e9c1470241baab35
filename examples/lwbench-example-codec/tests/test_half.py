"""The example plugin's own tests: lwbench's conformance kit, then what is particular to it."""

from __future__ import annotations

import numpy as np
from lwbench_example_codec import HalfFloatCodec

from lwbench import get_sensor
from lwbench.testing import check_codec, parametrize_with_checks, room_scan


def test_the_codec_keeps_lwbenchs_contract():
    check_codec(HalfFloatCodec)


@parametrize_with_checks([(HalfFloatCodec, {"center": False})])
def test_each_contract_check_without_centring(plugin, check):
    check(plugin)  # one pytest case per check; those that do not apply (selection, budget) are skips


def test_centring_keeps_the_error_of_float16_small():
    frame = room_scan(get_sensor("vlp16"), seed=0)
    cloud = HalfFloatCodec().decode(HalfFloatCodec().encode(frame))
    assert np.abs(cloud - frame.points).max() < 0.005  # float16 at <= 4 m: ~2 mm steps
