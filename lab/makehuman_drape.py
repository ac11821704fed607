"""MakeHuman garments simulated by Blender's cloth solver: a reference that is not body-driven.

The MakeHuman fixtures' garments are placed on every body by MakeHuman's proxy fitting (each vertex a
barycentric point of three body vertices plus a scaled offset), which is a body-driven deformation,
the kind `direct` transfer itself makes. This drapes each fixture garment with Blender's cloth solver
(``operators/cloth.py``'s ``drape_garment``, the demo data's solver and settings) on the source body
``female_average``, then follows the body as it morphs into each target body, and writes the results
in the fixtures' own layout, units and axes (decimetres, Y up), so any study that reads the fixtures
reads these instead (``GARMENT_TRANSFER_MAKEHUMAN=DIR``).

The bodies are copied unchanged; ``garments/<garment>/<body>.obj`` is the garment settled on that body
(on ``female_average`` too: the simulated garment replaces the proxy fit there, so source and targets
are one simulation). Garments are simulated in metres, Z up (the solver's gravity and collision
distances are physical). Pinned: the garment vertices in contact with the body (within 1 cm) around
the waist (52% to 62% of the body's height from the soles), so trousers hold on the hips, and a
separate piece with none of those (a belt) around the waist; pinned vertices follow the body as it
morphs. Tops hang on the shoulders.

Run (needs the ``bpy`` module; the project's ``.venv`` has it)::

    nice python -m lab.makehuman_drape --out DIR [--garments g1 g2 ...] [--targets b1 b2 ...] \
        [--continuous] [--source-frames 30] [--morph-frames 15] [--frames 15]

``--continuous``: each target is one simulation from the start (the source settling, then the morph),
not a restart from the garment settled on the source body; a restart moves the settled garment even on
an unchanged body (its legs and hems sag a few millimetres more), which no transfer can predict from the
body's change (``operators/cloth.py``, ``drape_garment``'s ``continuous``). It costs the source frames
again for every target.

``--figure PNG`` also renders the first garment on the source body and on the last target, MakeHuman's
proxy fit beside the simulation (Cycles on the CPU, ``lab/blender/render_columns.py``).

Each garment is written as soon as it is done (atomically), and a garment already written is skipped,
so an interrupted run continues where it stopped; a folder draped with other simulation settings is
refused. ``DIR/drape_log.json`` records seconds, vertices, the settings and the penetration fix per garment,
and how far the garment slid off the shoulders on each target (``shoulder_drops``); a drape that slid further
than ``SLID_SHARE`` of the body's height has failed (the run says so, and the MakeHuman study leaves the garment
out: ``failed_drapes``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from garment_transfer.geometry.obj import obj_text, read_obj, write_text_atomic
from garment_transfer.geometry.proximity import TriangleSurface

from .paths import MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, SHARED_MAKEHUMAN, makehuman_folder

METRES_PER_UNIT = 0.1           # the fixtures are in decimetres
PIN_BAND = (0.52, 0.62)         # share of the body's height from the soles: the waist and hips
PIN_CONTACT = 0.01              # metres from the body
LOOSE_SUFFIX = "_loose"         # a looser cut of a fixture garment (--loose)
LOOSE_FADE = 0.05               # metres from the pinned vertices over which the ease of a looser cut fades in
#: drape_garment's frames on the source body, of each morph, of settling after it, and whether each target
#: is one simulation from the start (see the module's text).
SIMULATION = {"source_frames": 30, "morph_frames": 15, "frames": 15, "continuous": False}


def to_blender(V):
    """Fixture coordinates (decimetres, Y up, +Z forward) to metres, Z up, -Y forward."""
    V = np.asarray(V, dtype=np.float64) * METRES_PER_UNIT
    return np.column_stack([V[:, 0], -V[:, 2], V[:, 1]])


def from_blender(V):
    V = np.asarray(V, dtype=np.float64) / METRES_PER_UNIT
    return np.column_stack([V[:, 0], V[:, 2], -V[:, 1]])


def waist_pins(G, F, body_V, body_F):
    """Pinned garment vertices (metres, Z up): those within PIN_CONTACT of the body inside PIN_BAND of its
    height; a separate piece of the garment with none of those (a belt on a skirt) has its vertices
    inside the band pinned, or else its tenth nearest the body, so that no piece falls off."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    z = body_V[:, 2]
    share = (G[:, 2] - z.min()) / np.ptp(z)
    band = (share >= PIN_BAND[0]) & (share <= PIN_BAND[1])
    d = np.abs(TriangleSurface(body_V, body_F).signed_distance(G)[0])
    pinned = band & (d <= PIN_CONTACT)
    n = G.shape[0]
    edges = coo_matrix((np.ones(F.size), (F.ravel(), np.roll(F, 1, axis=1).ravel())), shape=(n, n))
    pieces = connected_components(edges, directed=False)[1]
    for p in np.unique(pieces):
        piece = pieces == p
        if pinned[piece].any():
            continue
        if (piece & band).any():
            pinned |= piece & band
        else:
            idx = np.flatnonzero(piece)
            pinned[idx[d[idx] <= np.quantile(d[idx], 0.1)]] = True
    return np.flatnonzero(pinned)


