"""Shape keys for a garment: speed of fitting 10 keys with one preparation, and how linear blending of
the keys clips, with and without a remedy.

Run: ``python -m lab.shape_keys [--combinations 50] [--garments a,b] [--skip-bench] [--skip-study]``.

The body with shape keys is built from the MakeHuman fixtures (one topology): ``female_average`` is the
basis; each of ten keys is one height band (legs, hips, waist, chest and arms) of another body's
difference from it (pear, male, slim), faded over 2% of the height, like the hip, belly or chest sliders
of a character generator. Units are decimetres: 1 mm is 0.01.

Speed: a ~20K-vertex garment (``lab.bench.tube_dress``, 40K triangles) fitted to the 10 keys with one
preparation, beside 10 independent cold transfers (each preparing the garment again).

Blending study: random slider combinations of 3 to 6 keys with values in [0, 1]; for each, the linear
blend of the garment's keys against the body at that combination (share of garment vertices more than
1 mm inside), and the distance of the blend from a transfer to that exact body. Remedies: a margin
(every key transferred further from the body), corrective keys for every pair of keys, and keeping the
blend outside the body (``shape_keys.keep_outside``: what the operator's Shrinkwrap modifier does, at
half the offset, on the surface and at the whole offset; and per vertex, in bands, ``keep_outside_bands``: what
the operator's Shrinkwrap modifiers do, one per band; ``SHAPE_KEY_BANDS`` the default, ``KEEP_OUTSIDE_BANDS`` up to
the offset only; where the mixes that still cross do so: ``lab.shape_keys_mixes``). For each, the mixes in which a
garment edge passes through the body or a body edge through the garment under some triangulation of the faces
(``crossings`` under every reading), and the most it moves a vertex of a key at 1 (which must stay the transfer
to its shape).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.geometry.intersections import crossings
from garment_transfer.geometry.readings import readings_of
from garment_transfer.pipeline.shape_keys import (KEEP_OUTSIDE_BANDS, SHAPE_KEY_BANDS, all_pairs, body_at,
                                                  fit_shape_keys, keep_outside, keep_outside_banded,
                                                  keep_outside_bands)
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

from .paths import MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, makehuman_folder

MM = 0.01                      # one millimetre in the fixtures' decimetres
#: (key, body, band): each key is one height band of one body's difference from the basis.
BANDS = {"legs": (None, 0.45), "hips": (0.45, 0.58), "waist": (0.58, 0.68), "chest": (0.68, None)}
KEYS = (("pear_legs", "female_pear", "legs"), ("pear_hips", "female_pear", "hips"),
        ("pear_waist", "female_pear", "waist"), ("pear_chest", "female_pear", "chest"),
        ("male_legs", "male_average", "legs"), ("male_hips", "male_average", "hips"),
        ("male_waist", "male_average", "waist"), ("male_chest", "male_average", "chest"),
        ("slim_waist", "female_slim_banana", "waist"), ("slim_legs", "male_slim", "legs"))
STUDY_GARMENTS = ("female_casualsuit01",)


def band_weights(y, fade=0.02):
    """(n,) weights of each height band (a partition of unity over the body's height).

    Returns
    -------
    dict of str to (n,) float64
    """
    lo, hi = y.min(), y.max()
    h = (y - lo) / (hi - lo)

    def above(t):
        return 1.0 / (1.0 + np.exp(-(h - t) / fade))

    return {band: (above(a) if a is not None else 1.0) - (above(b) if b is not None else 0.0)
            for band, (a, b) in BANDS.items()}


def body_with_keys(folder):
    """The basis body and ten shape keys (absolute positions), one band of one body's difference each.

    Returns
    -------
    basis : Mesh
    shapes : dict of str to (n,3) float64
    """
    basis = read_obj(folder / "bodies" / f"{MAKEHUMAN_SOURCE}.obj", name=MAKEHUMAN_SOURCE)
    bodies = {name: read_obj(folder / "bodies" / f"{name}.obj").V for name in MAKEHUMAN_TARGETS}
    bands = band_weights(basis.V[:, 1])
    return basis, {key: basis.V + bands[band][:, None] * (bodies[body] - basis.V)
                   for key, body, band in KEYS}


def combinations(names, count, seed=0, fewest=3, most=6):
    """``count`` random slider settings: 3 to 6 keys, values uniform in [0, 1].

    Returns
    -------
    list of dict of str to float
    """
    rng = np.random.default_rng(seed)
    names = list(names)
    out = []
    for _ in range(count):
        m = int(rng.integers(fewest, min(most, len(names)) + 1))
        chosen = rng.choice(len(names), size=m, replace=False)
        out.append({names[i]: float(rng.uniform(0.0, 1.0)) for i in sorted(chosen)})
    return out


def bench(folder, repeats=1):
    """Seconds to fit 10 keys with one preparation, and 10 independent cold transfers."""
    from .bench import TUBE_CROSSINGS, tube_dress

    basis, shapes = body_with_keys(folder)
    garment = tube_dress(basis, 40000)
    fitted = []
    for _ in range(repeats):
        t = time.perf_counter()
        fit = fit_shape_keys(basis, shapes, garment, resolve_crossings=TUBE_CROSSINGS)
        fitted.append(time.perf_counter() - t)
    t = time.perf_counter()
    for name, V in shapes.items():
        transfer_garment(basis, basis.with_vertices(V, name=name), garment, resolve_crossings=TUBE_CROSSINGS)
    cold = time.perf_counter() - t
    inside = sum(fit.info[n]["penetrating_vertices"] for n in shapes)
    stages = {stage: float(np.mean([fit.info[n]["seconds"].get(stage, 0.0) for n in shapes]))
              for stage in ("field", "bind", "embed", "solve", "fix")}
    return {"per_key_stages": stages, "garment_vertices": garment.n_vertices, "garment_triangles": garment.n_triangles,
            "keys": len(shapes), "fit_seconds": min(fitted), "fit_stages": fit.seconds,
            "cold_seconds": cold, "inside_at_keys": inside}


def study(folder, garments, count=50, seed=0, margin_mm=(2.0,)):
    """The blending study on the MakeHuman garments: one row per garment and remedy."""
    basis, shapes = body_with_keys(folder)
    combos = combinations(shapes, count, seed)
    bodies = [body_at(basis.V, shapes, w) for w in combos]
    surfaces = [TriangleSurface(V, basis.F) for V in bodies]
    rows = []
    for name in garments:
        garment = read_obj(folder / "garments" / name / f"{MAKEHUMAN_SOURCE}.obj", name=name)
        G, B = readings_of(garment), readings_of(basis)
        prepared = prepare_garment(basis, garment)
        exact = [transfer_garment(basis, basis.with_vertices(V), garment, prepared=prepared).V
                 for V in bodies]
        exact_inside = [float((s.signed_distance(ex)[0] < -MM).mean()) for s, ex in zip(surfaces, exact)]
        # (label, margin, pair correctives, keep outside at run time, the lift of a mix); the lift (on by default,
        # ``shape_keys.mix_lift``) with the bands only: the other rows are the blend as it was before it.
        remedies = [("none", 0.0, False, False, False)]
        remedies += [(f"margin {m:g} mm", m * MM, False, False, False) for m in margin_mm]
        remedies += [("pair correctives", 0.0, True, False, False),
                     ("keep outside, on the surface", 0.0, False, 0.0, False),
                     ("keep outside, half the offset", 0.0, False, 0.5, False),
                     ("keep outside, the whole offset", 0.0, False, 1.0, False)]
        # Per-vertex distances in bands (one Shrinkwrap per band in Blender): the default (bands above the offset
        # too, and the lift), the same without the lift, then up to the offset only (the default before), finer
        # ones up to the offset.
        remedies += [("keep outside in 8 bands and the lift (default)", 0.0, False, SHAPE_KEY_BANDS, True)]
        remedies += [(f"keep outside in {len(b)} bands", 0.0, False, tuple(b), False)
                     for b in (SHAPE_KEY_BANDS, KEEP_OUTSIDE_BANDS, np.linspace(0.5, 1.0, 5),
                               np.linspace(0.5, 1.0, 11))]
        key_surfaces = {k: TriangleSurface(V, basis.F) for k, V in shapes.items()}
        fits = {}
        for label, margin, pairs, outside, lift in remedies:
            key = (margin, pairs)
            if key not in fits:
                fits[key] = fit_shape_keys(basis, shapes, garment, prepared=prepared, margin=margin,
                                           pairs=all_pairs(shapes) if pairs else ())
            fit = fits[key]
            offset = fit.info["Basis"]["offset"]
            if isinstance(outside, tuple):
                bands = keep_outside_bands(fit, basis, shapes, bands=outside)

                def kept(V, surface):
                    return keep_outside_banded(V, surface, bands)
            elif outside is not False:
                def kept(V, surface, share=outside):
                    return keep_outside(V, surface, share * offset)
            else:
                def kept(V, surface):
                    return V
            # How far the rule moves each key at 1 (each must stay the transfer to its shape).
            key_moved = max(float(np.linalg.norm(kept(fit.keys[k], key_surfaces[k]) - fit.keys[k], axis=1).max())
                            for k in shapes)
            inside, worst, error, crossed = [], [], [], []
            for w, surface, ex, body in zip(combos, surfaces, exact, bodies):
                V = kept(fit.blend(w, lift=lift), surface)
                sd = surface.signed_distance(V)[0]
                inside.append(float((sd < -MM).mean()))
                worst.append(float(max(0.0, -sd.min())))
                error.append(float(np.linalg.norm(V - ex, axis=1).mean()))
                c = crossings(V, G, body, B)
                crossed.append(c["a_edges_through_b"] + c["b_edges_through_a"])
            print(f"  {name}: {label} done", flush=True)
            rows.append({"garment": name, "vertices": garment.n_vertices, "remedy": label,
                         "mean_inside": float(np.mean(inside)), "max_inside": float(np.max(inside)),
                         "combinations_over_half_percent": int(np.sum(np.array(inside) > 0.005)),
                         "deepest_mm": max(worst) / MM,
                         "mean_distance_to_exact_mm": float(np.mean(error)) / MM,
                         "combinations_crossing": int(np.count_nonzero(crossed)),
                         "key_at_one_moved_mm": key_moved / MM,
                         "most_edges_crossing": int(max(crossed)),
                         "fit_seconds": fit.seconds["total"], "extra_keys": len(fit.correctives),
                         "exact_mean_inside": float(np.mean(exact_inside)),
                         "exact_max_inside": float(np.max(exact_inside))})
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.shape_keys", description=__doc__.split("\n")[0])
    p.add_argument("--combinations", type=int, default=50)
    p.add_argument("--garments", default=",".join(STUDY_GARMENTS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skip-bench", action="store_true")
    p.add_argument("--skip-study", action="store_true")
    args = p.parse_args(argv)
    folder = makehuman_folder()
    if folder is None:
        print("The MakeHuman fixtures are missing (../shared/data/makehuman); nothing to measure.")
        return 1
    print(f"{os.cpu_count()} CPUs visible, affinity {len(os.sched_getaffinity(0))} cores")
    if not args.skip_bench:
        b = bench(folder)
        print(f"\n10 shape keys on a {b['garment_vertices']}-vertex garment ({b['garment_triangles']} "
              f"triangles): {b['fit_seconds']:.2f} s with one preparation "
              f"(prepare {b['fit_stages']['prepare']:.2f} s, basis and keys {b['fit_stages']['keys']:.2f} s, "
              f"pairs of keys checked {b['fit_stages'].get('pairs', 0.0):.2f} s); "
              f"10 independent cold transfers: {b['cold_seconds']:.2f} s; "
              f"{b['inside_at_keys']} vertices inside at the keys")
        print("per key, mean seconds by stage: " + ", ".join(f"{k} {v:.3f}" for k, v in
                                                             b["per_key_stages"].items()))
    if not args.skip_study:
        garments = [g for g in args.garments.split(",") if g]
        rows = study(folder, garments, args.combinations, args.seed)
        print(f"\nBlending study: {args.combinations} combinations of 3 to 6 of 10 keys, values in [0,1] "
              f"(seed {args.seed}); share of vertices > 1 mm inside the blended body")
        print("mean/max: over the combinations; >0.5%: combinations above the goal; to exact: mean "
              "vertex distance from the transfer to that exact body; exact: the exact transfer's own share; "
              "crossing: combinations where an edge passes through the other mesh under some triangulation "
              "(most: edges in the worst); key@1: the most the remedy moves a vertex of a key at 1")
        print(f"{'garment':20s} {'remedy':46s} {'mean':>7s} {'max':>7s} {'>0.5%':>5s} {'deepest':>9s} "
              f"{'to exact':>9s} {'exact':>7s} {'crossing':>8s} {'most':>5s} {'key@1':>7s} {'keys+':>5s} "
              f"{'fit s':>6s}")
        for r in rows:
            print(f"{r['garment']:20s} {r['remedy']:46s} {r['mean_inside']:7.3%} {r['max_inside']:7.3%} "
                  f"{r['combinations_over_half_percent']:5d} {r['deepest_mm']:7.2f}mm "
                  f"{r['mean_distance_to_exact_mm']:7.2f}mm {r['exact_mean_inside']:7.3%} "
                  f"{r['combinations_crossing']:8d} {r['most_edges_crossing']:5d} "
                  f"{r['key_at_one_moved_mm']:5.2f}mm "
                  f"{r['extra_keys']:5d} {r['fit_seconds']:6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
