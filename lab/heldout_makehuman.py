"""Leave-one-garment-out evaluation of the shared deformation model on the MakeHuman fixtures.

Source body ``female_average``; targets ``female_pear``, ``female_slim_banana``, ``male_average``,
``male_slim``. For each of the 8 garments: train on the 7 others (one model for all four targets),
transfer the held-out garment to every target, and compare with the garment fitted on that target
(the fixtures' ground truth). Variants, all on the same folds:

* ``direct``: the body's own deformation gradients (no learning; the paper's fig. 2 baseline).
* ``shared``: masked loss, the decoder at the mean latent of the training garments on the target.
* ``mean_field``: the mean of the training fields themselves (no network).
* ``paper``: the paper's loss over every body triangle, decoder at the mean latent.
* ``hidden_mean_latent`` / ``hidden_mean_decoded``: a sigmoid hidden layer on each side, where
  decoding the mean latent differs from averaging the decoded fields (with no hidden layer the decoder
  is affine and the two are equal).
* ``oracle``: the held-out garment's own embedded deformation: the best any body field
  could do through this pipeline (embedding, Poisson solve, anchoring, penetration fix).

Figures: vertex error against the fitted garment (mean, mm; the fixtures are in decimetres), MDC
against the source garment (design kept; the fitted ground truth's own MDC is given for scale), drape
error relative to the untransferred garment (1 = nothing moved toward the target fit, 0 = perfect),
penetration (share of vertices inside the target body), and the field error: RMS difference between
the predicted and the held-out garment's own deformation gradients over the body triangles it covers.

Usage::

    nice .venv/bin/python -m lab heldout [--epochs 500] [--threads 1] [--out results.md]
        [--json results.json] [--garments g1,g2]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from garment_transfer.errors import GarmentTransferError
from garment_transfer.files import check_outputs, write_json_atomic, write_text_atomic
from garment_transfer.learning.dataset import load_dataset

from .experiment import METHODS as ALL_METHODS
from .experiment import run_experiment
from .paths import MAKEHUMAN_SOURCE as SOURCE
from .paths import MAKEHUMAN_TARGETS, data_folders, makehuman_folder

TARGETS = list(MAKEHUMAN_TARGETS)
DM_TO_MM = 100.0

METHODS = ["direct", "shared", "mean_field", "paper", "hidden_mean_latent", "hidden_mean_decoded", "oracle"]


def run(folder, epochs, threads, seed, garments, log):
    """Leave each garment out in turn; rows with the figures in millimetres."""
    ds = load_dataset(folder)
    garments = garments or ds.garments
    folds = [([g for g in ds.garments if g != h], [h]) for h in garments]
    res = run_experiment(folder, SOURCE, TARGETS, folds, METHODS, epochs, reference="fitted", seed=seed,
                         threads=threads, field_error=True,
                         progress=lambda f, stage: log(f"{stage} ({100 * f:.0f}%)"))
    gt_mdc = {(r["garment"], r["target"]): r["mdc"] for r in res["rows"] if r["method"] == "fitted"}
    rows = [{"garment": r["garment"], "target": r["target"], "method": r["method"],
             "vertex_error_mm": DM_TO_MM * r["vertex_error_mean"],
             "vertex_error_max_mm": DM_TO_MM * r["vertex_error_max"], "mdc": r["mdc"],
             "gt_mdc": gt_mdc[(r["garment"], r["target"])], "drape_relative": r["drape_error_relative"],
             "penetration": r["penetration_ratio"], "field_rms": r.get("field_rms"),
             "transfer_s": r["seconds_reused"]}
            for r in res["rows"] if r["method"] != "fitted"]
    trainings = [{"heldout": t["test"][0], "variant": {"shared": "masked", "paper": "unmasked"}.get(t["variant"],
                                                                                                 t["variant"]),
                  "seconds": t["seconds"], "final_loss": t["final_loss"],
                  "final_masked_loss": t["final_masked_loss"]} for t in res["trainings"]]
    return {"rows": rows, "trainings": trainings, "read_seconds": res["read_seconds"], "garments": list(garments)}


def mean_of(rows, method, key, **where):
    vals = [r[key] for r in rows if r["method"] == method and all(r[k] == v for k, v in where.items())]
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else float("nan")


def markdown(res, args, command, seconds):
    rows = res["rows"]
    L = []
    L.append("# Shared deformation model on the MakeHuman fixtures: leave one garment out\n")
    L.append(f"Produced by:\n\n```\n{command}\n```\n")
    L.append(f"Source body `{SOURCE}`; targets {', '.join(f'`{t}`' for t in TARGETS)} (one model for all "
             f"four, one-hot condition). For each of the {len(res['garments'])} garments, the models are "
             f"trained on the 7 others ({args.epochs} epochs, Adam, latent 30, seed {args.seed}, "
             f"{args.threads} torch thread(s)), and the held-out garment is transferred with "
             "`transfer_garment(..., method=\"model\")` (interpolating embedding, anchored Poisson solve, "
             "penetration fix) and compared with the same garment fitted on the target (the fixtures' "
             "ground truth; MakeHuman's proxy fitting, a body-driven deformation, not a cloth simulation).\n")
    L.append(f"Machine: {platform.machine()}, {os.cpu_count()} cores shared with other work; whole run "
             f"{seconds / 60:.1f} min (reading the dataset {res['read_seconds']:.1f} s).\n")
    L.append("## All garments and targets (means)\n")
    L.append("| method | vertex error mm | max mm | MDC | drape error (rel.) | penetration | field RMS |")
    L.append("|---|---|---|---|---|---|---|")
    L.append("Methods: " + "; ".join(f"`{m}`: {ALL_METHODS[m].label}" for m in METHODS) + ".\n")
    for m in METHODS:
        L.append(f"| {m} | {mean_of(rows, m, 'vertex_error_mm'):.2f} | "
                 f"{mean_of(rows, m, 'vertex_error_max_mm'):.1f}"
                 f" | {mean_of(rows, m, 'mdc'):.4f} | {mean_of(rows, m, 'drape_relative'):.3f} | "
                 f"{100 * mean_of(rows, m, 'penetration'):.2f}% | {mean_of(rows, m, 'field_rms'):.4f} |")
    L.append(f"\nMDC of the fitted ground truth against the source garment (for scale): "
             f"{mean_of(rows, 'direct', 'gt_mdc'):.4f}.\n")
    L.append("## Vertex error (mm) per target\n")
    L.append("| method | " + " | ".join(TARGETS) + " |")
    L.append("|---|" + "---|" * len(TARGETS))
    for m in METHODS:
        L.append(f"| {m} | " + " | ".join(f"{mean_of(rows, m, 'vertex_error_mm', target=t):.2f}"
                                          for t in TARGETS) + " |")
    L.append("\n## Vertex error (mm) per held-out garment (mean over targets)\n")
    main = ["direct", "shared", "mean_field", "paper", "oracle"]
    L.append("| garment | " + " | ".join(main) + " |")
    L.append("|---|" + "---|" * len(main))
    for g in res["garments"]:
        L.append(f"| {g} | " + " | ".join(f"{mean_of(rows, m, 'vertex_error_mm', garment=g):.2f}"
                                          for m in main) + " |")
    L.append("\n## Training\n")
    L.append("| variant | mean seconds | mean final loss (its own objective) | mean masked loss |")
    L.append("|---|---|---|---|")
    for v in ("masked", "unmasked", "hidden"):
        tr = [t for t in res["trainings"] if t["variant"] == v]
        L.append(f"| {v} | {np.mean([t['seconds'] for t in tr]):.1f} | "
                 f"{np.mean([t['final_loss'] for t in tr]):.4f} | "
                 f"{np.mean([t['final_masked_loss'] for t in tr]):.4f} |")
    L.append("")
    return "\n".join(L)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--epochs", type=int, default=500)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--garments", help="held-out garments, comma-separated (default: all 8)")
    ap.add_argument("--out", help="markdown file to write")
    ap.add_argument("--json", help="raw results (JSON) to write")
    args = ap.parse_args(argv)
    folder = makehuman_folder()
    if folder is None:
        raise SystemExit("MakeHuman fixtures not found (../shared/data/makehuman)")
    try:
        # Before the study, not after it: never into the fixtures, never a missing folder.
        check_outputs([(p, o) for p, o in ((args.out, "--out"), (args.json, "--json")) if p],
                      input_folders=data_folders())
    except GarmentTransferError as exc:
        raise SystemExit(f"error: {exc}") from None
    command = "nice .venv/bin/python -m lab heldout " + " ".join(argv if argv is not None else sys.argv[1:])
    t0 = time.perf_counter()
    res = run(folder, args.epochs, args.threads, args.seed,
              [g for g in args.garments.split(",") if g] if args.garments else None,
              lambda msg: print(msg, file=sys.stderr, flush=True))
    seconds = time.perf_counter() - t0
    text = markdown(res, args, command.strip(), seconds)
    if args.json:
        write_json_atomic(args.json, res)
    if args.out:
        write_text_atomic(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
