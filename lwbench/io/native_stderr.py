"""What C++ libraries (Open3D, VTK) print to file descriptor 2, collected instead of shown."""

from __future__ import annotations

import contextlib
import os
import re
import tempfile

__all__ = ["captured_stderr"]


@contextlib.contextmanager
def captured_stderr():
    """Collect what C++ code writes to file descriptor 2 (Open3D's errors) instead of letting
    it reach the terminal; yields a list that holds the text, one line, once the block ends."""
    said: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no stderr to redirect
        yield said
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield said
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = re.sub(r"\x1b\[[0-9;]*m", "", tmp.read(4000).decode(errors="replace"))
            said.append(" ".join(text.split())[:300])
