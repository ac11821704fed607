"""Which mixes of the shape-key study still cross with keep outside on, where, and why (issue 36).

Run: ``python -m lab.shape_keys_mixes [--combinations 50] [--garment female_casualsuit01] [--remedies]``.

The study's body, keys and slider settings (``lab.shape_keys``); the garment's keys fitted once. For every mix in
which, after ``keep_outside_banded`` (the Shrinkwrap stack of the operator), a garment edge passes through a body
triangle or a body edge through a garment triangle under some triangulation, it prints each crossing edge: which
way, where on the body (the nearest body vertex's height as a share of the body's height, its height band, left
or right, front or back), the garment vertices involved (their bands, or "no band" where the Shrinkwrap would
misjudge them at a key at 1), how deep (the edge's deepest sample inside the blended body, exact sign) and the
Shrinkwrap's own reading of those vertices at the mix, and the edges through away from where that body crosses
itself (the pose fit's rule). With ``--remedies``, the candidate remedies of ``REMEDIES`` measured as
``lab.shape_keys`` measures (mixes crossing, key at 1 moved, distance to the exact transfer), each with the lift of
the mix (``shape_keys.mix_lift``, the default) and without.
"""

from __future__ import annotations

import argparse

import numpy as np

from garment_transfer.geometry.intersections import crossings, self_intersections
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.geometry.readings import readings_of
from garment_transfer.pipeline.shape_keys import (KEEP_OUTSIDE_BANDS, SHAPE_KEY_BANDS, body_at, fit_shape_keys,
                                                  keep_outside_banded, keep_outside_bands, shrinkwrap_distance)
from garment_transfer.pipeline.pose_fit import CONTACT_GAP, CONTACT_RINGS, crossing_counts, every_split, self_contact
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

from .paths import MAKEHUMAN_SOURCE, makehuman_folder
from .shape_keys import BANDS, MM, body_with_keys, combinations

SAMPLES = 17                   # points along an edge to find its deepest point inside the body
#: Candidate bands (shares of the transfer's offset) for ``keep_outside_bands``: three up to the offset
#: (``KEEP_OUTSIDE_BANDS``, Rig to Body's), bands above the offset (vertices that the basis and every key at 1 hold
#: farther out than the offset kept that far; ``SHAPE_KEY_BANDS`` is the default), and a fine ladder up to three
#: offsets (near the per-vertex limit of the rule).
REMEDIES = {"three to the offset (0.5, 0.75, 1)": KEEP_OUTSIDE_BANDS,
            "above the offset (..., 1.25, 1.5, 2)": (0.5, 0.75, 1.0, 1.25, 1.5, 2.0),
            "default (..., 1.1, 1.2, 1.35, 1.5, 2)": SHAPE_KEY_BANDS,
            "fine ladder to 3 offsets (26 bands)": tuple(np.round(np.linspace(0.5, 3.0, 26), 3))}


def setup(folder, garment_name, count=50, seed=0, exact=False):
    """The study's body, keys, mixes and the garment's fitted keys (and the exact transfers when asked)."""
    basis, shapes = body_with_keys(folder)
    combos = combinations(shapes, count, seed)
    bodies = [body_at(basis.V, shapes, w) for w in combos]
    garment = read_obj(folder / "garments" / garment_name / f"{MAKEHUMAN_SOURCE}.obj", name=garment_name)
    prepared = prepare_garment(basis, garment)
    fit = fit_shape_keys(basis, shapes, garment, prepared=prepared)
    ex = ([transfer_garment(basis, basis.with_vertices(V), garment, prepared=prepared).V for V in bodies]
          if exact else None)
    return {"basis": basis, "shapes": shapes, "combos": combos, "bodies": bodies, "garment": garment,
            "fit": fit, "exact": ex, "surfaces": [TriangleSurface(V, basis.F) for V in bodies]}


def region(body_V, i):
    """Where body vertex ``i`` is: height share, height band, side, front or back."""
    y = body_V[:, 1]
    h = (body_V[i, 1] - y.min()) / (y.max() - y.min())
    band = next(b for b, (lo, hi) in BANDS.items() if (lo is None or h >= lo) and (hi is None or h < hi))
    cx, cz = np.median(body_V[:, 0]), np.median(body_V[:, 2])
    return (f"h {h:.3f} {band:5s} {'left' if body_V[i, 0] > cx else 'right'} "
            f"{'front' if body_V[i, 2] > cz else 'back'}")


