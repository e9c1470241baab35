"""Importing the heavy optional-at-startup libraries, in one place, with a clear error.

Open3D's Linux wheels link against ``libusb-1.0.so.0`` (for its RealSense support), which a
fresh Debian/Ubuntu machine does not have, so a plain ``import open3d`` fails there with
``ImportError: libusb-1.0.so.0: cannot open shared object file``. The ``libusb-package`` wheel
(a dependency of lwbench) ships that library; loading it with ``RTLD_GLOBAL`` before Open3D is
imported satisfies the dynamic linker, so ``pip install lwbench`` alone is enough -- no apt step.
A system libusb, when present, is used instead -- unless ``LWBENCH_LIBUSB=package`` asks for the
wheel's copy (a broken system library, or a test that proves the pip-only path on a machine that
has one).

Every module of lwbench and of its plugins gets Open3D through :func:`import_open3d` (never a
top-level ``import open3d``), which keeps ``lwbench list`` fast and turns a broken install into
one :class:`MissingDependencyError` that says what to do.
"""

from __future__ import annotations

import ctypes
import functools
import os
from types import ModuleType

from lwbench.errors import MissingDependencyError

__all__ = ["import_open3d", "preload_libusb"]

_SYSTEM_LIBUSB = "libusb-1.0.so.0"
_OPEN3D_HINT = "install it with `pip install open3d-cpu` (or `pip install lwbench`, which brings it)"


@functools.cache
def preload_libusb() -> str | None:
    """Make ``libusb-1.0.so.0`` loadable for Open3D; returns the library used (None if none).

    The system library wins when the dynamic linker finds one; otherwise the copy shipped by
    the ``libusb-package`` wheel is loaded into the global symbol namespace.
    """
    if os.environ.get("LWBENCH_LIBUSB", "").lower() != "package":
        try:
            ctypes.CDLL(_SYSTEM_LIBUSB, mode=ctypes.RTLD_GLOBAL)
            return _SYSTEM_LIBUSB
        except OSError:
            pass
    try:
        import libusb_package
    except ImportError:
        return None
    path = libusb_package.get_library_path()
    if path is None:
        return None
    try:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return None
    return str(path)


@functools.cache
def import_open3d() -> ModuleType:
    """The ``open3d`` module, importable on a machine without a system libusb.

    Raises :class:`MissingDependencyError` (one line: why, and what to install) instead of the
    linker's ``ImportError``.
    """
    libusb = preload_libusb()
    try:
        import open3d
    except ImportError as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        hint = _OPEN3D_HINT
        if "libusb" in reason and libusb is None:
            hint = "install `pip install libusb-package` (or the system package libusb-1.0-0)"
        raise MissingDependencyError(f"Open3D cannot be imported ({reason}); {hint}") from None
    return open3d
