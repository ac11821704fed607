"""Writing files whole or not at all, without ever destroying what is not ours; JSON of the core's results.

Every writer (OBJ results, model files, reports, the batch commands and scripts) goes through
``check_outputs`` (or ``check_output`` for one file) before the work and ``atomic_path`` /
``write_atomic`` at the end:

- a command declares what it reads (files, and folders such as a dataset's ``bodies/``) and what it
  writes (files, and folders it fills); an output that is an input, lies inside an input folder, or
  is an output folder holding an input is refused, however it is spelled (``..``, a symlink, a hard
  link, another case where the file system folds case): paths are compared by the file system's
  identity of what they reach (device and inode), not by their text;
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


def _identity(path):
    """``(device, inode)`` of what ``path`` reaches (links followed), or None where nothing is."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _as_given(path):
    # Joined to the working folder without normalising: "link/../x" must go where the system takes it.
    return os.path.join(os.getcwd(), os.fspath(path))


class _Reads:
    """What a command reads, by identity (device and inode): its input files and input folders.

    Folders are looked up once per check (``_chain``): a catalogue's thousands of results share a few
    hundred folders.
    """

    def __init__(self, inputs=(), input_folders=()):
        self.files = [os.fspath(p) for p in inputs if p is not None]
        self.folders = [os.fspath(p) for p in input_folders if p is not None]
        self.file_ids = {i: p for p in self.files if (i := _identity(p)) is not None}
        self.folder_ids = {i: p for p in self.folders if (i := _identity(p)) is not None}
        self._ids, self._chains, self._real, self._inside = {}, {}, {}, None

    def _chain(self, folder):
        """Identities of the real place of ``folder`` (where it exists) and of every existing folder above it.

        The real place has its symlinks resolved, and a ``..`` after a folder that does not exist yet taken
        as a folder maker takes it; identities, not names, are compared, so a spelling in another case on a
        case-folding file system reaches the same folder.
        """
        if folder not in self._chains:
            p, chain = os.path.realpath(folder), []
            while True:
                if p not in self._ids:
                    self._ids[p] = _identity(p)
                if self._ids[p] is not None:
                    chain.append(self._ids[p])
                parent = os.path.dirname(p)
                if parent == p:
                    break
                p = parent
            self._chains[folder] = chain
        return self._chains[folder]

    def real_folder(self, path):
        """The real place of the folder ``path`` is named in (looked up once per folder)."""
        folder = os.path.dirname(_as_given(path))
        if folder not in self._real:
            self._real[folder] = os.path.realpath(folder)
        return self._real[folder]

    def places(self, path):
        """Identities of the folders ``path`` lies in: those of its name, and of the file a link leads to."""
        chain = self._chain(os.path.dirname(_as_given(path)))
        if os.path.islink(path):
            chain = chain + self._chain(os.path.dirname(os.path.realpath(path)))
        return chain

    def inside(self):
        """``{identity: path}`` of every file in the input folders (links followed: a dataset of links to
        files elsewhere reads those files). Listed once, and only when an existing output needs it."""
        if self._inside is None:
            self._inside, seen = {}, set()
            for top in self.folders:
                for root, dirs, names in os.walk(top, followlinks=True):
                    here = _identity(root)
                    if here in seen:
                        dirs[:] = []
                        continue
                    seen.add(here)
                    for name in names:
                        p = os.path.join(root, name)
                        if (i := _identity(p)) is not None:
                            self._inside.setdefault(i, p)
        return self._inside

    def objection(self, path, what, folder=False):
        """Why the output ``path`` would harm an input (one phrase), or None."""
        ident = _identity(path)
        if ident in self.file_ids:
            return (f"is the input {self.file_ids[ident]}; refusing to overwrite an input: give {what} "
                    f"another {'folder' if folder else 'file name'}")
        if ident is not None and self.folders and not folder and ident in self.inside():
            return (f"is the input {self.inside()[ident]} (read from the input folder it is in); refusing to "
                    f"overwrite an input: give {what} another file name")
        if ident in self.folder_ids:
            return (f"is the input folder {self.folder_ids[ident]}, which this command reads; give {what} "
                    "a place outside it")
        for above in self.places(path):
            if above in self.folder_ids:
                return (f"lies inside the input folder {self.folder_ids[above]}, which this command reads; "
                        f"give {what} a place outside it")
        return None

    def held_by(self, folder):
        """The first input that lies inside ``folder`` (an existing folder), or None."""
        ident = _identity(folder)
        if ident is None:
            return None
        for p in self.files + self.folders:
            if ident in self.places(p):
                return p
        return None


