"""The dataset interface: an indexable sequence of frames, optionally with ground-truth poses."""

from __future__ import annotations

import abc
import hashlib
import json
from pathlib import Path
from typing import Any, ClassVar

from lwbench.frame import Frame
from lwbench.params import Param, resolve_params

__all__ = ["Dataset"]


class Dataset(abc.ABC):
    """A sequence of frames.

    Loaders follow one pattern (one small class per source): ``__init__`` resolves the declared
    parameters into ``self.config`` and reads only what it needs to know the length; frames are
    read lazily by :meth:`frame`, so a 10,000-scan folder costs nothing until it is iterated.
    Loaders that read a path declare a ``path`` parameter and implement :meth:`sniff` so that
    ``lwbench run --dataset PATH`` can pick them automatically.
    """

    name: ClassVar[str]
    description: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    # The dataset ``lwbench run`` uses when none is named (the built-in simulator: no download).
    is_default: ClassVar[bool] = False

    def __init__(self, **params: Any) -> None:
        self.config: dict[str, Any] = resolve_params(self.name, self.params, params)

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def frame(self, index: int) -> Frame:
        """Frame ``index`` (0-based); raises ``IndexError`` past the end."""

    @property
    @abc.abstractmethod
    def has_poses(self) -> bool:
        """Whether frames carry ground-truth poses (sequence metrics need them)."""

    def why_no_poses(self) -> str:
        """Said when a run skips the sequence metrics because :attr:`has_poses` is false: where
        the poses would have come from (a loader names its pose files). Default: a generic line."""
        return f"{self.name} gives no ground-truth poses"

    @property
    def sensor_guessed(self) -> bool:
        """Whether the dataset's sensor model is a guess (derived without ring labels, a preset
        snapped to by the elevation histogram): every row scored on it carries the board flag
        ``sensor guessed``, because the range metrics stand on that beam table. Default: no (a
        simulator's or a named sensor is exact); the file and bag loaders say when they guessed."""
        return False

    def traversals(self) -> list[list[int]]:
        """Frame indices of each separate drive through the same place (default: one drive, every
        frame). A dataset with two -- a mapping drive and a later tracking drive -- lets the
        localization metric build its map from one and track the other, as a robot relocalizing
        in a map made on another day does."""
        return [list(range(len(self)))]

    def pose(self, index: int):
        """Ground-truth pose (sensor -> world, 4x4) of frame ``index``, or ``None``. Sequence
        metrics read every pose before any scan: a loader that knows its poses without reading the
        scan (a poses file, a simulator's path) overrides this; the default reads the frame."""
        return self[index].pose

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"{self.name}: frame {index} out of range (0..{len(self) - 1})")
        return self.frame(index % len(self))

    def __iter__(self):
        for i in range(len(self)):
            yield self.frame(i)

    def frame_origin(self, index: int) -> dict[str, Any]:
        """Where frame ``index`` came from, for files written from it (``lwbench encode`` /
        ``decode``): ``name`` (a readable file stem) and, where the source has them, ``stamp_ns``,
        ``log_ns``, ``topic`` and ``frame_id`` (ROS bags), so decoded clouds keep their names,
        topics and stamps. Cheap: it reads no scan."""
        return {"name": f"{index:06d}"}

    @classmethod
    def sniff(cls, path: Path) -> bool:
        """Whether this loader can read ``path`` (only loaders with a ``path`` parameter)."""
        return False

    @classmethod
    def describe(cls) -> dict:
        return {
            "name": cls.name,
            "description": cls.description,
            "params": [p.describe() for p in cls.params],
        }

    def identity(self) -> str:
        """A stable description of *what data* this is, stored with every result row.

        The default hashes the parameters plus, for path datasets, each file's name, size and
        mtime, so that changed data on disk is never a cache hit.
        """
        h = hashlib.sha256(json.dumps(self.config, sort_keys=True, default=str).encode())
        path = self.config.get("path")
        if path:
            p = Path(path)
            files = sorted(p.rglob("*")) if p.is_dir() else [p]
            for f in files:
                if f.is_file():
                    st = f.stat()
                    h.update(f"{f.relative_to(p) if p.is_dir() else f.name}:{st.st_size}:{int(st.st_mtime)}".encode())
        return f"{self.name}:{h.hexdigest()[:16]}"
