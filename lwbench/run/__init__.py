"""The run path, one stage per module -- read them in this order to follow a frame:

1. :mod:`.plan` -- what to run: dataset x codec configurations x sweeps, one seed policy;
2. :mod:`.evaluate` -- one frame through one configuration, scored (a worker's whole job);
3. :mod:`.record` -- results become rows with keys and provenance, decoded clouds artifacts;
4. :mod:`.sequence` -- sequence metrics over a configuration's recorded frames;

with :mod:`.execute` (where evaluations run) and :mod:`.runner` (the four in order, one plan;
internal). A :class:`~.request.RunRequest` (what the command line, a run file -- :mod:`.config` --
or a gate asks for) becomes plans and a :class:`~.request.Study` in :mod:`.request`, whose
:meth:`~.request.Study.run` is the one entry point every front end uses. The leaderboard
(:mod:`lwbench.results.leaderboard`) reads what they stored.
"""

from .evaluate import Evaluator, FrameResult
from .execute import DEFAULT_TIMEOUT_S, FrameTask, InProcessExecutor, ProcessExecutor, Worker
from .plan import (
    CodecConfig,
    DatasetSpec,
    RunPlan,
    config_label,
    expand_codec_configs,
    frames_for,
    parse_assignments,
    parse_metric_params,
    parse_sweeps,
    plan_run,
    preflight,
    resolve_dataset,
)
from .record import Provenance, RowFactory
from .request import (
    DEFAULT_STORE,
    DatasetRequest,
    PlanFinished,
    PlanStarted,
    RunRequest,
    Study,
    StudyEvent,
    StudyOutcome,
)
from .runner import Progress, RunSummary
from .sequence import SequenceStage

__all__ = [
    "DEFAULT_STORE",
    "DatasetRequest",
    "RunRequest",
    "PlanFinished",
    "PlanStarted",
    "Study",
    "StudyEvent",
    "StudyOutcome",
    "CodecConfig",
    "DEFAULT_TIMEOUT_S",
    "InProcessExecutor",
    "ProcessExecutor",
    "DatasetSpec",
    "Evaluator",
    "FrameResult",
    "FrameTask",
    "Progress",
    "Provenance",
    "RowFactory",
    "RunPlan",
    "RunSummary",
    "SequenceStage",
    "Worker",
    "config_label",
    "expand_codec_configs",
    "frames_for",
    "parse_assignments",
    "parse_metric_params",
    "parse_sweeps",
    "plan_run",
    "preflight",
    "resolve_dataset",
]
