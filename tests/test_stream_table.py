"""``lwbench stream``'s table says why frames were dropped and where a frame's latency goes (the
split into encode, queue, transfer and decode the README promises)."""

from __future__ import annotations

from lwbench.link import LinkModel, table_rows
from lwbench.link.session import FrameOutcome, StreamRun


def _run() -> StreamRun:
    parts = {"encode": 0.120, "queue": 0.010, "transfer": 0.030, "decode": 0.040}
    outcomes = [FrameOutcome(0, "on_time", latency=0.2, parts=parts, payload_bytes=900)]
    outcomes += [FrameOutcome(i, "dropped", reason="encoder busy") for i in range(1, 4)]
    outcomes.append(FrameOutcome(4, "dropped", reason="queue full", payload_bytes=900))
    return StreamRun("gmm", LinkModel(50.0), 10.0, outcomes, 1800, {0: 1800}, 0.1, 0.5, 0.5, 10, 20, 1, 0)


def test_the_table_says_why_frames_dropped_and_splits_the_latency():
    header, (row,) = table_rows([_run()])
    cells = dict(zip(header, row, strict=True))
    assert cells["dropped (why)"] == "4 (encoder busy 3, queue full 1)"
    assert cells["median ms: encode / queue / transfer / decode"] == "120 / 10 / 30 / 40"
    assert cells["latency ms (median / p95)"] == "200 / 200"


def test_a_stream_with_nothing_decoded_shows_dashes_not_zeros():
    run = _run()
    run.outcomes = [FrameOutcome(0, "dropped", reason="encoder busy")]
    header, (row,) = table_rows([run])
    cells = dict(zip(header, row, strict=True))
    assert cells["dropped (why)"] == "1 (encoder busy 1)"
    assert cells["median ms: encode / queue / transfer / decode"] == "–"


def test_the_tables_fit_a_100_column_log_and_cut_no_value():
    """Issue 33: one table of thirteen columns was 204 wide and cut mid-value at 100 off a terminal."""
    import io

    from rich.console import Console

    from lwbench.cli.stream import stream_tables
    from lwbench.link import STREAM_TABLES

    run = _run()
    run.outcomes.append(FrameOutcome(5, "dropped", reason="encoder busy while the link was full"))
    header, rows = table_rows([run, _run()])
    shown = [c for _, cols in STREAM_TABLES for c in cols if c not in ("codec", "link")]
    assert sorted(shown) == sorted(header[2:])  # every column is in one of the tables
    out = io.StringIO()
    for table in stream_tables([run, _run()], 10.0):
        Console(file=out, width=100, force_terminal=False).print(table)
    text = out.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 100
    assert "…" not in text
    assert "5 (encoder" in text and "120 / 10 / 30 / 40" in text and "1/6" in text