#: A drape has failed where a piece that reaches the shoulders has its top slid further than this share of the
#: target body's height below where the body carries it (lab/notes/garment-model-study.md, "A failed drape in the
#: data").
SLID_SHARE = 0.03
#: The top of a piece: its highest share of vertices; a piece reaches the shoulders where that lies above this
#: share of the source body's height from the soles.
TOP_SHARE, SHOULDER_SHARE = 0.05, 0.75


def shoulder_drops(source_body, garment, target_bodies, drapes):
    """How far a garment slid off the shoulders on each target body: over the pieces of ``garment`` (on
    ``source_body``) that reach the shoulders, the largest drop of a piece's top (its highest ``TOP_SHARE`` of
    vertices) in the drape below where the body carries it, over the target body's height; 0 where no piece
    dropped (or none reaches the shoulders). Fixture axes (Y up).

    Parameters
    ----------
    source_body, garment : Mesh
    target_bodies : list of Mesh
    drapes : list of (n,3) float
        The garment on each target body.

    Returns
    -------
    list of float
    """
    from garment_transfer.geometry.binding import bind, carry
    from garment_transfer.geometry.mesh import connected_pieces

    y0, height = source_body.V[:, 1].min(), np.ptp(source_body.V[:, 1])
    pieces = connected_pieces(garment.n_vertices, garment.F)[1]
    tops = []
    for p in np.unique(pieces[garment.F.reshape(-1)]):
        idx = np.flatnonzero(pieces == p)
        y = garment.V[idx, 1]
        top = idx[y >= np.quantile(y, 1.0 - TOP_SHARE)]
        if (garment.V[top, 1].mean() - y0) / height >= SHOULDER_SHARE:
            tops.append(top)
    binding = bind(garment.V, source_body.V, source_body.F)
    drops = []
    for body, draped in zip(target_bodies, drapes):
        fall = np.asarray(draped, dtype=np.float64)[:, 1] - carry(binding, body.V, source_body.F)[:, 1]
        drop = max([0.0] + [-float(fall[top].mean()) for top in tops])
        drops.append(drop / float(np.ptp(body.V[:, 1])))
    return drops


def slid(targets, drops):
    """{target: drop} for the drops past ``SLID_SHARE`` (a failed drape), rounded as the drape log keeps them."""
    return {t: round(d, 4) for t, d in zip(targets, drops) if d > SLID_SHARE}


def failed_drapes(dataset, source, targets, garments=None):
    """The drapes of a dataset folder where a garment slid off the shoulders (``shoulder_drops`` over
    ``SLID_SHARE``): {garment: {target: drop}}, only the garments with one."""
    body, bodies = dataset.body(source), [dataset.body(t) for t in targets]
    failed = {}
    for g in garments or dataset.garments:
        drops = shoulder_drops(body, dataset.garment(g, source), bodies, [dataset.garment(g, t).V for t in targets])
        if slid(targets, drops):
            failed[g] = slid(targets, drops)
    return failed


def other_settings(log, sim, log_path):
    """The refusal when ``log`` (a folder's drape log) records garments draped with other settings than
    ``sim``, else None."""
    other = sorted(g for g, e in log.items() if e.get("simulation", dict(SIMULATION)) != sim)
    if not other:
        return None
    return (f"{log_path} records {', '.join(other)} draped with other simulation settings "
            f"({log[other[0]].get('simulation', SIMULATION)}, not {sim}); give another --out")


def read_json(path):
    """A folder's JSON file (its manifest, its drape log) as a dict, {} when there is none."""
    path = Path(path)
    return json.loads(path.read_text()) if path.exists() else {}


