"""How far garments sit from their source body, and how much of them is inside it.

Prints, for every MakeHuman fixture and demo garment on every body it is dressed on, the share of
garment vertices inside the body and the median distance to it as a share of the body scale; then
the same for garments misplaced on purpose (moved 0.5 m up, turned 90 degrees about the vertical
axis). The thresholds of ``garment_transfer.transfer._check_placement`` are chosen from these.

    python -m lab.placement_study
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from garment_transfer.binding import bind
from garment_transfer.embedding import body_scale
from garment_transfer.obj import read_obj
from garment_transfer.proximity import TriangleSurface

ROOT = Path(__file__).resolve().parents[1]
MAKEHUMAN = next((p / "shared" / "data" / "makehuman" for p in ROOT.parents
                  if (p / "shared" / "data" / "makehuman").is_dir()), ROOT.parent / "shared" / "data" / "makehuman")
DEMO = ROOT / "garment_transfer" / "demo_data"
if not DEMO.is_dir():
    DEMO = ROOT / "data" / "demo"


DEPTHS = (0.0025, 0.005, 0.01, 0.02)


def measure(body, V):
    """Share inside; median and 90th percentile distance / scale; share deeper than DEPTHS * scale."""
    surface = TriangleSurface(body.V, body.F)
    sd = surface.signed_distance(V)[0]
    scale = body_scale(body.V)
    return (float((sd < 0).mean()), float(np.median(np.abs(sd)) / scale),
            float(np.percentile(np.abs(sd), 90) / scale), *[float((sd < -d * scale).mean()) for d in DEPTHS])


def sets():
    if (MAKEHUMAN / "bodies").is_dir():
        names = json.loads((MAKEHUMAN / "manifest.json").read_text())
        bodies = names["bodies"] if isinstance(names, dict) and "bodies" in names else \
            [p.stem for p in (MAKEHUMAN / "bodies").glob("*.obj")]
        for g in sorted(p.name for p in (MAKEHUMAN / "garments").iterdir()):
            for b in bodies:
                yield "makehuman", MAKEHUMAN / "bodies" / f"{b}.obj", MAKEHUMAN / "garments" / g / f"{b}.obj", \
                    np.array([0.0, 1.0, 0.0]), 10.0
    manifest = json.loads((DEMO / "manifest.json").read_text())
    up = {"Y": [0, 1.0, 0], "Z": [0, 0, 1.0]}[manifest["up_axis"]]
    for g in manifest["garments"]:
        for b in manifest["bodies"]:
            path = DEMO / "garments" / g / f"{b}.obj"
            if path.is_file():
                yield "demo", DEMO / "bodies" / f"{b}.obj", path, np.array(up), 1.0


def turn(V, up, centre, degrees):
    a = np.radians(degrees)
    k = up / np.linalg.norm(up)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
    return (V - centre) @ R.T + centre


def main():
    rows = {"dressed": [], "up 0.5 m": [], "turned 90": []}
    bodies = {}
    for kind, bpath, gpath, up, per_metre in sets():
        body = bodies.setdefault(bpath, read_obj(bpath))
        g = read_obj(gpath)
        centre = body.V.mean(axis=0)
        rows["dressed"].append((kind, gpath, *measure(body, g.V)))
        rows["up 0.5 m"].append((kind, gpath, *measure(body, g.V + 0.5 * per_metre * up)))
        rows["turned 90"].append((kind, gpath, *measure(body, turn(g.V, up, centre, 90))))
    for case, r in rows.items():
        for kind in ("makehuman", "demo"):
            sel = [x for x in r if x[0] == kind]
            if not sel:
                continue
            stats = np.array([x[2:] for x in sel])
            labels = ["inside", "median dist", "p90 dist"] + [f"deeper {d}" for d in DEPTHS]
            print(f"{case} / {kind} ({len(sel)} garment files): min / median / max")
            for j, label in enumerate(labels):
                col = stats[:, j]
                print(f"    {label:14s} {col.min():.4f} {np.median(col):.4f} {col.max():.4f}  "
                      f"(max: {sel[int(np.argmax(col))][1].parent.name}/{sel[int(np.argmax(col))][1].stem}; "
                      f"min: {sel[int(np.argmin(col))][1].parent.name}/{sel[int(np.argmin(col))][1].stem})")


if __name__ == "__main__":
    main()


def passing(rule):
    """Misplaced cases that ``rule(stats)`` lets through, and dressed cases it refuses."""
    bodies = {}
    for kind, bpath, gpath, up, per_metre in sets():
        body = bodies.setdefault(bpath, read_obj(bpath))
        g = read_obj(gpath)
        centre = body.V.mean(axis=0)
        for case, V in (("dressed", g.V), ("up", g.V + 0.5 * per_metre * up), ("turned", turn(g.V, up, centre, 90))):
            st = measure(body, V)
            if rule(st) != (case == "dressed"):
                yield case, gpath.parent.name, gpath.stem, np.round(st, 4)
