"""Writing files so that nothing is ever half-written, and JSON of the core's results.

Every file the project writes goes through ``atomic_path``: the content is written to a temporary file
in the target's folder and renamed over the target once complete, so an interruption, a full disk or an
error leaves either the old file or the new one, never a mix.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from .errors import NamedError


class OutputError(NamedError):
    """An output path that cannot be written as asked."""


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; it becomes ``path`` by one rename when the block ends.

    The temporary file is removed when the block fails or is interrupted.

    Raises
    ------
    OutputError
        When the folder of ``path`` does not exist.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise OutputError(path, f"the folder {folder} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.splitext(path)[1], dir=folder)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_text_atomic(path, text):
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)


def json_default(x):
    """``json.dumps(..., default=json_default)``: numpy scalars and arrays, paths."""
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def write_json_atomic(path, obj, indent=1):
    """Write ``obj`` as JSON to ``path`` atomically."""
    write_text_atomic(path, json.dumps(obj, indent=indent, default=json_default) + "\n")
