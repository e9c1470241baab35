"""The dataset contract, one top-level check per clause (``check_dataset_<what>(dataset_cls, params)``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lwbench.dataset import Dataset
from lwbench.frame import Frame

from .base import check, fail

__all__ = ["check_dataset_declared", "check_dataset_deterministic", "check_dataset_frames"]


@check("declared", "dataset")
def check_dataset_declared(dataset_cls, params: dict | None = None) -> None:
    """A Dataset subclass with a name, a ``describe()``, and a ``sniff`` that answers a bool for
    any path (and never raises)."""
    if not (isinstance(dataset_cls, type) and issubclass(dataset_cls, Dataset)):
        fail("declared", f"{dataset_cls!r} is not a lwbench.Dataset subclass")
    if not getattr(dataset_cls, "name", ""):
        fail("declared", "a dataset needs a name")
    dataset_cls.describe()
    if not isinstance(dataset_cls.sniff(Path("/nonexistent/lwbench-check")), bool):
        fail("declared", "sniff() must answer True or False (and never raise) for any path")


@check("frames", "dataset")
def check_dataset_frames(dataset_cls, params: dict | None = None) -> None:
    """Frames carry their index (and a pose when ``has_poses``); indexing past the end raises
    ``IndexError``."""
    ds = dataset_cls(**dict(params or {}))
    n = len(ds)
    if n < 1:
        fail("frames", "a dataset with these parameters has no frames")
    for i in sorted({0, n - 1}):
        f = ds[i]
        if not isinstance(f, Frame) or f.index != i:
            fail("frames", f"frame {i}: expected a Frame with index {i}")
        if ds.has_poses and f.pose is None:
            fail("frames", f"frame {i}: has_poses is true but the frame has no pose")
    try:
        ds[n]
    except IndexError:
        pass
    else:
        fail("frames", "indexing past the end must raise IndexError")


@check("deterministic", "dataset")
def check_dataset_deterministic(dataset_cls, params: dict | None = None) -> None:
    """The same parameters give the same ``identity()`` string and the same frames."""
    a, b = dataset_cls(**dict(params or {})), dataset_cls(**dict(params or {}))
    if a.identity() != b.identity() or not isinstance(a.identity(), str):
        fail("deterministic", "identity() must be the same string for the same parameters")
    if not np.array_equal(a[0].points, b[0].points):
        fail("deterministic", "the same parameters must give the same frames")
