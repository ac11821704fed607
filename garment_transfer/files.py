"""Writing files whole or not at all, without ever destroying what is not ours; JSON of the core's results.

Every writer (OBJ results, model files, reports, the batch commands and scripts) goes through
``check_output`` before the work and ``atomic_path`` / ``write_atomic`` at the end:

- an output that is the same file as one of the inputs (also through a symlink or a hard link) is
  refused: a result must never replace the garment or the body it was made from;
- an existing output that is not a regular file (a symlink, a FIFO, a device, a folder) is refused:
  renaming over it would replace the special file by a regular one (``/dev/null`` run as root);
- the file is written to a temporary file in the same folder and renamed over the output, so a
  reader never sees half a file and an interrupted write leaves nothing;
- the result gets the permissions any other tool would give a new file (``0o666 & ~umask``),
  not the 0600 of a temporary file.

Messages name the user's path, never the temporary file.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import tempfile
from pathlib import Path

import numpy as np

from .errors import GarmentTransferError, NamedError


class OutputError(NamedError):
    """An output path that cannot (or must not) be written."""


def _umask() -> int:
    # os.umask can only be read by setting it; set it straight back.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_file_mode() -> int:
    """Permissions a new file gets under the current umask (``0o666 & ~umask``)."""
    return 0o666 & ~_umask()


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path, inputs=(), what="output"):
    """Raise OutputError unless ``path`` can be written without harm.

    Parameters
    ----------
    path : str or Path
        The output file.
    inputs : iterable of str or Path
        Files read by the same command; the output must be none of them.
    what : str
        The option or role of the output, for messages (``--out``).

    Returns
    -------
    str
        The path as given (``os.fspath``).
    """
    path = os.fspath(path)
    if path == "":
        raise OutputError(f"{what} ''", "is empty; give a file name to write")
    for source in inputs:
        if source is not None and _same_file(path, source):
            raise OutputError(path, f"is the input {os.fspath(source)}; refusing to overwrite an input: "
                                    f"give {what} another file name")
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise OutputError(path, f"cannot be checked ({exc.strerror or exc})") from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise OutputError(path, "is a symbolic link; refusing to replace it: give the real file's "
                                    "path or another name")
        if stat.S_ISDIR(st.st_mode):
            raise OutputError(path, f"is a folder; give {what} a file name inside it")
        if not stat.S_ISREG(st.st_mode):
            raise OutputError(path, "is not a regular file (a device, FIFO or socket); refusing to "
                                    "replace it: give another file name")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise OutputError(path, f"its folder {folder} does not exist; create it first")
    # Mode bits as well as access(): root may write anywhere, but a file or folder marked read-only
    # says its owner wants it kept.
    if not os.access(folder, os.W_OK | os.X_OK) or not os.stat(folder).st_mode & 0o222:
        raise OutputError(path, f"its folder {folder} is not writable")
    if st is not None and (not os.access(path, os.W_OK) or not st.st_mode & 0o222):
        raise OutputError(path, "exists and is read-only; remove it or give another file name")
    return path


def check_output_folder(path, what="output folder"):
    """Raise OutputError unless ``path`` is a folder or can be made one (checked before the work).

    Returns
    -------
    str
    """
    path = os.fspath(path)
    if path == "":
        raise OutputError(f"{what} ''", "is empty; give a folder name")
    if os.path.lexists(path) and not os.path.isdir(path):
        raise OutputError(path, f"is a file, not a folder; give {what} a folder for the results")
    parent = os.path.abspath(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.access(parent, os.W_OK | os.X_OK) or not os.stat(parent).st_mode & 0o222:
        raise OutputError(path, f"cannot be written: {parent} is not writable")
    return path


@contextlib.contextmanager
def atomic_path(path, inputs=(), what="output"):
    """Yield a temporary path beside ``path`` to write; it becomes ``path`` by one rename when the block
    ends, and is removed when the block fails or is interrupted.

    For writers that need a file name (Blender's saving and rendering, ``np.save``); ``write_atomic``
    for those that write to a file object. ``path`` is checked first (``check_output``).

    Raises
    ------
    OutputError
        Naming ``path``, when it must not or cannot be written.
    """
    path = check_output(path, inputs, what)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.splitext(path)[1], dir=folder)
        os.fchmod(fd, new_file_mode())
        os.close(fd)
    except OSError as exc:
        raise OutputError(path, f"cannot be written ({exc.strerror or exc})") from None
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        if isinstance(exc, GarmentTransferError):
            raise
        raise OutputError(path, f"cannot be written ({exc.strerror or exc})") from None
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


def write_atomic(path, write, inputs=(), what="output", binary=False):
    """Write a file whole or not at all.

    Parameters
    ----------
    path : str or Path
    write : callable(file object)
        Writes the content (text, UTF-8, or bytes with ``binary=True``).
    inputs, what
        See ``check_output``.
    binary : bool

    Raises
    ------
    OutputError
        Naming ``path``, when it must not or cannot be written.
    """
    with atomic_path(path, inputs, what) as tmp:
        with open(tmp, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8", "newline": ""})) as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())


def write_text_atomic(path, text, inputs=(), what="output"):
    """Write ``text`` (UTF-8) to ``path`` atomically (see ``write_atomic``).

    Bytes that were not UTF-8 in a file read with ``errors="surrogateescape"`` (an OBJ's Latin-1
    comment) are written back exactly as they were.
    """
    data = text.encode("utf-8", errors="surrogateescape")
    write_atomic(path, lambda fh: fh.write(data), inputs, what, binary=True)


def json_default(x):
    """``json.dumps(..., default=json_default)``: numpy scalars and arrays, paths."""
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def write_json_atomic(path, obj, indent=1, inputs=(), what="output"):
    """Write ``obj`` as JSON to ``path`` atomically."""
    write_text_atomic(path, json.dumps(obj, indent=indent, default=json_default) + "\n", inputs, what)