def edge_depth(P0, P1, surface):
    """The deepest sample of segment P0-P1 inside the body (exact sign), 0 when none is inside."""
    t = np.linspace(0.0, 1.0, SAMPLES)[:, None]
    sd = surface.signed_distance(P0 * (1 - t) + P1 * t)[0]
    return float(max(0.0, -sd.min()))


def band_names(bands, v):
    """The bands (distances in mm) that keep garment vertex ``v``, or "no band"."""
    names = [f"{d / MM:.2f}" for d, only in bands if only[v]]
    return ",".join(names) if names else "no band"


def diagnose(s, bands, verbose=True):
    """One line per crossing edge of every crossing mix; returns a summary per mix."""
    basis, garment = s["basis"], s["garment"]
    G, B = readings_of(garment), readings_of(basis)
    fit = s["fit"]
    out = []
    for k, (w, surface, body) in enumerate(zip(s["combos"], s["surfaces"], s["bodies"])):
        V = keep_outside_banded(fit.blend(w), surface, bands)
        c = crossings(V, G, body, B)
        n = c["a_edges_through_b"] + c["b_edges_through_a"]
        if not n:
            continue
        sw = shrinkwrap_distance(V, surface)[0]
        sd = surface.signed_distance(V)[0]
        mix = ", ".join(f"{name} {x:.2f}" for name, x in w.items())
        print(f"\nmix {k}: {mix}\n  {c['a_edges_through_b']} garment edges through the body "
              f"({c['a_edge_pairs']} pairs), {c['b_edges_through_a']} body edges through the garment "
              f"({c['b_edge_pairs']} pairs); {int((sd < 0).sum())} garment vertices inside after the stack; "
              f"the body crosses itself {self_intersections(body, basis.F)[0]} times (the basis "
              f"{self_intersections(basis.V, basis.F)[0]})")
        away = away_from_contact(V, s, body)
        print(f"  away from where this body crosses itself or closes on itself (the pose fit's rule: "
              f"{away['contact_vertices']} body vertices of contact): {away['edges']} edges through")
        if s["exact"] is not None:
            e = crossings(s["exact"][k], G, body, B)
            print(f"  the exact transfer to this body: {e['a_edges_through_b']} garment edges through the body, "
                  f"{e['b_edges_through_a']} body edges through the garment")
        rows = []
        for (i, j) in np.unique(np.sort(c["a_pairs"], axis=1), axis=0):
            depth = edge_depth(V[i], V[j], surface)
            near = int(np.argmin(np.linalg.norm(body - (V[i] + V[j]) / 2, axis=1)))
            rows.append(("garment edge", i, j, depth, near))
            if verbose:
                print(f"  garment edge {i}-{j} ({np.linalg.norm(V[i] - V[j]) / MM:.1f} mm): deepest "
                      f"{depth / MM:.2f} mm inside; {region(body, near)}; vertices: "
                      f"{i} [{band_names(bands, i)}] sd {sd[i] / MM:+.2f} mm shrinkwrap {sw[i] / MM:+.2f} mm, "
                      f"{j} [{band_names(bands, j)}] sd {sd[j] / MM:+.2f} mm shrinkwrap {sw[j] / MM:+.2f} mm")
        gsurf = TriangleSurface(V, garment.F)
        for (i, j), tri in zip(c["b_pairs"], c["b_triangles"]):
            gv = G.F[tri]
            t = np.linspace(0.0, 1.0, SAMPLES)[:, None]
            # How far the body edge reaches beyond the garment: its samples' distance to the garment surface.
            reach = float(gsurf.closest(body[i] * (1 - t) + body[j] * t)[1].max())
            rows.append(("body edge", i, j, reach, i))
            if verbose:
                print(f"  body edge {i}-{j} ({np.linalg.norm(body[i] - body[j]) / MM:.1f} mm) through garment "
                      f"triangle {tuple(int(x) for x in gv)}: {region(body, i)}; reaches {reach / MM:.2f} mm "
                      "from the garment; triangle's vertices: " + ", ".join(
                          f"{v} [{band_names(bands, v)}] sd {sd[v] / MM:+.2f} shrinkwrap {sw[v] / MM:+.2f}"
                          for v in gv))
        out.append({"mix": k, "garment_edges": c["a_edges_through_b"], "body_edges": c["b_edges_through_a"],
                    "away_from_contact": away["edges"], "rows": rows})
    away = [m["mix"] for m in out if m["away_from_contact"]]
    print(f"\n{len(out)} of {len(s['combos'])} mixes cross {[m['mix'] for m in out]}; away from where the mixed "
          f"body crosses itself or closes on itself: {len(away)} {away}")
    return out


