"""Model files loaded once and kept while the file is unchanged (the panel lists their targets), and the model
file trained for the scene's source body, found where the user keeps it."""

from __future__ import annotations

import glob
import os
from collections import OrderedDict

import bpy

#: Model files kept loaded (the one in use, and the few the search for a source body's model reads).
CACHE_SIZE = 8
#: The most model files beside the .blend file that the search reads (the newest first).
MAX_BESIDE = 8

_cache = OrderedDict()


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
        _cache.move_to_end(key)
        return _cache[key]
    model = read_model_file(path)
    if key is not None:
        for old in [k for k in _cache if k[0] == path]:
            del _cache[old]
        _cache[key] = model
        while len(_cache) > CACHE_SIZE:
            _cache.popitem(last=False)
    return model


def clear_cache():
    _cache.clear()


def model_candidates(last_trained=""):
    """Where a user keeps the model file of a scene: the last one trained here, then the ``.npz`` files beside
    the saved .blend file (at most ``MAX_BESIDE``, the newest first). Absolute paths of existing files."""
    found = []
    last = model_file_path(last_trained)
    if last and os.path.isfile(last):
        found.append(last)
    if bpy.data.filepath:
        beside = glob.glob(os.path.join(glob.escape(os.path.dirname(bpy.data.filepath)), "*.npz"))
        beside = sorted((p for p in beside if os.path.isfile(p)), key=os.path.getmtime, reverse=True)
        found += [os.path.abspath(p) for p in beside[:MAX_BESIDE] if os.path.abspath(p) not in found]
    return found


def find_model_for(source, candidates):
    """The first model file of ``candidates`` trained for the source body ``source`` (a core Mesh), a garment
    fit model before the paper's shared model: (path, ``ModelFile``), or (None, None). Files that cannot be
    read or were trained on another body are passed over."""
    from ..garment_transfer import GarmentTransferError

    fitting = []
    for path in candidates:
        try:
            model = load_model_cached(path)
            model.check_source_body(source)
        except GarmentTransferError:
            continue
        fitting.append((path, model))
    for path, model in fitting:
        if model.kind == "garment":
            return path, model
    return fitting[0] if fitting else (None, None)


def found_model_text(path, model, source_name):
    """One line offering a found model file for the source body ``source_name``."""
    what = ("garment fit model" + (" + placement" if model.has_placement else "") if model.kind == "garment"
            else "shared deformation model")
    return f"{os.path.basename(path)}: {what} for {source_name}"


def refresh_found_model(settings, context):
    """Look for the model file trained for the scene's source body (``model_candidates``) and offer it: set
    ``found_model`` (its path) and ``found_model_text`` (one line), both empty when there is none. Returns the
    path or ""."""
    from ..garment_transfer import GarmentTransferError
    from .convert import core_mesh_from_object

    settings.found_model = ""
    settings.found_model_text = ""
    body = settings.source_body
    candidates = model_candidates(settings.last_trained_model)
    if body is None or not candidates:
        return ""
    try:
        source = core_mesh_from_object(body, context.evaluated_depsgraph_get(), settings.use_evaluated,
                                       "source body")
    except GarmentTransferError:
        # The transfer says what is wrong with the source body; an offer is no place for it.
        return ""
    path, model = find_model_for(source, candidates)
    if path:
        settings.found_model = path
        settings.found_model_text = found_model_text(path, model, body.name)
    return path or ""


def use_found_model(settings):
    """Choose the found model file (``refresh_found_model``) as the Model method's file."""
    settings.model_path = settings.found_model
    settings.method = 'MODEL'


class GARMENT_TRANSFER_OT_find_model(bpy.types.Operator):
    """Use the model file trained for the source body: the last one trained in this scene, else a model file
    beside the saved .blend file (a garment fit model first, the newest first)"""

    bl_idname = "garment_transfer.find_model"
    bl_label = "Find Model"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        settings = getattr(context.scene, "garment_transfer", None)
        if settings is None or settings.source_body is None:
            cls.poll_message_set("Choose the source body first: a model serves the body it was trained on")
            return False
        return True

    def execute(self, context):
        settings = context.scene.garment_transfer
        if not refresh_found_model(settings, context):
            where = ("beside the .blend file" if bpy.data.filepath else "beside the .blend file (not saved yet)")
            self.report({'WARNING'}, f"No model file trained for {settings.source_body.name} found (the last one "
                                     f"trained here, then {where}); train one in the Training panel")
            return {'CANCELLED'}
        use_found_model(settings)
        self.report({'INFO'}, f"Using {settings.found_model_text} ({settings.found_model})")
        return {'FINISHED'}


CLASSES = (GARMENT_TRANSFER_OT_find_model,)
