"""Generate the built-in demo dataset: procedural mannequins, procedural garments draped with
Blender's cloth solver on the source body and then on every target body.

Runs with a Python that has the ``bpy`` module (or ``blender --background --python`` this file ``--``)::

    .venv/bin/python -m lab make-data [--out data/demo]

Deterministic: the same arguments give the same files. Writes, in the common dataset layout,
``bodies/<body>.obj``, ``garments/<garment>/<body>.obj`` and ``manifest.json``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# Under a Blender binary (blender --python this file) the checkout is not installed: import it from here.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))


from garment_transfer.geometry.mesh import mesh_from_polygons  # noqa: E402
from garment_transfer.geometry.obj import obj_text, write_text_atomic  # noqa: E402
from lab.procedural.garments import TEST_GARMENTS, TRAIN_GARMENTS, garment  # noqa: E402
from lab.procedural.mannequin import mannequin, measurements  # noqa: E402

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


def compact_obj(V, polys, header):
    """Compact OBJ text: 5 significant digits (0.01 mm at body scale), the polygons as given."""
    return obj_text(mesh_from_polygons(V, polys), header=header, digits=5)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "data" / "demo"))
    ap.add_argument("--garments", nargs="*", default=list(TRAIN_GARMENTS + TEST_GARMENTS))
    ap.add_argument("--targets", nargs="*", default=list(TARGETS))
    ap.add_argument("--frames", type=int, default=15, help="frames to settle after each morph")
    ap.add_argument("--morph-frames", type=int, default=15, help="frames of each morph")
    ap.add_argument("--source-frames", type=int, default=30, help="frames to settle on the source body")
    ap.add_argument("--jobs", type=int, default=1, help="simulate garments in this many processes")
    ap.add_argument("--continuous", action="store_true",
                    help="each target one simulation from the start (source settling, then the morph), not a "
                         "restart from the garment settled on the source (operators/cloth.py, drape_garment)")
    ap.add_argument("--log-dir", help=argparse.SUPPRESS)
    if "--" in sys.argv and argv is None:
        argv = sys.argv[sys.argv.index("--") + 1:]
    args = ap.parse_args(argv)
    out = Path(args.out)
    (out / "bodies").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    def say(text):
        print(f"[{time.perf_counter() - t0:6.1f}s] {text}", flush=True)

    if args.jobs > 1 and args.log_dir is None:
        return run_jobs(args, out, say)

    bodies = {}
    for name in [SOURCE] + args.targets:
        V, F = mannequin(name)
        bodies[name] = V
        if args.log_dir is None:
            write_text_atomic(out / "bodies" / f"{name}.obj",
                              compact_obj(V, F, f"procedural mannequin '{name}': {measurements(name)}"))
            say(f"body {name}: {V.shape[0]} vertices, {F.shape[0]} triangles")
    F = mannequin(SOURCE)[1]
    cloth = load_cloth()
    log = [drape_one(cloth, gname, bodies, F, args, out, say, f"{i + 1}/{len(args.garments)}")
           for i, gname in enumerate(args.garments)]
    if args.log_dir is not None:
        for entry in log:
            write_text_atomic(Path(args.log_dir) / f"{entry['garment']}.json", json.dumps(entry))
        return 0
    write_manifest(out, args, log)
    say(f"wrote {out} ({dataset_size(out) / 1e6:.1f} MB)")
    return 0


def drape_one(cloth, gname, bodies, F, args, out, say, counter):
    """Drape one garment on the source and every target; write its OBJ files; return its log entry."""
    g = garment(gname)
    t = time.perf_counter()
    report = []
    shapes = cloth.drape_garment(g.V, g.polygons, bodies[SOURCE], F, [bodies[b] for b in args.targets],
                                 pin_group=g.pin, frames=args.frames, morph_frames=args.morph_frames,
                                 source_frames=args.source_frames, report=report, continuous=args.continuous)
    folder = out / "garments" / gname
    folder.mkdir(parents=True, exist_ok=True)
    tris = mesh_from_polygons(g.V, g.polygons, name=gname).n_triangles
    for body, S in zip([SOURCE] + args.targets, shapes):
        write_text_atomic(folder / f"{body}.obj", compact_obj(S, g.polygons, f"{gname} draped on {body}"))
    secs = time.perf_counter() - t
    entry = {"garment": gname, "vertices": int(g.V.shape[0]), "triangles": int(tris),
             "seconds": round(secs, 1),
             "inside_before_fix": [r["inside_before"] for r in report],
             "inside_after_fix": [r["inside_after"] for r in report],
             "deepest_before_fix": [round(r["max_depth"], 4) for r in report]}
    say(f"garment {counter} {gname}: {g.V.shape[0]} vertices, {tris} triangles, {secs:.1f}s, vertices "
        f"inside the body before/after the fix {entry['inside_before_fix']}/{entry['inside_after_fix']}")
    return entry


def run_jobs(args, out, say):
    """Split the garments over ``args.jobs`` child processes (largest first, round robin), then merge."""
    import tempfile

    sizes = {g: garment(g).V.shape[0] for g in args.garments}
    order = sorted(args.garments, key=lambda g: -sizes[g])
    shares = [order[i::args.jobs] for i in range(args.jobs)]
    for name in [SOURCE] + args.targets:
        V, F = mannequin(name)
        write_text_atomic(out / "bodies" / f"{name}.obj",
                          compact_obj(V, F, f"procedural mannequin '{name}': {measurements(name)}"))
        say(f"body {name}: {V.shape[0]} vertices, {F.shape[0]} triangles")
    with tempfile.TemporaryDirectory() as logs:
        common = ["--out", str(out), "--targets", *args.targets, "--frames", str(args.frames),
                  "--morph-frames", str(args.morph_frames), "--source-frames", str(args.source_frames),
                  "--log-dir", logs] + (["--continuous"] if args.continuous else [])
        procs = [subprocess.Popen([sys.executable, __file__, *common, "--garments", *share])
                 for share in shares if share]
        codes = [p.wait() for p in procs]
        if any(codes):
            say(f"a job failed (exit codes {codes}); manifest not written")
            return 1
        log = [json.loads((Path(logs) / f"{g}.json").read_text()) for g in args.garments]
    write_manifest(out, args, log)
    say(f"wrote {out} ({dataset_size(out) / 1e6:.1f} MB)")
    return 0


def write_manifest(out, args, log):
    done = [e["garment"] for e in log]
    manifest = {
        "units": "metres", "up_axis": "Z", "forward_axis": "-Y",
        "bodies": [SOURCE] + args.targets,
        "garments": done,
        "source": SOURCE,
        "targets": args.targets,
        "train_garments": [g for g in TRAIN_GARMENTS if g in done],
        "test_garments": [g for g in TEST_GARMENTS if g in done],
        "generator": {"script": "lab/blender/make_demo_data.py", "frames": args.frames,
                      "morph_frames": args.morph_frames, "source_frames": args.source_frames,
                      "continuous": args.continuous},
        "drape_log": log,
    }
    write_text_atomic(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")


def dataset_size(out):
    return sum(f.stat().st_size for f in out.rglob("*") if f.is_file())


if __name__ == "__main__":
    sys.exit(main())