def away_from_contact(V, s, body):
    """Edges through (both ways, under every split of both meshes) of garment positions V on the mixed body, away
    from where that body crosses itself or two of its parts press together that were apart on the basis: the pose
    fit's rule (``pose_fit.self_contact`` with the basis as the rest shape, ``CONTACT_RINGS`` rings, a gap of
    ``CONTACT_GAP`` offsets), where no garment can be outside both surfaces."""
    basis, garment = s["basis"], s["garment"]
    offset = s["fit"].info["Basis"]["offset"]
    contact, _ = self_contact(body, basis.F, CONTACT_RINGS, basis.V, CONTACT_GAP * offset)
    body_F = every_split(basis)
    free = body_F[~contact[body_F].any(axis=1)]
    return {"edges": int(sum(crossing_counts(V, every_split(garment), body, free))),
            "contact_vertices": int(contact.sum())}


def measure(s, rule, lift=True):
    """Mixes crossing, key at 1 moved (mm) and mean distance to the exact transfer (mm) of ``rule(V, surface)`` on
    the blend (with the lift of the mix, ``shape_keys.mix_lift``, or without)."""
    fit, basis, shapes = s["fit"], s["basis"], s["shapes"]
    G, B = readings_of(s["garment"]), readings_of(basis)
    moved = max(float(np.linalg.norm(rule(fit.keys[k], TriangleSurface(V, basis.F)) - fit.keys[k], axis=1).max())
                for k, V in shapes.items())
    moved = max(moved, float(np.linalg.norm(rule(fit.basis, TriangleSurface(basis.V, basis.F)) - fit.basis,
                                            axis=1).max()))
    crossing, edges, error = [], [], []
    for k, (w, surface, body) in enumerate(zip(s["combos"], s["surfaces"], s["bodies"])):
        V = rule(fit.blend(w, lift=lift), surface)
        c = crossings(V, G, body, B)
        n = c["a_edges_through_b"] + c["b_edges_through_a"]
        if n:
            crossing.append(k)
            edges.append(n)
        if s["exact"] is not None:
            error.append(float(np.linalg.norm(V - s["exact"][k], axis=1).mean()))
    return {"crossing": crossing, "edges": edges, "key_moved_mm": moved / MM,
            "to_exact_mm": float(np.mean(error)) / MM if error else float("nan")}


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.shape_keys_mixes", description=__doc__.split("\n")[0])
    p.add_argument("--combinations", type=int, default=50)
    p.add_argument("--garment", default="female_casualsuit01")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--remedies", action="store_true")
    args = p.parse_args(argv)
    folder = makehuman_folder()
    if folder is None:
        print("The MakeHuman fixtures are missing (../shared/data/makehuman); nothing to measure.")
        return 1
    s = setup(folder, args.garment, args.combinations, args.seed, exact=args.remedies)
    bands = keep_outside_bands(s["fit"], s["basis"], s["shapes"])
    offset = s["fit"].info["Basis"]["offset"]
    print(f"offset {offset / MM:.2f} mm; bands: " + "; ".join(
        f"{d / MM:.2f} mm keeps {int(only.sum())}" for d, only in bands)
        + f"; {int((~bands[0][1]).sum())} of {len(s['garment'].V)} vertices in no band")
    diagnose(s, bands)
    if args.remedies:
        print("\nremedy: mixes crossing (edges each), key at 1 or basis moved, mean distance to the exact transfer")
        for label, shares in REMEDIES.items():
            b = keep_outside_bands(s["fit"], s["basis"], s["shapes"], bands=shares)
            for lift in (True, False):
                m = measure(s, lambda V, surface, b=b: keep_outside_banded(V, surface, b), lift=lift)
                print(f"  {label:40s} {'with' if lift else 'without'} the lift: {len(m['crossing'])} of "
                      f"{len(s['combos'])} {m['crossing']} {m['edges']}; moved {m['key_moved_mm']:.4f} mm; "
                      f"to exact {m['to_exact_mm']:.3f} mm", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
