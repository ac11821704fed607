"""A model trained on one body family serving garments dressed on another.

The shared model is trained on the demo mannequins (metres, Z up, source ``banana``); the garments are
MakeHuman's (decimetres, Y up), dressed on ``female_average``. The model's body is registered onto
``female_average`` and its field for a mannequin label carried onto MakeHuman's triangles
(``garment_transfer.field_mapping``); the anchors come from the MakeHuman target body as always.
Each MakeHuman garment goes to the MakeHuman body paired with a mannequin label, and is compared with
MakeHuman's own fit of that garment on that body (the reference) and with direct transfer.

    python -m lab.cross_family [--epochs 400] [--pairs female_pear:pear,female_slim_banana:slim]
    python -m lab.cross_family --renders DIR      # each family's garment on the other's body, rendered
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, makehuman_folder

PAIRS = {"female_pear": "pear", "female_slim_banana": "slim", "male_average": "heavy"}


def run(epochs=400, pairs=None, say=print):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.learning.dataset import build_training_fields, load_dataset
    from garment_transfer.learning.training import train_model
    from garment_transfer.pipeline.field_mapping import model_field
    from garment_transfer.pipeline.metrics import mdc, vertex_error
    from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

    pairs = pairs or PAIRS
    root = makehuman_folder()
    if root is None:
        raise SystemExit("the MakeHuman fixtures are not there (../shared/data/makehuman)")
    data = load_dataset(DEMO_DATA)
    labels = sorted(set(pairs.values()))
    t = time.perf_counter()
    fields = build_training_fields(data, "banana", labels, garments=data.manifest["train_garments"])
    model, _ = train_model(fields, latent=30, epochs=epochs, seed=0)
    say(f"model on the mannequins ({', '.join(labels)}): {time.perf_counter() - t:.1f} s")
    source = read_obj(root / "bodies" / f"{MAKEHUMAN_SOURCE}.obj")
    t = time.perf_counter()
    model_field(model, labels[0], source)
    say(f"registration of the mannequin onto {source.name} and the field carried: {time.perf_counter() - t:.1f} s")
    rows = []
    garments = sorted(p.name for p in (root / "garments").iterdir() if (p / f"{MAKEHUMAN_SOURCE}.obj").exists())
    mm = 100.0      # decimetres to millimetres
    for gname in garments:
        garment = read_obj(root / "garments" / gname / f"{MAKEHUMAN_SOURCE}.obj")
        prepared = prepare_garment(source, garment)
        for body_name, label in pairs.items():
            ref_path = root / "garments" / gname / f"{body_name}.obj"
            if not ref_path.exists():
                continue
            target = read_obj(root / "bodies" / f"{body_name}.obj")
            ref = read_obj(ref_path)
            row = {"garment": gname, "target": body_name, "label": label,
                   "untransferred_mm": vertex_error(garment.V, ref.V)[0] * mm}
            for name, opts in (("direct", {}), ("model", {"method": "model", "model": model, "target": label})):
                r = transfer_garment(source, target, garment, prepared=prepared, **opts)
                row[f"{name}_mm"] = vertex_error(r.V, ref.V)[0] * mm
                row[f"{name}_mdc"] = mdc(garment.V, r.V, garment.F)
                row[f"{name}_inside"] = r.penetrating_vertices
            rows.append(row)
            say(f"{gname:22s} {body_name:19s} ({label:6s}) untransferred {row['untransferred_mm']:6.2f} mm  "
                f"direct {row['direct_mm']:6.2f} mm mdc {row['direct_mdc']:.4f}  "
                f"model {row['model_mm']:6.2f} mm mdc {row['model_mdc']:.4f} inside {row['model_inside']}")
    for body_name in pairs:
        sub = [r for r in rows if r["target"] == body_name]
        if sub:
            ratio = np.mean([r["model_mm"] / r["direct_mm"] for r in sub])
            say(f"mean on {body_name}: direct {np.mean([r['direct_mm'] for r in sub]):.2f} mm, model "
                f"{np.mean([r['model_mm'] for r in sub]):.2f} mm ({ratio:.2f}x), "
                f"MDC {np.mean([r['model_mdc'] / r['direct_mdc'] for r in sub]):.2f}x direct's, "
                f"inside {sum(r['model_inside'] for r in sub)}")
    return rows


#: (figure, source body, garment, target body) of ``renders``: each family's garment on the other family.
FIGURES = (
    ("mannequin_garment_on_makehuman", ("demo", "banana"), ("demo", "tshirt"), ("makehuman", "female_average")),
    ("makehuman_garment_on_mannequin", ("makehuman", "female_average"), ("makehuman", "female_casualsuit01"),
     ("demo", "pear")),
)


def renders(out, samples=16, say=print):
    """Each family's garment transferred onto the other family's body (registered), rendered with
    Blender beside the garment on its own body: ``out/<figure>.png``; the penetration and the fit's
    residual of each are printed and returned."""
    import json
    import subprocess
    from pathlib import Path

    from garment_transfer.geometry.obj import read_obj, write_obj
    from garment_transfer.pipeline.any_body import transfer_to_any_body

    root = makehuman_folder()
    if root is None:
        raise SystemExit("the MakeHuman fixtures are not there (../shared/data/makehuman)")
    out = Path(out)
    meshes = out / "meshes"
    meshes.mkdir(parents=True, exist_ok=True)
    frame = {"demo": {"scale": 1.0, "up": "Z"}, "makehuman": {"scale": 0.1, "up": "Y"}}

    def body_path(family, name):
        return (DEMO_DATA if family == "demo" else root) / "bodies" / f"{name}.obj"

    def garment_path(family, name, body):
        return (DEMO_DATA if family == "demo" else root) / "garments" / name / f"{body}.obj"

    results = []
    for fig, (sf, sname), (gf, gname), (tf, tname) in FIGURES:
        source, target = read_obj(body_path(sf, sname)), read_obj(body_path(tf, tname))
        garment = read_obj(garment_path(gf, gname, sname))
        r, reg = transfer_to_any_body(source, target, garment)
        moved = meshes / f"{fig}.obj"
        write_obj(moved, garment, r.V)
        q = reg.quality
        rec = {"figure": fig, "garment": gname, "source": sname, "target": tname,
               "inside": int(r.penetrating_vertices), "vertices": garment.n_vertices,
               "residual_p95_share": [q.get("to_target_p95_share"), q.get("from_target_p95_share")]}
        results.append(rec)
        say(f"{gname} from {sname} onto {tname}: {rec['inside']} of {rec['vertices']} vertices inside; fit residual "
            f"p95 {100 * rec['residual_p95_share'][0]:.2f}% / {100 * rec['residual_p95_share'][1]:.2f}% of the height")
        spec = {"size": [900, 520], "columns": [
            {"meshes": [dict(obj=str(body_path(sf, sname)), kind="body", **frame[sf]),
                        dict(obj=str(garment_path(gf, gname, sname)), kind="source", **frame[sf])]},
            {"meshes": [dict(obj=str(body_path(tf, tname)), kind="body", **frame[tf]),
                        dict(obj=str(moved), kind="ours", **frame[tf])]}]}
        spec_path = meshes / f"{fig}.json"
        spec_path.write_text(json.dumps(spec, indent=1))
        proc = subprocess.run([sys.executable, "-m", "lab.blender.render_columns", "--spec", str(spec_path),
                               "--out", str(out / f"{fig}.png"), "--samples", str(samples)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"rendering {fig} failed: {proc.stderr[-2000:]}")
        say(proc.stdout.strip().splitlines()[-1])
    return results


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m lab.cross_family", description=__doc__.split("\n\n")[0])
    ap.add_argument("--epochs", type=int, default=400)
    ap.add_argument("--pairs", help="makehuman_body:mannequin_label,... (default: "
                    + ",".join(f"{k}:{v}" for k, v in PAIRS.items()) + ")")
    ap.add_argument("--renders", metavar="DIR", help="only render each family's garment on the other family's "
                    "body into DIR (Blender, Cycles on the CPU)")
    ap.add_argument("--samples", type=int, default=16)
    args = ap.parse_args(argv)
    if args.renders:
        renders(args.renders, args.samples)
        return 0
    pairs = dict(p.split(":") for p in args.pairs.split(",")) if args.pairs else None
    run(args.epochs, pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
