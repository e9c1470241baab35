"""The scout -> base link, real and measured (``lwbench stream``).

A scout process encodes scans at the sensor's rate and sends the payloads over a TCP socket on
127.0.0.1 through a link model (token-bucket cap, packet loss, delay, corruption: :mod:`.shaper`,
:mod:`.transmit`); a base process decodes them and builds the occupancy map live (:mod:`.base`);
:mod:`.session` runs and measures one stream, :mod:`.study` a set of codecs through the same caps
and draws the VSGP paper's Fig. 6d. Messages are framed by :mod:`.wire` (no pickle anywhere).
"""

from .session import FrameOutcome, StreamRun, StreamSettings, reference_map, run_stream
from .shaper import KB, LinkModel, TokenBucket, parse_cap
from .study import STREAM_TABLES, StudyResult, fig6d, ratio_lines, run_study, table_rows

__all__ = [
    "FrameOutcome",
    "KB",
    "LinkModel",
    "StreamRun",
    "STREAM_TABLES",
    "StreamSettings",
    "StudyResult",
    "TokenBucket",
    "fig6d",
    "parse_cap",
    "ratio_lines",
    "reference_map",
    "run_stream",
    "run_study",
    "table_rows",
]
