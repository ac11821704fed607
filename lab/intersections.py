"""Study: does the crossing pass leave garments intersection-free, and at what cost?

Per garment and target it prints the exact crossings (garment edges through the body + body edges
through the garment, as edge-triangle pairs, under every triangulation of both meshes' quads) before and
after the pass, self-intersections of the
source garment, before and after the pass (and, after, how many of them the source does not have),
the smallest garment-body distance kept, MDC against the source garment without and with the pass
and their ratio, the time of the transfer and of the pass, and their ratio.

Sections: ``demo`` (every demo test garment on every target), ``makehuman`` (every fixture garment
from female_average to every other body), ``outfits`` (two layered outfits from the demo garments
on every target) and ``speed`` (demo garments subdivided to 28K..156K triangles, banana to pear).

    python -m lab.intersections                 # everything (a few minutes)
    python -m lab.intersections --only demo,outfits --quick

The MakeHuman fixtures are looked for beside the repository (``../shared/data/makehuman``) or where
``GARMENT_TRANSFER_MAKEHUMAN`` says.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from garment_transfer.geometry.clearance import separate
from garment_transfer.geometry.intersections import crossings, minimum_distance, self_intersections
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.readings import readings_of
from garment_transfer.pipeline.metrics import mdc
from garment_transfer.pipeline.transfer import transfer_garment

from .outfits import crossings_left
from .outfits import run_outfits as run_outfit_study
from .paths import DEMO_DATA as DEMO
from .paths import SHARED_MAKEHUMAN, makehuman_folder

MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN
SPEED = (("wrap_dress", 1), ("formal_dress", 1), ("wrap_dress", 2), ("pleated_skirt", 2))

HEADER = (f"{'garment':<20} {'target':<18} {'tris':>6} {'cross':>5} {'after':>5} {'self src':>8} "
          f"{'before':>6} {'after':>5} {'new':>4} {'min dist':>9} {'MDC off':>8} {'MDC on':>8} {'ratio':>5} "
          f"{'transfer s':>10} {'pass s':>6} {'pass/tr':>7}")


def crossing_count(V, F, body):
    """Edge-triangle pairs crossing, both ways, under every reading of both meshes' polygons (F: Readings)."""
    c = crossings(V, F, body.V, readings_of(body))
    return c["a_edge_pairs"] + c["b_edge_pairs"]


def study_pair(source_body, target_body, garment, label, target):
    """One transfer without the pass, then the pass alone on its result: every figure of the study, under every
    triangulation of the garment's and the body's polygons."""
    t = time.perf_counter()
    plain = transfer_garment(source_body, target_body, garment, resolve_crossings=False)
    t_transfer = time.perf_counter() - t
    G, B = readings_of(garment), readings_of(target_body)
    t = time.perf_counter()
    V, info = separate(plain.V, G, target_body.V, B, plain.info["offset"], source_V=garment.V)
    t_pass = time.perf_counter() - t
    F = garment.F
    row = {"garment": label, "target": target, "triangles": garment.n_triangles,
           "crossings_before": crossing_count(plain.V, G, target_body),
           "crossings_after": crossing_count(V, G, target_body),
           "self_source": self_intersections(garment.V, G)[0],
           "self_before": self_intersections(plain.V, G)[0], "self_after": self_intersections(V, G)[0],
           "min_distance": minimum_distance(V, G, target_body.V, B),
           "offset": plain.info["offset"],
           "mdc_off": mdc(garment.V, plain.V, F), "mdc_on": mdc(garment.V, V, F),
           "self_new": info["self_intersections_new"],
           "transfer_s": t_transfer, "pass_s": t_pass, "rounds": info["rounds"]}
    row["mdc_ratio"] = row["mdc_on"] / row["mdc_off"] if row["mdc_off"] > 0 else 1.0
    return row


def format_row(r):
    return (f"{r['garment']:<20} {r['target']:<18} {r['triangles']:>6} {r['crossings_before']:>5} "
            f"{r['crossings_after']:>5} {r['self_source']:>8} {r['self_before']:>6} {r['self_after']:>5} "
            f"{r['self_new']:>4} {r['min_distance']:>9.3g} {r['mdc_off']:>8.4f} {r['mdc_on']:>8.4f} "
            f"{r['mdc_ratio']:>5.3f} {r['transfer_s']:>10.2f} {r['pass_s']:>6.2f} "
            f"{r['pass_s'] / r['transfer_s']:>7.2f}")


def summary(name, rows):
    if not rows:
        return f"{name}: nothing run"
    left = sum(r["crossings_after"] > 0 for r in rows)
    had = sum(r["crossings_before"] > 0 for r in rows)
    more_self = sum(r["self_after"] > r["self_before"] for r in rows)
    above_src = sum(r["self_after"] > r["self_source"] for r in rows)
    above_src_before = sum(r["self_before"] > r["self_source"] for r in rows)
    over = sum(r["mdc_ratio"] > 1.10 for r in rows)
    return (f"{name}: {len(rows)} pairs; crossings in {had} before the pass, {left} after; "
            f"self-intersections increased by the pass in {more_self}; more self-intersections than the "
            f"source in {above_src_before} before the pass, {above_src} after (pairs the source lacks, after: "
            f"{sum(r['self_new'] for r in rows)} in all); MDC more than 10% above "
            f"without the pass in {over} (worst ratio {max(r['mdc_ratio'] for r in rows):.3f}); "
            f"smallest distance kept {min(r['min_distance'] for r in rows):.3g} "
            f"(offset {min(r['offset'] for r in rows):.3g}); pass / transfer time: median "
            f"{np.median([r['pass_s'] / r['transfer_s'] for r in rows]):.2f}, "
            f"worst {max(r['pass_s'] / r['transfer_s'] for r in rows):.2f}")


