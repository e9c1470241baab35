"""docs/leaderboard.md's notebook example runs as written, on a store this test makes."""

from __future__ import annotations

import re
from pathlib import Path

from lwbench.registry import get_registry
from lwbench.run import DatasetRequest, RunRequest, Study

DOC = Path(__file__).resolve().parents[1] / "docs" / "leaderboard.md"


def test_the_notebook_example_runs(tmp_path):
    store = tmp_path / "nb.sqlite"
    request = RunRequest(datasets=(DatasetRequest("sim", {"scene": "tunnel"}, frames=2),),
                         codecs=("raw", "random", "rangeimage"), sequence_metrics=False, isolate=False, store=store)
    Study.prepare(request, get_registry()).run()
    (block,) = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    namespace = {"STORE": str(store)}
    exec(compile(block, str(DOC), "exec"), namespace)  # noqa: S102 - the doc's own example
    board = namespace["board"]
    assert list(board["codec"]) and len(board) == 3 and board["encode_x"].notna().all()
    assert len(namespace["rows"]) == 6 and len(namespace["by_machine"]) == 3
