"""Baseline: Blender's Surface Deform modifier, bound to the source body, evaluated on target shapes.

What an artist does today: bind the garment to the body with Surface Deform, then change the body's
shape. Each garment is bound once to the source body; the body's vertices are then moved to each
target shape and the evaluated garment is written. No penetration fix, no cloth: the modifier as
Blender ships it (default falloff and strength).

With the bpy module::

    .venv/bin/python -m lab.blender.surface_deform_baseline --source-body S.obj \
        --target-body pear=T1.obj --target-body slim=T2.obj --garment dress=G.obj --out DIR

In Blender: ``blender --background --python lab/blender/surface_deform_baseline.py -- <same arguments>``.

``NAME=PATH`` names an input (default: the file's stem). Writes ``DIR/<garment>__<target>.obj`` (the
garment file with only its ``v`` lines changed) and ``DIR/surface_deform.json``: one record per garment
with ``bind_seconds`` (bind and first evaluation on the source body, inside Blender) and, per target,
``seconds`` (moving the body and evaluating the garment) or ``error``. Exit code 0 when every pair
succeeded, 1 otherwise, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# Under a Blender binary the checkout is not installed: import it from here.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def named_path(text):
    """``NAME=PATH`` or ``PATH`` (named after the file's stem)."""
    name, sep, path = text.partition("=")
    if not sep:
        return Path(text).stem, Path(text)
    return name, Path(path)


def parse_args(argv):
    p = argparse.ArgumentParser(prog="surface_deform_baseline.py",
                                description="Surface Deform modifier baseline (Blender).")
    p.add_argument("--source-body", type=Path, required=True, help="OBJ: the body the garments are on")
    p.add_argument("--target-body", type=named_path, action="append", required=True,
                   help="[NAME=]OBJ: the same body mesh in a target shape (repeatable)")
    p.add_argument("--garment", type=named_path, action="append", required=True,
                   help="[NAME=]OBJ: a garment on the source body (repeatable)")
    p.add_argument("--out", type=Path, required=True, help="folder for the results (created)")
    return p.parse_args(argv)


def script_argv(argv):
    """The script's own arguments: after ``--`` under Blender, else everything after the script."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def new_object(bpy, name, V, F):
    """A mesh object linked to the scene; ``F`` (m,3) triangles."""
    me = bpy.data.meshes.new(name)
    me.from_pydata(V.tolist(), [], F.tolist())
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def set_positions(obj, V):
    obj.data.vertices.foreach_set("co", V.astype("float32").ravel())
    obj.data.update()


def evaluated_positions(bpy, obj, n):
    import numpy as np

    depsgraph = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        if len(me.vertices) != n:
            raise RuntimeError(f"the evaluated garment has {len(me.vertices)} vertices, expected {n}")
        co = np.empty(3 * n, np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    return co.reshape(n, 3).astype(np.float64)


def run(args, log):
    """Bind every garment to the source body and evaluate it on every target; the JSON records."""
    import bpy
    import numpy as np

    from garment_transfer.geometry.mesh import require_same_topology
    from garment_transfer.geometry.obj import read_obj, write_obj

    bpy.ops.wm.read_factory_settings(use_empty=True)
    source = read_obj(args.source_body)
    targets = [(name, read_obj(path, name=name)) for name, path in args.target_body]
    for _, t in targets:
        require_same_topology(source, t)
    args.out.mkdir(parents=True, exist_ok=True)
    # The body as triangles: Surface Deform refuses concave polygons, and a quad body's quads may be.
    body = new_object(bpy, "body", source.V, source.F)
    records = []
    for gname, gpath in args.garment:
        garment = read_obj(gpath, name=gname)
        rec = {"garment": gname, "vertices": garment.n_vertices, "triangles": garment.n_triangles,
               "targets": {}}
        records.append(rec)
        set_positions(body, source.V)
        obj = new_object(bpy, f"garment_{gname}", garment.V, garment.F)
        mod = obj.modifiers.new("SurfaceDeform", "SURFACE_DEFORM")
        mod.target = body
        t = time.perf_counter()
        try:
            with bpy.context.temp_override(object=obj, active_object=obj):
                bpy.ops.object.surfacedeform_bind(modifier=mod.name)
            V0 = evaluated_positions(bpy, obj, garment.n_vertices)
            if not mod.is_bound:
                raise RuntimeError("Surface Deform did not bind (Blender refused the body)")
        except RuntimeError as exc:
            rec["error"] = str(exc)
            log(f"{gname}: {exc}")
            bpy.data.objects.remove(obj)
            continue
        rec["bind_seconds"] = time.perf_counter() - t
        rec["bound_max_move"] = float(np.abs(V0 - garment.V).max())
        for tname, tbody in targets:
            t = time.perf_counter()
            try:
                set_positions(body, tbody.V)
                V = evaluated_positions(bpy, obj, garment.n_vertices)
            except RuntimeError as exc:
                rec["targets"][tname] = {"error": str(exc)}
                log(f"{gname} on {tname}: {exc}")
                continue
            seconds = time.perf_counter() - t
            path = args.out / f"{gname}__{tname}.obj"
            write_obj(path, garment, V, header=f"Surface Deform: {gname} bound to {source.name}, on {tname}")
            rec["targets"][tname] = {"seconds": seconds, "out": str(path)}
        log(f"{gname}: bound in {rec['bind_seconds']:.2f} s, {len(rec['targets'])} targets")
        bpy.data.objects.remove(obj)
    (args.out / "surface_deform.json").write_text(json.dumps({"blender": bpy.app.version_string,
                                                              "garments": records}, indent=1))
    return records


def main(argv=None):
    argv = script_argv(sys.argv if argv is None else ["script"] + list(argv))
    try:
        args = parse_args(argv)
    except SystemExit as exc:
        return 2 if exc.code else 0

    def log(text):
        print(f"surface_deform_baseline: {text}", file=sys.stderr, flush=True)

    try:
        records = run(args, log)
    except Exception as exc:  # one line naming the problem, like the other scripts
        log(f"error: {exc}")
        return 1
    ok = all("error" not in r and all("error" not in v for v in r["targets"].values()) for r in records)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
