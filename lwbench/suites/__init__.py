"""Suites: named, versioned benchmark protocols shipped with lwbench, so that two teams run the
same thing -- datasets with their seeds and frames, codecs and sweeps, metrics and their
settings, all pinned in one run file (``NAME-VERSION.toml`` here).

A suite's identity is its name and version plus a hash of the file's bytes
(``sim-tunnel-1+3f2a9c01b7e4``): an edited file is another suite, whatever it is called. Every
row a suite run asks for -- computed or found in the store -- is tagged with that identity
(:meth:`lwbench.results.store.ResultStore.tag_suite`), and bundles carry the tags, so a common
board can say which protocol its numbers follow (``lwbench leaderboard --suite``). A user's own
data joins a suite with ``lwbench suite run NAME --dataset PATH``: the suite's codecs and
settings on that data, whose rows name the data by its content hash (the dataset id).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

from lwbench.errors import ParameterError

__all__ = ["SUITES_DIR", "Suite", "find_suite", "list_suites"]

SUITES_DIR = Path(__file__).parent


@dataclass(frozen=True)
class Suite:
    name: str  # NAME-VERSION, the file's stem
    path: Path
    digest: str  # sha256 of the file's bytes

    @property
    def id(self) -> str:
        """``NAME-VERSION+HASH``: what every row of the suite is tagged with."""
        return f"{self.name}+{self.digest[:12]}"

    @property
    def description(self) -> str:
        """The file's leading comment lines (what the suite is, in its own words)."""
        lines = []
        for line in self.path.read_text().splitlines():
            if not line.startswith("#"):
                break
            lines.append(line.lstrip("# ").rstrip())
        return " ".join(x for x in lines if x)

    def request(self, dataset: str | None = None, dataset_params: dict | None = None):
        """The suite's :class:`~lwbench.run.RunRequest`, tagged with its id; ``dataset``: run its
        codecs and settings on that data instead of the suite's datasets."""
        from lwbench.run import DatasetRequest
        from lwbench.run.config import read_run_file

        request = read_run_file(self.path)
        if dataset is not None:
            request = replace(request, datasets=(DatasetRequest(dataset, dict(dataset_params or {})),))
        return replace(request, suite=self.id)


def list_suites() -> list[Suite]:
    return [Suite(p.stem, p, hashlib.sha256(p.read_bytes()).hexdigest()) for p in sorted(SUITES_DIR.glob("*.toml"))]


def find_suite(name: str) -> Suite:
    """The suite of that name (``sim-tunnel-1``), or a clear error listing the suites."""
    suites = {s.name: s for s in list_suites()}
    if name not in suites:
        raise ParameterError(f"no suite {name!r}; suites: {', '.join(suites) or 'none'}")
    return suites[name]
