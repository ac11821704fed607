"""Render meshes in columns side by side with Blender (Cycles, CPU): one figure from OBJ files.

    .venv/bin/python -m lab.blender.render_columns --spec SPEC.json --out FIGURE.png [--samples 16]

``SPEC.json``::

    {"size": [1200, 500],
     "columns": [{"label": "source", "meshes": [{"obj": "body.obj", "kind": "body", "scale": 0.1, "up": "Y"},
                                                {"obj": "garment.obj", "kind": "source", "scale": 0.1, "up": "Y"}]},
                 ...]}

``kind`` picks the colour of ``render_demo`` (body grey, source blue, ours yellow, simulation green);
``scale`` takes the file's units to metres and ``up`` ("Y" or "Z") its up axis to Blender's Z, the
figure facing -Y like the demo's renders. Columns are placed left to right with a gap. Exit status 0
when the figure was written, 1 with one line naming the file when an input is missing or the render
fails.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from lab.blender.render_demo import (  # noqa: E402
    frame_camera,
    material,
    new_mesh_object,
    render_to,
    set_material,
    setup_scene,
)


def to_blender(V, scale=1.0, up="Z"):
    """File coordinates to Blender's (metres, Z up, facing -Y)."""
    V = np.asarray(V, dtype=np.float64) * float(scale)
    if up.upper() == "Y":
        # Y up, facing +Z (MakeHuman) -> Z up, facing -Y.
        V = np.stack([V[:, 0], -V[:, 2], V[:, 1]], axis=1)
    return V


def render(spec, out, samples=16):
    import bpy

    from garment_transfer.geometry.obj import read_obj

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = setup_scene(tuple(spec.get("size", (1200, 500))), samples, 100, True)
    x = 0.0
    objects = []
    for c, column in enumerate(spec["columns"]):
        built = []
        for k, item in enumerate(column["meshes"]):
            path = Path(item["obj"])
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such file")
            mesh = read_obj(path)
            V = to_blender(mesh.V, item.get("scale", 1.0), item.get("up", "Z"))
            built.append((item, mesh.with_vertices(V)))
        lo = min(m.V[:, 0].min() for _, m in built)
        hi = max(m.V[:, 0].max() for _, m in built)
        floor = min(m.V[:, 2].min() for _, m in built)
        shift = np.array([x - lo, 0.0, -floor])
        for k, (item, mesh) in enumerate(built):
            obj = new_mesh_object(f"c{c}_{k}_{Path(item['obj']).stem}", mesh.with_vertices(mesh.V + shift))
            set_material(obj, material(item.get("kind", "body")))
            objects.append(obj)
        x += (hi - lo) + spec.get("gap", 0.12)
    frame_camera(scene, objects)
    out.parent.mkdir(parents=True, exist_ok=True)
    return render_to(scene, out)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m lab.blender.render_columns", description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--samples", type=int, default=16)
    args = ap.parse_args(argv)
    try:
        spec = json.loads(args.spec.read_text())
        seconds, _ = render(spec, args.out, args.samples)
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        print(f"render_columns: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out} in {seconds:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