def run_demo(quick):
    manifest = json.loads((DEMO / "manifest.json").read_text())
    source = read_obj(DEMO / "bodies" / f"{manifest['source']}.obj")
    garments = manifest["test_garments"][:2] if quick else manifest["test_garments"]
    rows = []
    for g in garments:
        garment = read_obj(DEMO / "garments" / g / f"{manifest['source']}.obj", name=g)
        for t in manifest["targets"]:
            rows.append(study_pair(source, read_obj(DEMO / "bodies" / f"{t}.obj"), garment, g, t))
            print(format_row(rows[-1]), flush=True)
    return rows


def run_makehuman(quick):
    if not (MAKEHUMAN / "bodies").is_dir():
        print(f"MakeHuman fixtures not found at {MAKEHUMAN}: section skipped")
        return []
    manifest = json.loads((MAKEHUMAN / "manifest.json").read_text())
    source = read_obj(MAKEHUMAN / "bodies" / "female_average.obj")
    garments = manifest["garments"][:2] if quick else manifest["garments"]
    rows = []
    for g in garments:
        garment = read_obj(MAKEHUMAN / "garments" / g / "female_average.obj", name=g)
        own = crossing_count(garment.V, readings_of(garment), source)
        print(f"{g}: the source garment itself crosses female_average at {own} edge-triangle pairs")
        for t in manifest["bodies"]:
            if t != "female_average":
                rows.append(study_pair(source, read_obj(MAKEHUMAN / "bodies" / f"{t}.obj"), garment, g, t))
                print(format_row(rows[-1]), flush=True)
    return rows


def format_outfit_row(r):
    under = f"{r['layer_crossings_source']:>6} {r['layer_crossings']:>5}" if r["layer"] > 1 else f"{'-':>6} {'-':>5}"
    dist = "-" if r["min_layer_distance"] is None else f"{r['min_layer_distance']:.3g}"
    return (f"{r['outfit']:<22} {r['target']:<10} {r['layer']:>5} {r['garment']:<12} "
            f"{r['garment_edge_body_pairs']:>5} {r['body_edge_garment_pairs']:>5} {under} "
            f"{r['self_intersections_source']:>8} {r['self_intersections']:>5} {r['min_body_distance']:>9.3g} "
            f"{dist:>9} {r['mdc']:>8.4f}")


def run_outfits(quick):
    targets = json.loads((DEMO / "manifest.json").read_text())["targets"]
    print(f"{'outfit':<22} {'target':<10} {'layer':>5} {'garment':<12} {'g>b':>5} {'b>g':>5} "
          f"{'under src':>6} {'after':>5} {'self src':>8} {'after':>5} {'min body':>9} {'min under':>9} "
          f"{'MDC':>8}")
    res = run_outfit_study(DEMO, targets[:2] if quick else targets,
                           on_row=lambda r: print(format_outfit_row(r), flush=True))
    for ref in res["refusals"]:
        given = " under ".join(ref["order"])
        print(f"the wrong order ({given}) is refused: {ref['message']}" if ref["refused"]
              else f"{given}: the wrong order was NOT refused")
    transfers = {(r["outfit"], r["target"]) for r in res["rows"]}
    crossed = {(r["outfit"], r["target"]) for r in crossings_left(res)}
    return (f"outfits: {len(transfers)} outfit transfers; crossings left (between layers or with the body) "
            f"in {len(crossed)}")


def subdivide(V, F):
    """Each triangle into four at its edge midpoints (the surface does not change)."""
    n = V.shape[0]
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    key, inv = np.unique(e[:, 0] * n + e[:, 1], return_inverse=True)
    mids = 0.5 * (V[key // n] + V[key % n])
    m = F.shape[0]
    inv = inv.reshape(3, m).T + n
    a, b, c = F.T
    ab, bc, ca = inv.T
    F2 = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                         np.stack([ab, bc, ca], 1)])
    return np.vstack([V, mids]), F2


def run_speed(quick):
    manifest = json.loads((DEMO / "manifest.json").read_text())
    source = read_obj(DEMO / "bodies" / f"{manifest['source']}.obj")
    target = read_obj(DEMO / "bodies" / "pear.obj")
    rows = []
    for g, times in SPEED[:2] if quick else SPEED:
        base = read_obj(DEMO / "garments" / g / f"{manifest['source']}.obj")
        V, F = base.V, base.F
        for _ in range(times):
            V, F = subdivide(V, F)
        garment = mesh_from_triangles(V, F, name=f"{g} x{4 ** times}")
        rows.append(study_pair(source, target, garment, garment.name, "pear"))
        print(format_row(rows[-1]), flush=True)
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.intersections", description=__doc__.split("\n")[0])
    p.add_argument("--only", default="demo,makehuman,outfits,speed", help="sections, comma-separated")
    p.add_argument("--quick", action="store_true", help="two garments or targets per section")
    args = p.parse_args(argv)
    sections = args.only.split(",")
    lines = []
    t0 = time.perf_counter()
    for name, fn in (("demo", run_demo), ("makehuman", run_makehuman), ("speed", run_speed)):
        if name in sections:
            print(f"\n== {name} ==\n{HEADER}")
            lines.append(summary(name, fn(args.quick)))
    if "outfits" in sections:
        print("\n== outfits ==")
        lines.append(run_outfits(args.quick))
    print("\n== summary ==")
    for line in lines:
        print(line)
    print(f"{time.perf_counter() - t0:.0f} s in all")


if __name__ == "__main__":
    main()
