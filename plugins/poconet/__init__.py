"""``poconet`` and ``oracle``: PocoNet (Cui et al.), the learned localization-oriented selector,
and the true observation-count labels it learns from.

- :mod:`.labels` -- §III-B: observation counts over a sequence, RANSAC ground, Algorithm 1
  (``lwbench label DATASET --out DIR``);
- :mod:`.network` / :mod:`.data` -- §III-C: RandLA-Net backbone, Global Feature Attention,
  siamese encoder, in plain PyTorch with SciPy k-d trees in the data pipeline;
- :mod:`.train` -- ``lwbench train poconet`` (CPU or CUDA, resumable);
- :mod:`.codec` -- the two selection codecs; the shipped weights are ``weights/``;
- :mod:`.diagnose`, :mod:`.table_command`, :mod:`.figures` -- ``lwbench diagnose``, ``lwbench
  poconet-table`` (Table I on held-out drives, docs/poconet.md §6), ``lwbench poconet-ablation``
  and ``lwbench poconet-real`` (the global module's ablation, real scans).

Heavy imports (torch, SciPy, Open3D) happen inside the functions that use them.
"""

from __future__ import annotations

from lwbench import hookimpl

from .codec import OracleSelector, PocoNetSelector

__all__ = ["PocoNetSelector", "OracleSelector"]


@hookimpl
def lwbench_codecs():
    return [PocoNetSelector, OracleSelector]


@hookimpl
def lwbench_register_commands(cli) -> None:
    from . import ceiling, commands, diagnose, figures, table_command

    commands.register(cli)
    diagnose.register(cli)
    table_command.register(cli)
    figures.register(cli)
    ceiling.register(cli)
