"""The Poisson solve's gradient term: the finite-element energy against the paper's sum over edges.

``poisson.PoissonSolver``'s ``energy``: ``"gradients"`` (each triangle's own metric, the product's) or
``"edges"`` (the paper's eq. 5). For every garment and target of a dataset folder, direct transfer and
direct transfer with the garment's own placement (``placement.true_offsets`` from its simulation on the
target: the strain a placement asks of the garment, without a model's error), each with both energies;
per target the mean vertex error against the reference, MDC and the vertices inside the body, and the
seconds ``prepare_garment`` takes (the binding and the solver).

Run::

    nice python -m lab.poisson_energy [--data DIR] [--source female_average] [--garments g1,g2] \
        [--targets b1,b2] [--json out.json]

``--data``: a dataset folder (default: the MakeHuman fixtures, ``GARMENT_TRANSFER_MAKEHUMAN``, or the
folder ``python -m lab.makehuman_drape --out DIR`` writes, whose garments are simulated); the source body is
``--source``, else the manifest's, else ``female_average``; the garments are the folder's own (not the catalogue
garments nor the looser cuts those lab modules add), the targets every other body.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from garment_transfer.files import write_json_atomic
from garment_transfer.geometry.poisson import ENERGIES
from garment_transfer.learning.dataset import load_dataset
from garment_transfer.learning.placement import true_offsets
from garment_transfer.pipeline.metrics import evaluate
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

from .paths import MAKEHUMAN_SOURCE, makehuman_folder

RUNS = [(e, placed) for placed in (False, True) for e in ENERGIES]


def run(folder, source, garments, targets, progress=print):
    """Rows: one per garment, target, energy and placement (``evaluate``'s figures, ``garment``, ``target``,
    ``energy``, ``placed`` and ``prepare_seconds``)."""
    ds = load_dataset(folder)
    body = ds.body(source)
    bodies = {b: ds.body(b) for b in targets}
    rows = []
    for g in garments:
        garment = ds.garment(g, source)
        prepared, seconds = {}, {}
        for e in ENERGIES:
            t = time.perf_counter()
            prepared[e] = prepare_garment(body, garment, energy=e)
            seconds[e] = time.perf_counter() - t
        for b in targets:
            target, ref = bodies[b], ds.garment(g, b)
            own = true_offsets(prepared["gradients"].binding, body, target, ref.V)[0]
            for e, placed in RUNS:
                r = transfer_garment(body, target, garment, prepared=prepared[e], placement=own if placed else None)
                row = evaluate(garment, garment.with_vertices(r.V), target, reference=ref)
                row.update(garment=g, target=b, energy=e, placed=placed, prepare_seconds=seconds[e])
                rows.append(row)
            progress(f"{g} on {b}: " + ", ".join(
                f"{x['energy']}{' placed' if x['placed'] else ''} MDC {x['mdc']:.4f}"
                for x in rows[-len(RUNS):]))
    return rows


def summarise(rows, targets, scale):
    lines = [f"{'target':20s} {'run':26s} {'vertex':>8s} {'MDC':>7s} {'x edges':>7s} {'inside':>6s}"]
    for b in targets:
        def mean(e, placed, key):
            return float(np.mean([r[key] for r in rows if r["target"] == b and r["energy"] == e
                                  and r["placed"] == placed]))
        for e, placed in RUNS:
            inside = sum(r["penetrating_vertices"] for r in rows if r["target"] == b and r["energy"] == e
                         and r["placed"] == placed)
            lines.append(f"{b:20s} {e + (' + own placement' if placed else ''):26s} "
                         f"{scale * mean(e, placed, 'vertex_error_mean'):8.2f} {mean(e, placed, 'mdc'):7.4f} "
                         f"{mean(e, placed, 'mdc') / mean('edges', placed, 'mdc'):7.2f} {inside:6d}")
    seconds = {e: np.mean([r["prepare_seconds"] for r in rows if r["energy"] == e]) for e in ENERGIES}
    lines.append("prepare_garment (binding and solver), mean per garment: "
                 + ", ".join(f"{e} {s:.3f} s" for e, s in seconds.items()))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--source", default=None)
    ap.add_argument("--garments", default="")
    ap.add_argument("--targets", default="")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    folder = args.data or makehuman_folder()
    if folder is None:
        ap.error("no dataset folder: give --data, or set GARMENT_TRANSFER_MAKEHUMAN")
    ds = load_dataset(folder)
    source = args.source or ds.manifest.get("source", MAKEHUMAN_SOURCE)
    # By default the folder's own garments: not the catalogue's nor the looser cuts lab.makehuman_drape adds.
    added = set(ds.manifest.get("procedural_garments", [])) | set(ds.manifest.get("variants", {}))
    garments = [g for g in args.garments.split(",") if g] or [g for g in ds.garments if g not in added]
    targets = [b for b in args.targets.split(",") if b] or [b for b in ds.bodies if b != source]
    rows = run(folder, source, garments, targets)
    # Decimetres (MakeHuman) or metres: vertex errors in mm.
    scale = 100.0 if (ds.units or "").startswith("decim") else 1000.0
    text = summarise(rows, targets, scale)
    print(f"\nvertex error in mm, {len(garments)} garments, source {source}\n{text}")
    if args.json:
        write_json_atomic(args.json, {"command": " ".join(["python -m lab.poisson_energy", *(argv or sys.argv[1:])]),
                                      "rows": rows, "text": text})
    return 0


if __name__ == "__main__":
    sys.exit(main())
