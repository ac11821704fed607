"""The registration cache: fits kept per (source, target, settings) as plain ``.npz`` files.

The folder is ``cache_folder()``: ``$GARMENT_TRANSFER_CACHE``, or
``$XDG_CACHE_HOME/garment_transfer/registration`` (``~/.cache/...``); ``GARMENT_TRANSFER_CACHE=off``
turns it off. Files are read with ``allow_pickle=False``; a file that cannot be read is ignored (the
fit is made again), and one that cannot be written only costs the next run the fit again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile

import numpy as np

from ..geometry.mesh import Mesh

log = logging.getLogger(__name__)


def cache_folder():
    """The registration cache folder, or None when caching is turned off.

    ``$GARMENT_TRANSFER_CACHE`` (``off``, ``0`` or ``none`` turn it off), else
    ``$XDG_CACHE_HOME/garment_transfer/registration``, else ``~/.cache/garment_transfer/registration``.
    """
    env = os.environ.get("GARMENT_TRANSFER_CACHE")
    if env is not None:
        if env.strip().lower() in ("", "off", "0", "none", "false", "no"):
            return None
        return env
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "garment_transfer", "registration")


def _mesh_digest(mesh: Mesh, h):
    h.update(np.ascontiguousarray(mesh.V, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.F, dtype=np.int64).tobytes())


def cache_key(source: Mesh, target: Mesh, settings: dict, version: int) -> str:
    """Content hash of both bodies (positions and faces), the settings and the algorithm's version."""
    h = hashlib.sha256()
    h.update(f"registration v{version}".encode())
    _mesh_digest(source, h)
    h.update(b"|")
    _mesh_digest(target, h)
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:32]


def load_cached(folder, key):
    """``(arrays, meta)`` of the entry ``key`` in ``folder``: a dict of arrays and the JSON metadata;
    None when there is none or it cannot be read."""
    path = os.path.join(folder, f"{key}.npz")
    if not os.path.isfile(path):
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: np.asarray(z[name]) for name in z.files if name != "meta"}
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, KeyError) as exc:
        log.warning("ignoring unreadable registration cache file %s (%s)", path, exc)
        return None
    return arrays, meta


def save_cached(folder, key, arrays: dict, meta: dict):
    """Write the entry ``key`` (arrays and JSON metadata) whole, by a rename; a failure is logged."""
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=folder)
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
        os.replace(tmp, os.path.join(folder, f"{key}.npz"))
    except OSError as exc:
        # A read-only or full disk only costs the next run the fit again.
        log.warning("could not write the registration cache in %s (%s)", folder, exc)
