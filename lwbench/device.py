"""Choosing a torch device: codecs that can use a GPU take a ``device`` parameter."""

from __future__ import annotations

from lwbench.errors import ParameterError
from lwbench.params import Param

__all__ = ["DEVICE_PARAM", "resolve_device"]

DEVICE_PARAM = Param("device", "str", "auto", "torch device: auto (CUDA when available), cpu, cuda, cuda:N")


def resolve_device(name: str):
    """``auto`` -> ``cuda`` when a GPU is visible, else ``cpu``; validates explicit names."""
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError as exc:
        raise ParameterError(f"device: {exc}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ParameterError("device: CUDA was requested but no GPU is visible to torch")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ParameterError(f"device: {name} requested, but torch sees {torch.cuda.device_count()} GPU(s)")
    return dev
