"""``random``: keep a uniformly random subset -- PocoNet's weakest baseline and the sanity
floor for every selector."""

from __future__ import annotations

import numpy as np

from lwbench import BUDGET_PARAMS, Frame, Param, SelectionCodec, hookimpl


class RandomSelector(SelectionCodec):
    """Uniform sampling without replacement, seeded per frame.

    The generator is seeded with ``(seed, frame.index)`` so that a frame's selection does not
    depend on which frames were evaluated before it (parallel workers, resumed runs).
    """

    name = "random"
    in_default_run = True
    description = "uniform random subset (seeded)"
    params = (*BUDGET_PARAMS, Param("seed", "int", 0, "random seed", low=0))

    def select(self, frame: Frame) -> np.ndarray:
        k = self.budget(len(frame))
        rng = np.random.default_rng([self.config["seed"], frame.index])
        return np.sort(rng.choice(len(frame), size=k, replace=False))


@hookimpl
def lwbench_codecs() -> list[type[RandomSelector]]:
    return [RandomSelector]
