from __future__ import annotations

import numpy as np
import pytest

from lwbench import Frame, InvalidFrameError, Param, ParameterError, get_sensor
from lwbench.params import resolve_params


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_frame_rejects_non_finite_points_with_a_count(bad):
    pts = np.zeros((10, 3), np.float32)
    pts[3, 1] = bad
    with pytest.raises(InvalidFrameError, match="1 of 10"):
        Frame(pts, get_sensor("vlp16"))


def test_frame_rejects_wrong_shapes():
    with pytest.raises(InvalidFrameError):
        Frame(np.zeros((10, 2)), get_sensor("vlp16"))
    with pytest.raises(InvalidFrameError):
        Frame(np.zeros((10, 3)), get_sensor("vlp16"), intensity=np.zeros(9))


def test_empty_frame_is_a_valid_frame():
    f = Frame(np.zeros((0, 3)), get_sensor("vlp16"))
    assert len(f) == 0 and f.raw_bytes == 0


def test_subset_carries_attributes():
    f = Frame(np.arange(12, dtype=np.float32).reshape(4, 3), get_sensor("vlp16"), intensity=np.arange(4.0))
    s = f.subset(np.array([1, 3]))
    np.testing.assert_array_equal(s.intensity, [1.0, 3.0])
    np.testing.assert_array_equal(s.points[1], [9, 10, 11])


def test_params_parse_validate_and_reject():
    p = Param("k", "int", 5, low=1, high=10)
    assert p.parse("7") == 7
    with pytest.raises(ParameterError, match="above the maximum"):
        p.parse("11")
    with pytest.raises(ParameterError, match="cannot read"):
        p.parse("seven")
    assert Param("b", "bool", False).parse("yes") is True
    with pytest.raises(ParameterError, match="not one of"):
        Param("e", "str", "a", choices=("a", "b")).validate("c")


def test_resolve_params_fills_defaults_and_rejects_unknown_names():
    declared = (Param("a", "float", 1.0), Param("b", "int", None))
    assert resolve_params("x", declared, {"a": "2.5"}) == {"a": 2.5, "b": None}
    with pytest.raises(ParameterError, match="unknown parameter"):
        resolve_params("x", declared, {"c": 1})
