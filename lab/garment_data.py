"""More training garments for the garment fit model: generated, draped, stored compactly.

``lab.procedural.garments.EXTRA_GARMENTS`` (loose and tight variants of the demo's 15 training styles
and 10 more styles) are draped by Blender's cloth solver (``lab/blender/make_demo_data.py``) on the
demo's source and target bodies, then packed into one compressed ``.npz`` (``data/extra/garments.npz``):
per garment its quads (int32), its source shape (int32, 0.01 mm) and its shape on every target as a
displacement from the source (int16, 0.05 mm), and the drape log (seconds, vertices inside before and
after the fix) in a JSON string. No OBJ files, no pickle.

Commands::

    nice -n 19 python -m lab.garment_data generate [--work /tmp/extra] [--garments g1 g2 ...]
    python -m lab.garment_data pack --work /tmp/extra           # what generate ran, packed (also partial)
    python -m lab.garment_data unpack --out /tmp/demo_plus      # data/demo + the packed garments, as a
                                                                # dataset folder for lab.garment_model --data
    nice -n 19 python -m lab.garment_data between [--work /tmp/between] [--garments ...]

``between`` drapes the demo's test garments and all training garments (by default) on the bodies between
two demo bodies (``lab.procedural.mannequin.BETWEEN``: every measurement interpolated) and packs them, with
those bodies, into ``data/extra/between.npz``; ``unpack`` adds them to the dataset folder. The source
shapes are the same as the demo's (the solver is deterministic and the source drape does not depend on
the targets; data/extra/README.md says where they differ).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from garment_transfer.files import atomic_path, write_json_atomic
from garment_transfer.geometry.mesh import mesh_from_polygons
from garment_transfer.geometry.obj import obj_text, read_obj, write_text_atomic

from .paths import BLENDER_SCRIPTS, DEMO_DATA, ROOT

PACKED = ROOT / "data" / "extra" / "garments.npz"
BETWEEN_PACKED = ROOT / "data" / "extra" / "between.npz"
SOURCE_STEP = 1e-5      # metres: 0.01 mm
OFFSET_STEP = 5e-5      # metres: 0.05 mm, so int16 holds displacements up to 1.6 m


def generate(work, garments, say, targets=None):
    """Drape ``garments`` (names of the procedural catalogue) into ``work`` with Blender's cloth solver
    (on the demo's targets, or on ``targets``)."""
    cmd = [sys.executable, str(BLENDER_SCRIPTS / "make_demo_data.py"), "--out", str(work), "--jobs", "1",
           "--garments", *garments] + (["--targets", *targets] if targets else [])
    say("running " + " ".join(cmd))
    log = Path(work) / "log.txt"
    Path(work).mkdir(parents=True, exist_ok=True)
    with open(log, "a") as fh:      # appended: a later run for more garments keeps the earlier ones packable
        return subprocess.call(cmd, stdout=fh, stderr=subprocess.STDOUT)


def _drape_log(work):
    """Seconds and fix counts per garment, from the generator's output (the manifest may not exist yet)."""
    out = {}
    log = Path(work) / "log.txt"
    pattern = re.compile(r"garment \d+/\d+ (\S+): (\d+) vertices, (\d+) triangles, ([\d.]+)s, vertices inside "
                         r"the body before/after the fix (\[[^\]]*\])/(\[[^\]]*\])")
    if log.exists():
        for m in pattern.finditer(log.read_text()):
            out[m.group(1)] = {"vertices": int(m.group(2)), "triangles": int(m.group(3)),
                               "seconds": float(m.group(4)), "inside_before_fix": json.loads(m.group(5)),
                               "inside_after_fix": json.loads(m.group(6))}
    return out


def pack(work, out=PACKED, source="banana", targets=("pear", "slim", "heavy", "apple", "hourglass"),
         with_bodies=False):
    """Pack every garment of ``work`` draped on the source and all targets into ``out`` (.npz); the
    garments ``out`` already holds and ``work`` does not are kept (generation runs in parts).
    ``with_bodies``: also the target bodies (``bodies/<target>``, int32 at 0.01 mm), for bodies that
    are not in the demo dataset."""
    work = Path(work)
    drape = _drape_log(work)
    arrays, done = {}, []
    kept = {}
    if Path(out).exists():
        with np.load(out, allow_pickle=False) as npz:
            old = json.loads(str(npz["metadata"]))
            if old.get("source") == source and list(old.get("targets", [])) == list(targets):
                kept = {g: {k: npz[f"{g}/{k}"] for k in ("quads", "source", "offsets")} for g in old["garments"]}
                drape = {**old.get("drape_log", {}), **drape}
                if with_bodies:
                    arrays.update({f"bodies/{t}": npz[f"bodies/{t}"] for t in targets if f"bodies/{t}" in npz})
    if with_bodies:
        for t in targets:
            path = work / "bodies" / f"{t}.obj"
            if path.exists():
                arrays[f"bodies/{t}"] = np.round(read_obj(path).V / SOURCE_STEP).astype(np.int32)
            elif f"bodies/{t}" not in arrays:
                raise ValueError(f"{path}: body not found; it is packed with the garments")
    for folder in sorted((work / "garments").glob("*")):
        g = folder.name
        files = [folder / f"{b}.obj" for b in (source, *targets)]
        if not all(f.exists() for f in files) or g not in drape:
            continue
        meshes = [read_obj(f) for f in files]
        polys = meshes[0].polygons()
        if any(len(p) != 4 for p in polys):
            raise ValueError(f"{folder}: the packer stores quads only")
        src = meshes[0].V
        arrays[f"{g}/quads"] = np.asarray(polys, dtype=np.int32)
        arrays[f"{g}/source"] = np.round(src / SOURCE_STEP).astype(np.int32)
        back = arrays[f"{g}/source"] * SOURCE_STEP
        arrays[f"{g}/offsets"] = np.stack([np.round((m.V - back) / OFFSET_STEP) for m in meshes[1:]]
                                          ).astype(np.int16)
        done.append(g)
    for g, parts in kept.items():
        if g not in done:
            arrays.update({f"{g}/{k}": v for k, v in parts.items()})
            done.append(g)
    done.sort()
    meta = {"source": source, "targets": list(targets), "garments": done, "source_step": SOURCE_STEP,
            "offset_step": OFFSET_STEP, "drape_log": {g: drape[g] for g in done}, "units": "metres",
            "bodies": sorted(k[len("bodies/"):] for k in arrays if k.startswith("bodies/"))}
    arrays["metadata"] = np.array(json.dumps(meta))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    return meta


def read_packed(path=PACKED):
    """(metadata, {garment: (quads (p,4) int, {body: V (n,3) float64})}) of a packed file; the bodies
    it holds (``pack(..., with_bodies=True)``) are in ``metadata["body_vertices"]`` ({name: (n,3)})."""
    with np.load(path, allow_pickle=False) as npz:
        meta = json.loads(str(npz["metadata"]))
        meta["body_vertices"] = {b: npz[f"bodies/{b}"].astype(np.float64) * meta["source_step"]
                                 for b in meta.get("bodies", [])}
        out = {}
        for g in meta["garments"]:
            src = npz[f"{g}/source"].astype(np.float64) * meta["source_step"]
            shapes = {meta["source"]: src}
            for k, t in enumerate(meta["targets"]):
                shapes[t] = src + npz[f"{g}/offsets"][k].astype(np.float64) * meta["offset_step"]
            out[g] = (npz[f"{g}/quads"].astype(np.int64), shapes)
    return meta, out


def unpack(out, packed=PACKED, demo=DEMO_DATA, between=BETWEEN_PACKED):
    """A dataset folder: the demo's bodies and garments and the packed ones (training garments); with
    ``between`` (if that file exists) also the in-between bodies and the garments draped on them
    (manifest: ``between_bodies``, {name: [body, body, share of the second]})."""
    from .procedural.mannequin import BETWEEN

    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(demo, out)
    meta, garments = read_packed(packed)
    manifest = json.loads((out / "manifest.json").read_text())

    def write(g, quads, shapes):
        (out / "garments" / g).mkdir(parents=True, exist_ok=True)
        for body, V in shapes.items():
            path = out / "garments" / g / f"{body}.obj"
            if not path.exists():
                write_text_atomic(path, obj_text(mesh_from_polygons(V, quads), header=f"{g} draped on {body}",
                                                 digits=6))

    for g, (quads, shapes) in garments.items():
        write(g, quads, shapes)
    manifest["garments"] = list(manifest["garments"]) + list(garments)
    manifest["extra_garments"] = list(garments)
    if between is not None and Path(between).exists():
        bmeta, bgarments = read_packed(between)
        faces = read_obj(out / "bodies" / f"{manifest['source']}.obj").F
        for name, V in bmeta["body_vertices"].items():
            write_text_atomic(out / "bodies" / f"{name}.obj",
                              obj_text(mesh_from_polygons(V, faces), header=f"body between {BETWEEN[name]}", digits=7))
        for g, (quads, shapes) in bgarments.items():
            if g not in manifest["garments"]:
                raise ValueError(f"{between}: garment {g!r} is in neither the demo nor {packed}")
            write(g, quads, {b: V for b, V in shapes.items() if b != bmeta["source"]})
        manifest["bodies"] = list(manifest["bodies"]) + list(bmeta["body_vertices"])
        manifest["between_bodies"] = {b: list(BETWEEN[b]) for b in bmeta["body_vertices"]}
        manifest["between_garments"] = list(bgarments)
    write_json_atomic(out / "manifest.json", manifest)
    return list(garments)


def pack_between(work, packed, say):
    """``pack`` of the garments draped on the in-between bodies, with the bodies, into ``packed`` (or, where
    that is the extra garments' file, the default, into ``BETWEEN_PACKED``)."""
    from .procedural.mannequin import BETWEEN

    out = BETWEEN_PACKED if str(packed) == str(PACKED) else Path(packed)
    meta = pack(work, out, targets=tuple(BETWEEN), with_bodies=True)
    say(f"packed {len(meta['garments'])} garments on {', '.join(BETWEEN)} into {out}")
    return meta


def main(argv=None):
    from .procedural.garments import EXTRA_GARMENTS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("command", choices=["generate", "pack", "unpack", "between"])
    ap.add_argument("--work", default="/tmp/garment_transfer_extra")
    ap.add_argument("--garments", nargs="*",
                    help="default: the extra garments (generate, pack); test + all training garments (between)")
    ap.add_argument("--packed", default=str(PACKED))
    ap.add_argument("--out", default="/tmp/garment_transfer_demo_plus")
    ap.add_argument("--between", action="store_true",
                    help="pack: the garments draped on the in-between bodies (into data/extra/between.npz)")
    args = ap.parse_args(argv)

    def say(text):
        print(text, flush=True)

    if args.command == "between":
        from .procedural.garments import TEST_GARMENTS, TRAIN_GARMENTS
        from .procedural.mannequin import BETWEEN

        names = args.garments or list(TEST_GARMENTS) + list(TRAIN_GARMENTS) + list(EXTRA_GARMENTS)
        code = generate(args.work, names, say, targets=list(BETWEEN))
        pack_between(args.work, args.packed, say)
        return code
    args.garments = args.garments or list(EXTRA_GARMENTS)
    if args.command == "generate":
        code = generate(args.work, args.garments, say)
        meta = pack(args.work, args.packed)
        say(f"packed {len(meta['garments'])} garments into {args.packed}")
        return code
    if args.command == "pack" and args.between:
        pack_between(args.work, args.packed, say)
        return 0
    if args.command == "pack":
        meta = pack(args.work, args.packed)
        secs = [e["seconds"] for e in meta["drape_log"].values()]
        say(f"packed {len(meta['garments'])} garments into {args.packed}"
            + (f"; {np.mean(secs):.0f} s per garment draped" if secs else ""))
        return 0
    names = unpack(args.out, args.packed)
    say(f"wrote {args.out}: the demo and {len(names)} extra training garments: {', '.join(names)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
