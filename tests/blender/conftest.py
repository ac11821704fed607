"""Fixtures for the Blender layer, with the real bpy module.

The add-on is registered once per session from this checkout (tools/extension_loader.py, with the
installed core as its core: one garment_transfer in the process); every
test starts from an empty factory scene. The MakeHuman fixtures are imported as Blender objects the
way a user would (decimetres, Y up: scaled by 0.1 and turned Z up on import).
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from lab.paths import SHARED_MAKEHUMAN, makehuman_folder

ROOT = Path(__file__).resolve().parents[2]
MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN
GARMENT = "female_sportsuit01"

sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT / "scripts"))


def pytest_collection_modifyitems(config, items):
    here = Path(__file__).resolve().parent
    for item in items:
        if here in Path(item.path).resolve().parents:
            item.add_marker(pytest.mark.blender)


@pytest.fixture(scope="session")
def extension():
    from extension_loader import load_extension

    ext = load_extension()
    ext.register()
    yield ext
    ext.unregister()


@pytest.fixture(autouse=True)
def empty_scene(extension):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


@pytest.fixture
def makehuman():
    if not MAKEHUMAN.is_dir():
        pytest.skip(f"MakeHuman fixtures not found at {MAKEHUMAN}")
    return MAKEHUMAN


def import_obj(path, name):
    """Import an OBJ file in decimetres, Y up, as one mesh object called ``name``."""
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=str(path), global_scale=0.1, use_split_objects=False,
                          use_split_groups=False)
    (obj,) = [o for o in bpy.data.objects if o not in before]
    obj.name = name
    obj.data.name = name
    return obj


def decorate_garment(obj):
    """Give a garment what a production garment has and a transfer must keep: a UV map, vertex
    groups, two materials, seams and sharp edges."""
    me = obj.data
    n_loops = len(me.loops)
    uv = me.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", np.random.default_rng(0).random(2 * n_loops).astype(np.float32))
    n = len(me.vertices)
    waist = obj.vertex_groups.new(name="waist")
    waist.add(list(range(0, n, 3)), 0.75, 'REPLACE')
    pin = obj.vertex_groups.new(name="pin")
    pin.add(list(range(0, n, 7)), 1.0, 'REPLACE')
    for name in ("fabric", "trim"):
        me.materials.append(bpy.data.materials.new(name))
    me.polygons.foreach_set("material_index", (np.arange(len(me.polygons)) % 2).astype(np.int32))
    seams = np.zeros(len(me.edges), dtype=bool)
    seams[::11] = True
    me.edges.foreach_set("use_seam", seams)
    sharp = np.zeros(len(me.edges), dtype=bool)
    sharp[5::13] = True
    me.edges.foreach_set("use_edge_sharp", sharp)
    me.update()
    return obj


@pytest.fixture
def dressed(makehuman):
    """Source body (female_average), target body (female_pear), a decorated garment on the source
    and the same garment fitted on the target (the reference), chosen in the Garment tab."""
    source = import_obj(makehuman / "bodies" / "female_average.obj", "average")
    target = import_obj(makehuman / "bodies" / "female_pear.obj", "pear")
    garment = decorate_garment(import_obj(makehuman / "garments" / GARMENT / "female_average.obj",
                                          "sportsuit"))
    settings = bpy.context.scene.garment_transfer
    settings.source_body = source
    settings.target_body = target
    settings.garment = garment
    return SimpleNamespace(source=source, target=target, garment=garment, settings=settings,
                           makehuman=makehuman)


def world_vertices(obj):
    """(n,3) world positions of an object's base mesh."""
    me = obj.data
    co = np.empty(3 * len(me.vertices), dtype=np.float32)
    me.vertices.foreach_get("co", co)
    M = np.array(obj.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def scene_state():
    """Everything a failed or read-only operator must leave as it was: the objects and meshes, their
    vertices, transforms, modifiers and attributes."""
    state = {"collections": {c.name: sorted(o.name for o in c.objects) for c in bpy.data.collections},
             "scene_objects": sorted(o.name for o in bpy.context.scene.collection.objects)}
    for obj in bpy.data.objects:
        entry = {"matrix": np.array(obj.matrix_world).round(9).tolist(),
                 "modifiers": [m.name for m in obj.modifiers],
                 "groups": [g.name for g in obj.vertex_groups], "data": obj.data.name if obj.data else None}
        if obj.type == 'MESH':
            me = obj.data
            co = np.empty(3 * len(me.vertices), dtype=np.float32)
            me.vertices.foreach_get("co", co)
            entry["co"] = co.tobytes()
            entry["attributes"] = sorted(a.name for a in me.attributes)
            entry["shape_keys"] = ([k.name for k in me.shape_keys.key_blocks] if me.shape_keys else [])
        state[f"object:{obj.name}"] = entry
    state["meshes"] = sorted(m.name for m in bpy.data.meshes)
    return state
