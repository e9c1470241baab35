"""The ``lwbench`` command line (typer + rich): forms and metric ids follow docs/design.md.

One module per command group, read in any order:

- :mod:`.app` -- the application: the one error boundary (a user error is one line and exit 2),
  ``--strict`` / ``--version``, plugin commands loaded lazily;
- :mod:`.options` -- the options several commands share, declared once (``--frames``, ``--param``,
  ``--dataset``, ``--store`` ... mean one thing everywhere), and the help panels;
- :mod:`.output` -- consoles, progress bars and the leaderboard table;
- :mod:`.listing` (``list``, ``inspect``), :mod:`.running` (``run``), :mod:`.board` (``leaderboard``,
  ``rd``, ``report``), :mod:`.bundles` (``export``, ``import``), :mod:`.suite`
  (``suite list``, ``suite run``), :mod:`.files` (``encode``, ``decode``,
  ``view``), :mod:`.simulate`, :mod:`.stream`, :mod:`.fuzz` (``fuzz``: crafted payloads against the decoders).

Commands only parse words and print: a run is a :class:`lwbench.run.RunRequest` (the same one a
run file and a gate fill) planned and run by :class:`lwbench.run.Study`; the board is
:func:`lwbench.results.leaderboard.build_leaderboard`.
"""

from __future__ import annotations

from . import board, bundles, files, fuzz, listing, running, simulate, stream, suite  # noqa: F401 - each module adds its commands
from .app import app, main

__all__ = ["app", "main"]