def loose_variant(G, F, body_V, body_F, pins, ease, fade=LOOSE_FADE):
    """A looser cut of a garment (metres, Z up): every vertex moved away from the body by ``ease`` along the
    body's outward normal at its closest point (the directions averaged over the garment's edges, so neighbours
    move alike), fading to nothing within ``fade`` of the pinned vertices (the waistband stays where it was)."""
    from scipy.spatial import cKDTree

    from garment_transfer.geometry.penetration import vertex_adjacency

    normal = TriangleSurface(body_V, body_F).signed_distance(G)[2]
    A = vertex_adjacency(G.shape[0], F)
    degree = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)[:, None]
    for _ in range(10):
        normal = 0.5 * normal + 0.5 * (A @ normal) / degree
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-12)[:, None]
    near = cKDTree(G[pins]).query(G)[0] if len(pins) else np.full(G.shape[0], np.inf)
    return G + (ease * np.clip(near / fade, 0.0, 1.0))[:, None] * normal


def drape(folder, out, garment, targets, say, sim=None, mesh=None, pins=None, loose=None):
    """Drape ``garment`` on the source body and into ``targets``; ``sim``: the simulation settings
    (``SIMULATION``'s keys), the defaults where None. ``mesh``: the garment on the source body (the
    fixtures' units and axes), else read from ``folder``; ``pins``: the vertices to pin, else
    ``waist_pins``."""
    from .blender.make_demo_data import load_cloth

    cloth = load_cloth()
    bodies = {b: read_obj(folder / "bodies" / f"{b}.obj", name=b) for b in (MAKEHUMAN_SOURCE, *targets)}
    source = bodies[MAKEHUMAN_SOURCE]
    g = mesh if mesh is not None else read_obj(folder / "garments" / garment / f"{MAKEHUMAN_SOURCE}.obj",
                                               name=garment)
    bV = to_blender(source.V)
    gV = to_blender(g.V)
    pins = waist_pins(gV, g.F, bV, source.F) if pins is None else np.asarray(pins, np.int64)
    original = garment
    if loose is not None:
        gV = loose_variant(gV, g.F, bV, source.F, pins, loose)
        garment = f"{original}{LOOSE_SUFFIX}"
        g = g.with_vertices(from_blender(gV), name=garment)
    report = []
    t = time.perf_counter()
    sim = dict(SIMULATION, **(sim or {}))
    shapes = cloth.drape_garment(gV, g.polygons(), bV, source.F, [to_blender(bodies[b].V) for b in targets],
                                 pin_group=pins, report=report, **sim)
    secs = time.perf_counter() - t
    dest = out / "garments" / garment
    dest.mkdir(parents=True, exist_ok=True)
    # The targets first, the source last: a garment folder with its source file is complete.
    for body, S in list(zip(targets, shapes[1:])) + [(MAKEHUMAN_SOURCE, shapes[0])]:
        write_text_atomic(dest / f"{body}.obj",
                          obj_text(g.with_vertices(from_blender(S)),
                                   header=f"{garment} draped by Blender's cloth solver on {body} "
                                          f"(lab.makehuman_drape)", digits=7))
    drops = shoulder_drops(source, g.with_vertices(from_blender(shapes[0])), [bodies[b] for b in targets],
                           [from_blender(S) for S in shapes[1:]])
    entry = {"garment": garment, "vertices": int(g.n_vertices), "pinned": int(pins.size), "simulation": sim,
             **({} if loose is None else {"variant_of": original, "ease": loose}),
             "seconds": round(secs, 1), "inside_before_fix": [r["inside_before"] for r in report],
             "inside_after_fix": [r["inside_after"] for r in report],
             "shoulder_drop": [round(d, 4) for d in drops]}
    say(f"{garment}: {g.n_vertices} vertices, {pins.size} pinned, {secs:.1f}s, inside before/after the fix "
        f"{entry['inside_before_fix']}/{entry['inside_after_fix']}")
    failed = slid(targets, drops)
    if failed:
        say(f"{garment}: FAILED on {', '.join(f'{b} ({100 * d:.1f}% of its height)' for b, d in failed.items())}: "
            "slid off the shoulders; lab.garment_model leaves it out")
    return entry


def figure(folder, out, garment, target, png):
    """MakeHuman's proxy fit and the simulation of ``garment``, on the source body and on ``target``."""
    def column(label, body, kind, garments):
        return {"label": label, "meshes": [{"obj": str(folder / "bodies" / f"{body}.obj"), "kind": "body",
                                            "scale": METRES_PER_UNIT, "up": "Y"}]
                + [{"obj": str(g / "garments" / garment / f"{body}.obj"), "kind": kind,
                    "scale": METRES_PER_UNIT, "up": "Y"} for g in garments]}

    spec = {"size": [1600, 560], "columns": [
        column("proxy fit, source", MAKEHUMAN_SOURCE, "source", [folder]),
        column("simulated, source", MAKEHUMAN_SOURCE, "simulation", [out]),
        column("proxy fit, target", target, "source", [folder]),
        column("simulated, target", target, "simulation", [out])]}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "spec.json"
        path.write_text(json.dumps(spec))
        return subprocess.run([sys.executable, "-m", "lab.blender.render_columns", "--spec", str(path),
                               "--out", str(png)]).returncode


