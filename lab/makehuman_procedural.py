"""Procedural garments on the MakeHuman bodies, draped by Blender's cloth solver: more garments to learn from.

The MakeHuman fixtures hold 8 garments; leaving one out for a test leaves 7 to train on. This carries
garments of the procedural catalogue (``lab/procedural``, built on the demo's ``banana`` mannequin) onto the
MakeHuman source body ``female_average`` with the product's own transfer to any body
(``garment_transfer.registration.transfer_to_any_body``: the mannequin registered onto the MakeHuman body,
then the transfer), and drapes each as ``lab.makehuman_drape`` drapes the fixtures' garments: settled on the
source body, then following it into each target body (same solver and settings), pinned where the catalogue
pins it (waistband, top band). The results go into a folder ``lab.makehuman_drape`` wrote (or a new one), in
the fixtures' layout, units and axes, and are listed in its manifest under ``garments`` and
``procedural_garments``: the MakeHuman study (``lab.garment_model --parts makehuman``, with
``--makehuman-garments`` naming the fixture garments to hold out) then trains every fold on them too.

``OUTFITS`` are a top and a bottom of the catalogue in one mesh (two pieces), draped as the fixture suits are:
pinned at the waist and hips (``makehuman_drape.waist_pins``), the top tucked in; the catalogue's own tops hang
from the shoulders. The manifest lists their pieces under ``outfits`` (a validation fold holding out a piece's
style holds out its outfits too).

    nice python -m lab.makehuman_procedural --out DIR [--garments g1 g2 ...] [--continuous] \
        [--source-frames 30] [--morph-frames 15] [--frames 15]

The simulation settings must be those of the garments already in ``DIR`` (else refused). Each garment is
written as soon as it is done (atomically) and a garment already there is skipped, so an interrupted run
continues (a garment claimed by a run that was stopped is draped again); two runs may share a folder (the log
and manifest are updated under a lock), which is how the 2-core machines drape two garments at a time.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from garment_transfer.geometry.obj import read_obj, write_text_atomic

from .makehuman_drape import drape, other_settings, output_folder, read_json, simulation_arguments
from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, SHARED_MAKEHUMAN

#: The catalogue's garments carried onto the MakeHuman bodies by default: trousers, shorts and tops of every
#: fit (the fixture garments are suits: trousers or shorts and shirts), and skirts and dresses for variety.
GARMENTS = ("trousers", "trousers_loose", "trousers_tight", "culottes", "culottes_loose", "culottes_tight",
            "bermudas", "wide_trousers", "shorts", "tank_top", "tank_top_loose", "tank_top_tight", "sweater",
            "sweater_loose", "sweater_tight", "crop_top", "long_sleeve_top", "tunic", "tshirt",
            "straight_skirt", "aline_skirt", "pencil_skirt", "mini_skirt", "shift_dress")
#: Two-piece outfits of the catalogue's tops and bottoms, each draped as one garment as the fixture suits are
#: (trousers or shorts and a shirt in one mesh): pinned at the waist and hips (``makehuman_drape.waist_pins``), the
#: top tucked in, where the catalogue's own tops hang from the shoulders.
OUTFITS = {
    "outfit_tshirt_trousers": ("tshirt", "trousers"),
    "outfit_long_sleeve_top_trousers": ("long_sleeve_top", "trousers"),
    "outfit_sweater_trousers": ("sweater", "trousers"),
    "outfit_tank_top_trousers": ("tank_top", "trousers"),
    "outfit_tshirt_shorts": ("tshirt", "shorts"),
    "outfit_tank_top_shorts": ("tank_top", "shorts"),
    "outfit_long_sleeve_top_bermudas": ("long_sleeve_top", "bermudas"),
    "outfit_tshirt_bermudas": ("tshirt", "bermudas"),
    "outfit_sweater_loose_trousers_loose": ("sweater_loose", "trousers_loose"),
    "outfit_tank_top_tight_trousers_tight": ("tank_top_tight", "trousers_tight"),
    "outfit_long_sleeve_top_wide_trousers": ("long_sleeve_top", "wide_trousers"),
    "outfit_sweater_tight_culottes": ("sweater_tight", "culottes"),
}
#: The mannequin the catalogue is built on.
MANNEQUIN = "banana"


@contextlib.contextmanager
def locked(folder):
    """Hold ``folder/.lock`` (an exclusive lock) while the folder's log and manifest are read and written."""
    import fcntl

    with open(Path(folder) / ".lock", "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def claimed_elsewhere(path):
    """Whether the claim file ``path`` names another process that is still running."""
    try:
        pid = int(Path(path).read_text())
    except (OSError, ValueError):
        return False
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def fit(name, mannequin, body, registration=None):
    """The catalogue's garment ``name`` on the MakeHuman source body ``body`` (decimetres, Y up), from the
    ``mannequin`` it is built on.

    Returns
    -------
    mesh : Mesh
        The garment (the catalogue's vertex order and quads).
    pins : (k,) int64
        The catalogue's pinned vertices.
    info : dict
        Vertices inside the body after the transfer, the registration's fit.
    registration : Registration
        For the next garment.
    """
    from garment_transfer.geometry.mesh import mesh_from_polygons
    from garment_transfer.pipeline.any_body import transfer_to_any_body

    from .procedural.garments import garment

    g = garment(name)
    mesh = mesh_from_polygons(g.V, g.polygons, name=name)
    result, registration = transfer_to_any_body(mannequin, body, mesh, registration=registration)
    q = registration.quality
    info = {"inside_after_transfer": int(result.penetrating_vertices),
            "registration_rms_share": round(float(q["rms"]) / float(q["height"]), 6)}
    return mesh.with_vertices(result.V, name=name), g.pin, info, registration


def fit_outfit(name, mannequin, body, registration=None):
    """The outfit ``name`` (``OUTFITS``) on the MakeHuman source body: its pieces carried as ``fit`` carries a
    garment, in one mesh (the top's vertices first). Returns ``fit``'s values, the pins None (the drape pins it
    at the waist, as the fixture suits)."""
    from garment_transfer.geometry.mesh import mesh_from_polygons

    meshes, infos = [], []
    for part in OUTFITS[name]:
        mesh, _, info, registration = fit(part, mannequin, body, registration)
        meshes.append(mesh)
        infos.append(info)
    start = np.cumsum([0] + [m.n_vertices for m in meshes])
    polygons = [p + s for m, s in zip(meshes, start) for p in m.polygons()]
    mesh = mesh_from_polygons(np.vstack([m.V for m in meshes]), polygons, name=name)
    info = {"inside_after_transfer": sum(i["inside_after_transfer"] for i in infos),
            "registration_rms_share": infos[0]["registration_rms_share"], "pieces": list(OUTFITS[name])}
    return mesh, None, info, registration


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="the folder (lab.makehuman_drape's, or a new one)")
    ap.add_argument("--garments", nargs="+", default=list(GARMENTS), help="catalogue garments or outfits (OUTFITS)")
    ap.add_argument("--targets", nargs="+", default=list(MAKEHUMAN_TARGETS))
    simulation_arguments(ap)
    args = ap.parse_args(argv)
    from .procedural.garments import EXTRA_GARMENTS, TEST_GARMENTS, TRAIN_GARMENTS

    known = set(TRAIN_GARMENTS) | set(TEST_GARMENTS) | set(EXTRA_GARMENTS) | set(OUTFITS)
    unknown = [g for g in args.garments if g not in known]
    if unknown:
        ap.error(f"--garments: not in the procedural catalogue or its outfits: {', '.join(unknown)}")
    fixtures = json.loads((SHARED_MAKEHUMAN / "manifest.json").read_text())
    out, sim = output_folder(ap, args, SHARED_MAKEHUMAN)
    log_path = out / "drape_log.json"
    with locked(out):
        problem = other_settings(read_json(log_path), sim, log_path)
    if problem:
        ap.error(problem)
    t0 = time.perf_counter()

    def say(text):
        print(f"[{time.perf_counter() - t0:7.1f}s] {text}", flush=True)

    registration = None
    mannequin = read_obj(DEMO_DATA / "bodies" / f"{MANNEQUIN}.obj", name=MANNEQUIN)
    body = read_obj(SHARED_MAKEHUMAN / "bodies" / f"{MAKEHUMAN_SOURCE}.obj", name=MAKEHUMAN_SOURCE)
    for name in args.garments:
        dest = out / "garments" / name
        # A run sharing the folder claims a garment (its process id in a claim file) before draping it; the
        # claim of a run that was stopped (its process gone) is taken over.
        with locked(out):
            log = read_json(log_path)
            if name in log or claimed_elsewhere(dest / ".claimed"):
                say(f"{name}: already draped or being draped, skipped")
                continue
            dest.mkdir(parents=True, exist_ok=True)
            (dest / ".claimed").write_text(str(os.getpid()))
        try:
            mesh, pins, info, registration = (fit_outfit if name in OUTFITS else fit)(name, mannequin, body,
                                                                                      registration)
            say(f"{name}: on {MAKEHUMAN_SOURCE}, {info['inside_after_transfer']} vertices inside after the transfer")
            entry = drape(SHARED_MAKEHUMAN, out, name, args.targets, say, sim, mesh=mesh, pins=pins)
        finally:
            (dest / ".claimed").unlink(missing_ok=True)
        entry.update(info, procedural=True, mannequin=MANNEQUIN)
        with locked(out):
            log = read_json(log_path)
            log[name] = entry
            write_text_atomic(log_path, json.dumps(log, indent=1) + "\n")
            m = read_json(out / "manifest.json") or dict(fixtures, garments=[],
                                                         bodies=[MAKEHUMAN_SOURCE, *args.targets],
                                                         placed_by="Blender's cloth solver", simulation=sim)
            extra = list(dict.fromkeys(m.get("procedural_garments", []) + [name]))
            m.update(garments=list(dict.fromkeys(m["garments"] + [name])), procedural_garments=extra)
            if name in OUTFITS:
                m["outfits"] = dict(m.get("outfits", {}), **{name: list(OUTFITS[name])})
            write_text_atomic(out / "manifest.json", json.dumps(m, indent=1) + "\n")
    say(f"done: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
