"""lwbench's built-in plugins. Each sub-package is one plugin, registered by an entry point in
the ``lwbench`` group and importing only the public ``lwbench`` API, exactly as a third-party
plugin would (so moving one into its own distribution only means adding a pyproject)."""
