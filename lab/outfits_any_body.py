"""Outfits onto a body of another mesh: the demo's outfits onto each target re-meshed (registered once for the
outfit), per layer against the body as given and the layers under it, beside the same outfit onto the target's
own mesh and each garment transferred alone through the same registration.

Per outfit and target: the seconds (the registration's apart), then per layer the edges through the body and
through the layers under it (both ways, every triangulation), self-intersections beyond the source's, and the mean
distance in mm to the outfit onto the target's own mesh, beside that of the garment transferred alone through the
same registration to the garment transferred alone onto the target's own mesh (the registration's own error: what
the outfit adds is the difference).

    python -m lab.outfits_any_body [--targets pear apple] [--triangles 20000] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.readings import readings_of
from garment_transfer.pipeline.any_body import transfer_to_any_body
from garment_transfer.pipeline.outfit import transfer_outfit
from garment_transfer.pipeline.result_check import check_result
from garment_transfer.pipeline.transfer import transfer_garment

from .outfits import OUTFITS, load_outfit
from .paths import DEMO_DATA, mm_per_unit
from .registration import remesh


def measure(targets=None, triangles=20000, say=print):
    """Rows: one per outfit, target and layer."""
    man = json.loads((DEMO_DATA / "manifest.json").read_text(encoding="utf-8"))
    unit_mm = mm_per_unit(man.get("units"))
    source = read_obj(DEMO_DATA / "bodies" / f"{man['source']}.obj")
    rows = []
    for t in targets or man["targets"]:
        own = read_obj(DEMO_DATA / "bodies" / f"{t}.obj")
        other = mesh_from_triangles(*remesh(own.V, own.F, triangles), name=f"{t} re-meshed")
        for layers in OUTFITS:
            garments = load_outfit(DEMO_DATA, man["source"], layers)
            start = time.perf_counter()
            result = transfer_outfit(source, other, garments, cache=False)
            wall = time.perf_counter() - start
            same = transfer_outfit(source, own, garments)
            alone = [transfer_to_any_body(source, other, g, registration=result.registration)[0].V for g in garments]
            alone_own = [transfer_garment(source, own, g).V for g in garments]
            R = [readings_of(g) for g in garments]
            for k, (g, V) in enumerate(zip(garments, result.V)):
                below = [(result.V[i], R[i]) for i in range(k)]
                rep = check_result(g, V, other, layers_below=below)
                row = {"target": t, "outfit": " under ".join(layers), "layer": g.name, "seconds": wall,
                       "register_seconds": result.seconds.get("register", 0.0),
                       "body_edges": rep["garment_edges_through_body"] + rep["body_edges_through_garment"],
                       "layer_edges": rep.get("layer_crossings", 0),
                       "self_intersections_new": rep["self_intersections_new"],
                       "to_own_mesh_mm": float(np.linalg.norm(V - same.V[k], axis=1).mean() * unit_mm),
                       "alone_to_own_mesh_mm": float(np.linalg.norm(alone[k] - alone_own[k], axis=1).mean() * unit_mm)}
                rows.append(row)
                say(f"{t:8s} {row['outfit']:24s} {g.name:12s} | {wall:5.1f} s (registration "
                    f"{row['register_seconds']:.1f}) | body {row['body_edges']} layers {row['layer_edges']} new "
                    f"self {row['self_intersections_new']} | to the own-mesh outfit {row['to_own_mesh_mm']:.1f} mm, "
                    f"the garment alone to its own-mesh transfer {row['alone_to_own_mesh_mm']:.1f} mm")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--targets", nargs="+", help="demo targets (default: the manifest's)")
    p.add_argument("--triangles", type=int, default=20000, help="triangles of each re-meshed target")
    p.add_argument("--json", type=Path, help="write the rows to this file")
    args = p.parse_args(argv)
    rows = measure(args.targets, args.triangles)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
