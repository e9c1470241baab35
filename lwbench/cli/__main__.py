"""``python -m lwbench.cli`` runs the ``lwbench`` command line."""

from lwbench.cli import main

main()
