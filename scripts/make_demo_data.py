"""Generate the built-in demo dataset: procedural mannequins, procedural garments draped with
Blender's cloth solver on the source body and then on every target body.

Runs with a Python that has the ``bpy`` module (or ``blender --background --python`` this file ``--``)::

    .venv/bin/python scripts/make_demo_data.py --out garment_transfer/demo_data

Deterministic: the same arguments give the same files. Writes, in the common dataset layout,
``bodies/<body>.obj``, ``garments/<garment>/<body>.obj`` and ``manifest.json``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import numpy as np  # noqa: E402

from garment_transfer.mesh import mesh_from_polygons  # noqa: E402
from garment_transfer.obj import write_text_atomic  # noqa: E402
from garment_transfer.procedural.garments import TEST_GARMENTS, TRAIN_GARMENTS, garment  # noqa: E402
from garment_transfer.procedural.mannequin import PRESETS, mannequin  # noqa: E402

SOURCE = "banana"
TARGETS = ("pear", "slim", "heavy", "apple", "hourglass")


def load_cloth():
    """operators/cloth.py, imported as part of the repository's extension package."""
    if (ROOT / "__init__.py").exists():
        from extension_loader import load_extension

        pkg = load_extension()
        return importlib.import_module(pkg.__name__ + ".operators.cloth")
    spec = importlib.util.spec_from_file_location("cloth", ROOT / "operators" / "cloth.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def obj_text(V, polys, header):
    """Compact OBJ: 5 significant digits (0.01 mm at body scale), the polygons as given."""
    lines = [f"# {header}"]
    lines += ["v %.5g %.5g %.5g" % tuple(v) for v in V]
    lines += ["f " + " ".join(str(int(i) + 1) for i in p) for p in polys]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "garment_transfer" / "demo_data"))
    ap.add_argument("--garments", nargs="*", default=list(TRAIN_GARMENTS + TEST_GARMENTS))
    ap.add_argument("--targets", nargs="*", default=list(TARGETS))
    ap.add_argument("--frames", type=int, default=15, help="settling frames per simulation")
    ap.add_argument("--morph-frames", type=int, default=12)
    if "--" in sys.argv and argv is None:
        argv = sys.argv[sys.argv.index("--") + 1:]
    args = ap.parse_args(argv)
    out = Path(args.out)
    (out / "bodies").mkdir(parents=True, exist_ok=True)
    cloth = load_cloth()
    t0 = time.perf_counter()

    bodies = {}
    for name in [SOURCE] + args.targets:
        V, F = mannequin(name)
        bodies[name] = V
        write_text_atomic(out / "bodies" / f"{name}.obj",
                          obj_text(V, F, f"procedural mannequin '{name}': {PRESETS[name]}"))
        print(f"[{time.perf_counter() - t0:6.1f}s] body {name}: {V.shape[0]} vertices, {F.shape[0]} triangles",
              flush=True)
    F = mannequin(SOURCE)[1]

    log = []
    done = []
    for gi, gname in enumerate(args.garments):
        g = garment(gname)
        t = time.perf_counter()
        report = []
        shapes = cloth.drape_garment(g.V, g.polygons, bodies[SOURCE], F,
                                     [bodies[b] for b in args.targets], pin_group=g.pin,
                                     frames=args.frames, morph_frames=args.morph_frames, report=report)
        folder = out / "garments" / gname
        folder.mkdir(parents=True, exist_ok=True)
        tris = mesh_from_polygons(g.V, g.polygons, name=gname).n_triangles
        for body, S in zip([SOURCE] + args.targets, shapes):
            write_text_atomic(folder / f"{body}.obj", obj_text(S, g.polygons, f"{gname} draped on {body}"))
        secs = time.perf_counter() - t
        entry = {"garment": gname, "vertices": int(g.V.shape[0]), "triangles": int(tris),
                 "seconds": round(secs, 1),
                 "inside_before_fix": [r["inside_before"] for r in report],
                 "inside_after_fix": [r["inside_after"] for r in report]}
        log.append(entry)
        done.append(gname)
        print(f"[{time.perf_counter() - t0:6.1f}s] garment {gi + 1}/{len(args.garments)} {gname}: "
              f"{g.V.shape[0]} vertices, {tris} triangles, {secs:.1f}s, inside before/after fix "
              f"{entry['inside_before_fix']}/{entry['inside_after_fix']}", flush=True)

    manifest = {
        "units": "metres", "up_axis": "Z", "forward_axis": "-Y",
        "bodies": [SOURCE] + args.targets,
        "garments": done,
        "source": SOURCE,
        "targets": args.targets,
        "train_garments": [g for g in TRAIN_GARMENTS if g in done],
        "test_garments": [g for g in TEST_GARMENTS if g in done],
        "generator": {"script": "scripts/make_demo_data.py", "frames": args.frames,
                      "morph_frames": args.morph_frames},
        "drape_log": log,
    }
    write_text_atomic(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    print(f"[{time.perf_counter() - t0:6.1f}s] wrote {out} ({size / 1e6:.1f} MB)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