def simulation_arguments(ap):
    """The command line's simulation settings (``SIMULATION``'s keys)."""
    ap.add_argument("--source-frames", type=int, default=SIMULATION["source_frames"],
                    help="frames to settle on the source body")
    ap.add_argument("--morph-frames", type=int, default=SIMULATION["morph_frames"], help="frames of each morph")
    ap.add_argument("--frames", type=int, default=SIMULATION["frames"], help="frames to settle after each morph")
    ap.add_argument("--continuous", action="store_true",
                    help="each target one simulation from the start (source settling, morph), no restart")


def output_folder(ap, args, folder):
    """``--out`` checked (not the fixtures' folder ``folder``) and made, with the source and target bodies
    copied from ``folder``; the simulation settings checked. Returns (out, settings)."""
    out = Path(args.out)
    if out.resolve() == Path(folder).resolve():
        ap.error(f"--out {out} is the fixtures' own folder; give another")
    for key in ("source_frames", "morph_frames", "frames"):
        if getattr(args, key) < 1:
            ap.error(f"--{key.replace('_', '-')} must be at least 1")
    sim = {"source_frames": args.source_frames, "morph_frames": args.morph_frames, "frames": args.frames,
           "continuous": args.continuous}
    (out / "bodies").mkdir(parents=True, exist_ok=True)
    for b in (MAKEHUMAN_SOURCE, *args.targets):
        if not (out / "bodies" / f"{b}.obj").exists():
            shutil.copyfile(Path(folder) / "bodies" / f"{b}.obj", out / "bodies" / f"{b}.obj")
    return out, sim


def main(argv=None):
    folder = makehuman_folder() or SHARED_MAKEHUMAN
    manifest = json.loads((folder / "manifest.json").read_text())
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the simulated fixtures")
    ap.add_argument("--garments", nargs="+", default=manifest["garments"])
    ap.add_argument("--targets", nargs="+", default=list(MAKEHUMAN_TARGETS))
    ap.add_argument("--figure", help="PNG: the first garment, proxy fit and simulation, source and last target")
    ap.add_argument("--loose", type=float, metavar="METRES",
                    help="drape a looser cut of each garment instead (<garment>_loose: this much ease, the "
                         "waistband kept), a garment of its own that the study never trains on with the original "
                         "held out")
    simulation_arguments(ap)
    args = ap.parse_args(argv)
    if args.loose is not None and not 0.0 < args.loose <= 0.05:
        ap.error(f"--loose {args.loose}: give the ease in metres, more than 0 and at most 0.05")
    out, sim = output_folder(ap, args, folder)
    t0 = time.perf_counter()

    def say(text):
        print(f"[{time.perf_counter() - t0:7.1f}s] {text}", flush=True)

    log_path = out / "drape_log.json"
    log = read_json(log_path)
    problem = other_settings(log, sim, log_path)
    if problem:
        ap.error(problem)
    for garment in args.garments:
        name = garment if args.loose is None else garment + LOOSE_SUFFIX
        if (out / "garments" / name / f"{MAKEHUMAN_SOURCE}.obj").exists() and name in log:
            say(f"{name}: already draped, skipped")
            continue
        log[name] = drape(folder, out, garment, args.targets, say, sim, loose=args.loose)
        write_text_atomic(log_path, json.dumps(log, indent=1) + "\n")
    done = [g for g in manifest["garments"] if g in log]        # every garment draped so far
    variants = {g: e["variant_of"] for g, e in log.items() if "variant_of" in e}
    # Garments another command added to this folder (lab.makehuman_procedural) stay listed.
    extra = read_json(out / "manifest.json").get("procedural_garments", [])
    m = dict(manifest, bodies=[MAKEHUMAN_SOURCE, *args.targets], garments=done + list(variants) + extra,
             **({"procedural_garments": extra} if extra else {}), **({"variants": variants} if variants else {}),
             placed_by="Blender's cloth solver (lab.makehuman_drape), from MakeHuman's proxy fit on "
                       f"{MAKEHUMAN_SOURCE}", simulation=sim)
    write_text_atomic(out / "manifest.json", json.dumps(m, indent=1) + "\n")
    if (folder / "LICENSE.md").exists():
        shutil.copyfile(folder / "LICENSE.md", out / "LICENSE.md")
    say(f"wrote {out}: {len(done)} garments")
    if args.figure:
        return figure(folder, out, args.garments[0], args.targets[-1], args.figure)
    return 0


if __name__ == "__main__":
    sys.exit(main())
