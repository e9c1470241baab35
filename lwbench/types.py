"""Compatibility: the frame model moved to :mod:`lwbench.frame`, parameters to :mod:`lwbench.params`."""

from lwbench.errors import InvalidFrameError, LwbenchError, ParameterError
from lwbench.frame import Frame
from lwbench.params import Param, resolve_params

__all__ = ["Frame", "Param", "LwbenchError", "InvalidFrameError", "ParameterError", "resolve_params"]
