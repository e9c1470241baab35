"""Every error lwbench raises on purpose, in one place.

All of them derive from :class:`LwbenchError`: the CLI prints such an error as one line and
exits with status 2 (a user error or bad input), while anything else is a bug with a traceback.
Most also derive from ``ValueError`` so that callers who only know the standard library can
still catch them.
"""

from __future__ import annotations

__all__ = [
    "LwbenchError",
    "InvalidFrameError",
    "ParameterError",
    "PayloadError",
    "DataFormatError",
    "SelectionError",
    "DecodeError",
    "PluginError",
    "MissingDependencyError",
    "StoreError",
    "WorkerError",
    "DataWarning",
]


class LwbenchError(Exception):
    """Base class of the errors lwbench raises on purpose (user-facing, no traceback needed)."""


class InvalidFrameError(LwbenchError, ValueError):
    """A scan that cannot be evaluated: wrong shape or dtype, NaN/inf coordinates."""


class ParameterError(LwbenchError, ValueError):
    """A parameter value that is unknown, of the wrong type or out of its declared range."""


class PayloadError(LwbenchError, ValueError):
    """A payload that is not a well-formed lwbench payload (or not one this codec can read)."""


class DataFormatError(LwbenchError, ValueError):
    """A file on disk that is not in the format its name or folder promises."""


class SelectionError(LwbenchError, ValueError):
    """A selector returned indices that do not describe a subset of the scan."""


class DecodeError(LwbenchError):
    """A codec's decode returned something that is not a finite (M, 3) cloud."""


class PluginError(LwbenchError):
    """A plugin failed to load (raised only in strict mode) or a name is unknown."""


class MissingDependencyError(LwbenchError, ImportError):
    """A library lwbench needs cannot be imported; the message says what to install."""


class StoreError(LwbenchError):
    """A file given as a results store is not one (or has a schema this lwbench cannot read)."""


class WorkerError(LwbenchError):
    """An evaluation's worker process was lost: killed after the per-call timeout, or dead
    (a segfault, ``os._exit``, a native library aborting). Recorded as the evaluation's failure."""


class DataWarning(UserWarning):
    """Data that loaded, but with a guess or a skip the user should know about (a beam table
    derived from an elevation histogram, files a loader skipped)."""
