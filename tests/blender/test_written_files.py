"""A written garment as Blender's OBJ importer reads it: its normals and its materials.

A garment file exported with its normals (Blender's exporter writes them by default) keeps them in the result;
Blender's importer makes them the mesh's custom normals, so a normal written for the source's shape would shade
the new shape with the old one's light. The result's normals must be the new shape's own. Its material library
(``mtllib``, written beside the garment by the exporter) must still be found from the folder the result is in.
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


def selected_only(obj):
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def test_the_result_shades_as_its_own_shape(tmp_path, makehuman):
    garment = imported(makehuman / "garments" / "female_casualsuit01" / "female_average.obj")
    selected_only(garment)
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


def textured_material(folder):
    """A material whose base colour is an image texture saved in ``folder``."""
    image = bpy.data.images.new("weave", 4, 4)
    image.pixels = [0.2, 0.6, 0.9, 1.0] * 16
    image.filepath_raw = str(folder / "weave.png")
    image.file_format = "PNG"
    image.save()
    mat = bpy.data.materials.new("cotton")
    if mat.node_tree is None:      # Blender 4.x makes a material without nodes until asked
        mat.use_nodes = True
    nodes = mat.node_tree.nodes
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def material_read(path):
    """(base colour, image files) of the material of the object imported from ``path``."""
    obj = imported(path)
    mat = obj.material_slots[0].material
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    images = [bpy.path.abspath(n.image.filepath) for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
    return tuple(round(x, 3) for x in bsdf.inputs["Base Color"].default_value[:3]), images


def test_the_result_written_elsewhere_keeps_its_material_and_texture(tmp_path, makehuman):
    source = tmp_path / "garments"
    source.mkdir()
    garment = imported(makehuman / "garments" / "female_casualsuit01" / "female_average.obj")
    garment.data.materials.append(textured_material(source))
    selected_only(garment)
    exported = source / "suit.obj"
    bpy.ops.wm.obj_export(filepath=str(exported), export_selected_objects=True, export_materials=True,
                          forward_axis="NEGATIVE_Z", up_axis="Y")
    assert (source / "suit.mtl").is_file()
    as_exported = material_read(exported)
    assert as_exported[1] == [str(source / "weave.png")]

    results = tmp_path / "results" / "pear"
    results.mkdir(parents=True)
    out = results / "suit_on_pear.obj"
    assert cli(["transfer", "--source-body", str(makehuman / "bodies" / "female_average.obj"), "--target-body",
                str(makehuman / "bodies" / "female_pear.obj"), "--garment", str(exported), "--out", str(out),
                "--no-crossing-pass"]) == 0
    assert material_read(out) == as_exported

    # The library named as the garment names it is looked for beside the result, and not found.
    lines = out.read_text().splitlines()
    lines = ["mtllib suit.mtl" if ln.startswith("mtllib") else ln for ln in lines]
    (results / "as_before.obj").write_text("\n".join(lines) + "\n")
    assert material_read(results / "as_before.obj")[1] == []
