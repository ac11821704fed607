"""How far garments sit from their source body, and how much of them is inside it.

For every MakeHuman fixture and demo garment on every body it is dressed on, and for the same garments
misplaced on purpose (moved 0.5 m up, turned 90 degrees about the vertical axis), prints the share of
vertices inside the body, the median and 90th-percentile distance to it (as shares of the body scale)
and the share deeper than a few depths; then how many of each case the placement check of
``garment_transfer.transfer`` refuses. Its thresholds are chosen from these figures.

    python -m lab.placement_study
"""

from __future__ import annotations

import json

import numpy as np

from garment_transfer.errors import MeshError
from garment_transfer.geometry.embedding import body_scale
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.transfer import prepare_garment

from .paths import DEMO_DATA as DEMO
from .paths import SHARED_MAKEHUMAN as MAKEHUMAN

DEPTHS = (0.0025, 0.005, 0.01, 0.02)
UP = {"X": [1.0, 0, 0], "Y": [0, 1.0, 0], "Z": [0, 0, 1.0]}


def measure(body, V):
    """Share inside; median and 90th percentile distance / scale; share deeper than DEPTHS * scale."""
    sd = TriangleSurface(body.V, body.F).signed_distance(V)[0]
    scale = body_scale(body.V)
    return (float((sd < 0).mean()), float(np.median(np.abs(sd)) / scale),
            float(np.percentile(np.abs(sd), 90) / scale), *[float((sd < -d * scale).mean()) for d in DEPTHS])


def dressed_garments():
    """(data set, body path, garment path, up vector, file units per metre)."""
    for kind, root, per_metre in (("makehuman", MAKEHUMAN, 10.0), ("demo", DEMO, 1.0)):
        if not (root / "manifest.json").is_file():
            continue
        manifest = json.loads((root / "manifest.json").read_text())
        for g in manifest["garments"]:
            for b in manifest["bodies"]:
                path = root / "garments" / g / f"{b}.obj"
                up = np.array(UP[manifest["up_axis"]])
                if path.is_file():
                    yield kind, root / "bodies" / f"{b}.obj", path, up, per_metre


def turn(V, up, centre, degrees):
    a = np.radians(degrees)
    K = np.array([[0, -up[2], up[1]], [up[2], 0, -up[0]], [-up[1], up[0], 0]])
    R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
    return (V - centre) @ R.T + centre


def main():
    rows, refused, passed = {}, {}, []
    bodies = {}
    for kind, bpath, gpath, up, per_metre in dressed_garments():
        body = bodies.setdefault(bpath, read_obj(bpath))
        g = read_obj(gpath)
        cases = {"dressed": g.V, "up 0.5 m": g.V + 0.5 * per_metre * up,
                 "turned 90": turn(g.V, up, body.V.mean(axis=0), 90)}
        for case, V in cases.items():
            rows.setdefault((case, kind), []).append((gpath, measure(body, V)))
            try:
                prepare_garment(body, g.with_vertices(V), need_solver=False)
                if case != "dressed":
                    passed.append(f"{case} {gpath.parent.name}/{gpath.stem}")
            except MeshError:
                refused[(case, kind)] = refused.get((case, kind), 0) + 1
    labels = ["inside", "median dist", "p90 dist"] + [f"deeper {d}" for d in DEPTHS]
    for (case, kind), sel in rows.items():
        stats = np.array([s for _, s in sel])
        print(f"{case} / {kind}: {len(sel)} garment files, {refused.get((case, kind), 0)} refused by the "
              "placement check; min / median / max:")
        for j, label in enumerate(labels):
            col = stats[:, j]
            worst = sel[int(np.argmax(col))][0]
            print(f"    {label:14s} {col.min():.4f} {np.median(col):.4f} {col.max():.4f}  "
                  f"(max: {worst.parent.name}/{worst.stem})")
    print(f"misplaced but accepted ({len(passed)}): {', '.join(passed) or 'none'}")


if __name__ == "__main__":
    main()
