"""The normals of a written garment, as Blender's OBJ importer reads them.

A garment file exported with its normals (Blender's exporter writes them by default) keeps them in the result;
Blender's importer makes them the mesh's custom normals, so a normal written for the source's shape would shade
the new shape with the old one's light. The result's normals must be the new shape's own.
"""

from __future__ import annotations

import bpy
import numpy as np

from garment_transfer.cli import main as cli


def imported(path):
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=str(path), forward_axis="NEGATIVE_Z", up_axis="Y", use_split_objects=False,
                          use_split_groups=False)
    (obj,) = [o for o in bpy.data.objects if o not in before]
    return obj


def corner_normals(obj):
    me = obj.data
    out = np.zeros(3 * len(me.loops))
    me.corner_normals.foreach_get("vector", out)
    return out.reshape(-1, 3)


def angles_to_own_normals(path):
    """Degrees between each corner's normal as imported from ``path`` and Blender's own normal of that shape."""
    obj = imported(path)
    assert obj.data.has_custom_normals
    read = corner_normals(obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.mesh.customdata_custom_splitnormals_clear()
    own = corner_normals(obj)
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", read, own), -1.0, 1.0)))


def test_the_result_shades_as_its_own_shape(tmp_path, makehuman):
    garment = imported(makehuman / "garments" / "female_casualsuit01" / "female_average.obj")
    bpy.ops.object.select_all(action="DESELECT")
    garment.select_set(True)
    bpy.context.view_layer.objects.active = garment
    bpy.ops.object.shade_smooth()
    exported = tmp_path / "suit_with_normals.obj"
    bpy.ops.wm.obj_export(filepath=str(exported), export_selected_objects=True, export_normals=True,
                          export_materials=False, forward_axis="NEGATIVE_Z", up_axis="Y")
    assert sum(line.startswith("vn ") for line in exported.read_text().splitlines()) > 1000
    assert angles_to_own_normals(exported).max() < 0.1      # Blender's own normals, written to 4 decimals

    out = tmp_path / "suit_on_pear.obj"
    assert cli(["transfer", "--source-body", str(makehuman / "bodies" / "female_average.obj"), "--target-body",
                str(makehuman / "bodies" / "female_pear.obj"), "--garment", str(exported), "--out", str(out)]) == 0
    assert angles_to_own_normals(out).max() < 0.1

    # The same file with the source's normals, as written before, shades the new shape wrongly.
    source = [ln for ln in exported.read_text().splitlines() if ln.startswith("vn ")]
    lines = out.read_text().splitlines()
    at = [i for i, ln in enumerate(lines) if ln.startswith("vn ")]
    for i, ln in zip(at, source):
        lines[i] = ln
    stale = tmp_path / "stale_normals.obj"
    stale.write_text("\n".join(lines) + "\n")
    assert angles_to_own_normals(stale).max() > 30
