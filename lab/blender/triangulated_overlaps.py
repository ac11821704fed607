"""An independent check of written results: Blender's own triangulations and Blender's own overlap test.

For each (result, target body) pair of OBJ files, both are imported with Blender's OBJ importer, each is
triangulated with ``bmesh.ops.triangulate`` in several of Blender's quad methods (BEAUTY, what the Triangulate
modifier and the renderers do; FIXED and ALTERNATE, the two diagonals; SHORT_EDGE), and every pair of
triangulations is tested with ``mathutils.bvhtree.BVHTree.overlap`` (Blender's floating-point triangle-triangle
test, not the project's exact predicates). Reported per pair: the overlapping triangle pairs of the worst pair of
triangulations and which they were, and the result's own overlapping triangle pairs (sharing no vertex) under
its worst triangulation, beside the same for its source garment.

With the bpy module::

    .venv/bin/python -m lab.blender.triangulated_overlaps --pairs PAIRS.json --out OUT.json

``PAIRS.json`` is a list of ``{"name", "result", "body", "source"}`` (paths); ``OUT.json`` gets one record per
pair. Exit code 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import bpy  # noqa: I001  (first: under the bpy module, bmesh and mathutils come with it)
import bmesh
from mathutils.bvhtree import BVHTree

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

METHODS = ("BEAUTY", "FIXED", "ALTERNATE", "SHORT_EDGE")


def load(path):
    """A bmesh of an OBJ file as Blender imports it (no axis change: both files of a pair alike)."""
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=str(path), forward_axis="NEGATIVE_Z", up_axis="Y", use_split_objects=False,
                          use_split_groups=False)
    (obj,) = [o for o in bpy.data.objects if o not in before]
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.transform(obj.matrix_world)
    me = obj.data
    bpy.data.objects.remove(obj)
    bpy.data.meshes.remove(me)
    return bm


def triangulated(bm, method):
    """(BVHTree, triangles as vertex index triples) of a copy of ``bm`` triangulated with a quad method."""
    t = bm.copy()
    bmesh.ops.triangulate(t, faces=t.faces[:], quad_method=method, ngon_method="BEAUTY")
    t.verts.ensure_lookup_table()
    t.faces.ensure_lookup_table()
    tris = [tuple(v.index for v in f.verts) for f in t.faces]
    tree = BVHTree.FromBMesh(t)
    t.free()
    return tree, tris


def self_overlaps(tree, tris):
    """Overlapping triangle pairs of one mesh that share no vertex."""
    return sum(1 for i, j in tree.overlap(tree) if i < j and not set(tris[i]) & set(tris[j]))


def check(pair):
    result, body, source = load(pair["result"]), load(pair["body"]), load(pair["source"])
    r = {m: triangulated(result, m) for m in METHODS}
    b = {m: triangulated(body, m) for m in METHODS}
    worst, where = 0, None
    for mr in METHODS:
        for mb in METHODS:
            n = len(r[mr][0].overlap(b[mb][0]))
            if n > worst:
                worst, where = n, (mr, mb)
    self_result = max(self_overlaps(*r[m]) for m in METHODS)
    s = {m: triangulated(source, m) for m in METHODS}
    self_source = max(self_overlaps(*s[m]) for m in METHODS)
    for bm in (result, body, source):
        bm.free()
    return {"name": pair["name"], "body_overlaps": worst, "worst_triangulations": where,
            "self_overlaps": self_result, "self_overlaps_source": self_source}


def main(argv=None):
    argv = sys.argv[sys.argv.index("--") + 1:] if argv is None and "--" in sys.argv else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", required=True)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    pairs = json.loads(Path(args.pairs).read_text())
    out = []
    for pair in pairs:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        out.append(check(pair))
        print(json.dumps(out[-1]), flush=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
