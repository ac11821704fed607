"""Model files loaded once and kept while the file is unchanged (the panel lists their targets)."""

from __future__ import annotations

import os

import bpy

_cache = {}


def model_file_path(path):
    """Absolute path of a model path as typed in Blender ("//" is relative to the .blend file)."""
    return os.path.abspath(bpy.path.abspath(path)) if path else ""


def load_model_cached(path):
    """The model file in ``path``, of any kind (``model_files.ModelFile``); loaded again only when the file
    changed.

    Raises
    ------
    ModelError
        From the core: missing, unreadable or corrupt file, or a kind this version does not read.
    """
    from ..garment_transfer import read_model_file

    path = model_file_path(path)
    try:
        st = os.stat(path)
        key = (path, st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    if key is not None and key in _cache:
        return _cache[key]
    model = read_model_file(path)
    if key is not None:
        _cache.clear()
        _cache[key] = model
    return model


def clear_cache():
    _cache.clear()