def check_outputs(files=(), folders=(), *, inputs=(), input_folders=(), holds_none=False, what="--out"):
    """Raise OutputError unless every output of a command can be written without harm to its inputs.

    The one check every command makes before its work: it compares what the command will write with
    everything it reads, then checks each output's own place (see ``check_output`` and
    ``check_output_folder``).

    Parameters
    ----------
    files : iterable of str or Path, or of (path, option)
        Output files. Each must not be an input file or input folder, nor lie inside an input folder. Its
        folder must exist, unless it is (or lies inside) one of ``folders``, which the command makes.
        An ``(path, option)`` pair is an output of another option than ``what`` (``--log``).
    folders : iterable of str or Path
        Output folders, made when missing. Each must not be an input, nor lie inside an input folder.
    inputs : iterable of str or Path
        Files the command reads (None entries are ignored).
    input_folders : iterable of str or Path
        Folders the command reads whole (a dataset's ``bodies/`` and ``garments/``).
    holds_none : bool
        The ``folders`` are filled with names of the command's own making (a catalogue's garments as
        sub-folders): each must also hold no input at all.
    what : str
        The option of the outputs, for messages (``--out``).

    Raises
    ------
    OutputError
        One line naming the output as given and what is wrong.
    """
    reads = _Reads(inputs, input_folders)
    folders = [os.fspath(f) for f in folders]
    for folder in folders:
        if folder == "":
            raise OutputError(f"{what} ''", "is empty; give a folder name")
        problem = reads.objection(folder, what, folder=True)
        if problem is None and holds_none:
            held = reads.held_by(folder)
            if held is not None:
                problem = (f"holds the input {held}; give {what} a folder that holds none of the inputs "
                           "(a new folder beside them)")
        if problem:
            raise OutputError(folder, problem)
        check_output_folder(folder, what)
    made = [os.path.realpath(f) for f in folders]
    for path in files:
        path, option = path if isinstance(path, tuple) else (path, what)
        path = os.fspath(path)
        folder = reads.real_folder(path)
        will_exist = any(folder == m or folder.startswith(m.rstrip(os.sep) + os.sep) for m in made)
        _check_file(path, reads, option, folder_made=will_exist)


def check_output(path, inputs=(), what="output", input_folders=()):
    """Raise OutputError unless ``path`` can be written without harm.

    Parameters
    ----------
    path : str or Path
        The output file.
    inputs : iterable of str or Path
        Files read by the same command; the output must be none of them.
    what : str
        The option or role of the output, for messages (``--out``).
    input_folders : iterable of str or Path
        Folders read by the same command; the output must not lie inside one.

    Returns
    -------
    str
        The path as given (``os.fspath``).
    """
    path = os.fspath(path)
    _check_file(path, _Reads(inputs, input_folders), what)
    return path


def _check_file(path, reads, what, folder_made=False):
    if path == "":
        raise OutputError(f"{what} ''", "is empty; give a file name to write")
    problem = reads.objection(path, what)
    if problem:
        raise OutputError(path, problem)
    try:
        st = os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
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
    # The folder as the system reaches it ("new/.." fails where "new" is missing, as the write would); the
    # messages show the path as the user wrote it.
    real, folder = reads.real_folder(path), os.path.dirname(os.path.abspath(path))
    if folder_made and not os.path.lexists(real):
        return
    if not os.path.isdir(os.path.dirname(_as_given(path))):
        if os.path.isfile(real):
            raise OutputError(path, f"its folder {folder} is a file, not a folder")
        raise OutputError(path, f"its folder {folder} does not exist; create it first")
    # Mode bits as well as access(): root may write anywhere, but a file or folder marked read-only
    # says its owner wants it kept.
    if not os.access(real, os.W_OK | os.X_OK) or not os.stat(real).st_mode & 0o222:
        raise OutputError(path, f"its folder {folder} is not writable")
    if st is not None and (not os.access(path, os.W_OK) or not st.st_mode & 0o222):
        raise OutputError(path, "exists and is read-only; remove it or give another file name")


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
    parent = os.path.realpath(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise OutputError(path, f"cannot be made: {parent} is a file, not a folder")
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
    # Beside the file the rename replaces: the real folder, where ".." or a linked folder leads.
    folder = os.path.dirname(os.path.realpath(path))
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
