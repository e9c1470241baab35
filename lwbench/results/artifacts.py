"""Arrays beside the results store -- decoded clouds and the originals a report shows -- as files.

A decoded KITTI-sequence configuration is gigabytes of clouds; in the SQLite file they made every
store slow to copy, back up and vacuum. They live beside it instead
(``results.sqlite`` -> ``results.clouds/ab/abcdef....lwbc``), and a store row keeps only the name:

- **content-addressed**: a file is named by the SHA-256 of its array (dtype, shape, bytes), so
  the same cloud -- raw's lossless decode of a frame, scored again with another metric version --
  is one file, written once, and a name always means the same array;
- **compressed**: the array's bytes are *shuffled* (byte planes: every float's first byte, then
  every second byte ...) and zstd-compressed: 0.76 of the raw size for a KITTI scan's float32
  x,y,z where plain zstd gets 0.92 (1,122,140 B -> 856,832 vs 1,030,613 B, 1 ms);
- **safe to read**: a small header (magic, JSON dtype and shape) says what to expect, only
  numeric dtypes are accepted, and the body must inflate to exactly that size (no pickle, no
  unbounded allocation); files are written to a temporary name and renamed, so a killed run
  leaves no half file under a real name.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import tempfile
from pathlib import Path

import numpy as np

from lwbench.errors import StoreError

__all__ = ["CloudFiles", "pack_array", "unpack_array"]

_MAGIC = b"LWBC"
_HEAD = struct.Struct("<4sBH")  # magic, format version, header JSON length
_VERSION = 1
_KINDS = "fiub"  # numeric dtypes only
_SUFFIX = ".lwbc"


def _describe(array: np.ndarray) -> bytes:
    if array.dtype.kind not in _KINDS or array.dtype.hasobject:
        raise ValueError(f"only numeric arrays are kept beside the store, got {array.dtype}")
    return json.dumps({"dtype": array.dtype.str, "shape": list(array.shape)}, separators=(",", ":")).encode()


def _shuffled(array: np.ndarray) -> bytes:
    size = array.dtype.itemsize
    return np.ascontiguousarray(array).view(np.uint8).reshape(-1, size).T.tobytes()


def digest_of(array: np.ndarray) -> str:
    """The name an array's file gets: SHA-256 of its dtype, shape and bytes."""
    array = np.ascontiguousarray(array)
    return hashlib.sha256(_describe(array) + array.tobytes()).hexdigest()


def pack_array(array: np.ndarray) -> bytes:
    """An array as a ``.lwbc`` file's bytes (see the module docstring)."""
    import zstandard

    array = np.ascontiguousarray(array)
    head = _describe(array)
    body = zstandard.ZstdCompressor(level=1).compress(_shuffled(array))
    return _HEAD.pack(_MAGIC, _VERSION, len(head)) + head + body


def unpack_array(data: bytes, where: str = "array file") -> np.ndarray:
    """Inverse of :func:`pack_array`; :class:`StoreError` for anything that is not such a file."""
    from lwbench.errors import PayloadError
    from lwbench.limits import MAX_INFLATED_BYTES, zstd_decompress

    try:
        magic, version, n = _HEAD.unpack_from(data, 0)
        if magic != _MAGIC or version != _VERSION:
            raise ValueError("not an lwbench array file")
        head = json.loads(data[_HEAD.size:_HEAD.size + n])
        dtype, shape = np.dtype(head["dtype"]), tuple(int(s) for s in head["shape"])
        if dtype.kind not in _KINDS or dtype.hasobject or any(s < 0 for s in shape):
            raise ValueError(f"dtype {dtype} shape {shape}")
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if size > MAX_INFLATED_BYTES:
            raise ValueError(f"{size} bytes is more than an array file may hold")
        raw = zstd_decompress(data[_HEAD.size + n:], size, where, exact=True) if size else b""
    except (struct.error, ValueError, TypeError, KeyError, PayloadError) as exc:
        raise StoreError(f"{where} is damaged ({exc})") from None
    planes = np.frombuffer(raw, dtype=np.uint8).reshape(dtype.itemsize, -1)
    return np.ascontiguousarray(planes.T).view(dtype).reshape(shape)


class CloudFiles:
    """The folder of array files beside one store (created on the first write)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)

    @classmethod
    def beside(cls, store_path: Path) -> CloudFiles:
        """``results.sqlite`` -> ``results.clouds/``."""
        return cls(store_path.with_name(store_path.stem + ".clouds"))

    def path(self, digest: str) -> Path:
        return self.folder / digest[:2] / f"{digest}{_SUFFIX}"

    def put(self, array: np.ndarray) -> str:
        """Store ``array`` (once: an existing file of that content is kept); returns its name."""
        digest = digest_of(array)
        path = self.path(digest)
        if path.is_file():
            return digest
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=_SUFFIX)
            with os.fdopen(fd, "wb") as fh:
                fh.write(pack_array(array))
            os.replace(tmp, path)
        except OSError as exc:
            raise StoreError(f"cannot write {path} beside the results store: {exc}") from None
        return digest

    def get(self, digest: str) -> np.ndarray | None:
        """The array of that name, or ``None`` when its file is missing (moved without the folder)."""
        path = self.path(digest)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise StoreError(f"cannot read {path}: {exc}") from None
        array = unpack_array(data, str(path))
        if digest_of(array) != digest:
            raise StoreError(f"{path} does not hold the array its name says (edited or damaged)")
        return array
