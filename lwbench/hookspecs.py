"""Hook specifications: the only contract between lwbench and its plugins.

A plugin is a module (or object) with functions named like these, decorated with
``lwbench.hookimpl``, and an entry point in the ``lwbench`` group pointing at it.
Registration hooks return *classes*; lwbench instantiates them with the parameters a run asks
for. Hooks are called with keyword arguments only (pluggy's rule); these take none.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from lwbench.codec import Codec
    from lwbench.dataset import Dataset
    from lwbench.metric import FrameMetric, SequenceMetric

PROJECT = "lwbench"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def lwbench_codecs() -> list[type[Codec]]:
    """Return the codec classes this plugin provides.

    :return: ``Codec`` subclasses (not instances), each with a unique ``name``.
    """


@hookspec
def lwbench_datasets() -> list[type[Dataset]]:
    """Return the dataset (loader) classes this plugin provides.

    :return: ``Dataset`` subclasses, each with a unique ``name``.
    """


@hookspec
def lwbench_metrics() -> list[type[FrameMetric] | type[SequenceMetric]]:
    """Return the metric classes this plugin provides.

    :return: ``FrameMetric`` or ``SequenceMetric`` subclasses; their ``ids`` must not clash
        with another metric's.
    """


@hookspec
def lwbench_register_commands(cli) -> None:
    """Add command-line commands to ``lwbench`` (as datasette's ``register_commands``).

    :param cli: the ``typer.Typer`` application; a plugin adds ``@cli.command()`` functions, or
        a sub-application with ``cli.add_typer``. Keep the imports inside the command bodies:
        every plugin's commands are registered whenever ``lwbench`` starts.
    """
