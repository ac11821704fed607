"""Leave-one-garment-out evaluation of the shared deformation model on the MakeHuman fixtures.

Source body ``female_average``; targets ``female_pear``, ``female_slim_banana``, ``male_average``,
``male_slim``. For each of the 8 garments: train on the 7 others (one model for all four targets),
transfer the held-out garment to every target, and compare with the garment fitted on that target
(the fixtures' ground truth). Variants, all on the same folds:

* ``direct``: the body's own deformation gradients (no learning; the paper's fig. 2 baseline).
* ``model``: ours: masked loss, the decoder at the mean latent of the training garments on the target.
* ``model, mean field``: the mean of the training fields themselves (no network).
* ``paper (unmasked)``: the paper's loss over every body triangle, decoder at the mean latent.
* ``hidden 32, mean latent`` / ``hidden 32, mean decoded``: a sigmoid hidden layer on each side, where
  decoding the mean latent differs from averaging the decoded fields (with no hidden layer the decoder
  is affine and the two are equal).
* ``own field (oracle)``: the held-out garment's own embedded deformation: the best any body field
  could do through this pipeline (embedding, Poisson solve, anchoring, penetration fix).

Figures: vertex error against the fitted garment (mean, mm; the fixtures are in decimetres), MDC
against the source garment (design kept; the fitted ground truth's own MDC is given for scale), drape
error relative to the untransferred garment (1 = nothing moved toward the target fit, 0 = perfect),
penetration (share of vertices inside the target body), and the field error: RMS difference between
the predicted and the held-out garment's own deformation gradients over the body triangles it covers.

Usage::

    nice .venv/bin/python benchmarks/heldout_makehuman.py [--epochs 500] [--threads 1]
        [--out results.md] [--json results.json] [--garments g1,g2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from garment_transfer.dataset import build_training_fields, load_dataset  # noqa: E402
from garment_transfer.metrics import evaluate, mdc  # noqa: E402
from garment_transfer.transfer import prepare_garment, transfer_garment  # noqa: E402

SOURCE = "female_average"
TARGETS = ["female_pear", "female_slim_banana", "male_average", "male_slim"]
MAKEHUMAN = Path(__file__).resolve().parents[2] / "shared" / "data" / "makehuman"
DM_TO_MM = 100.0

METHODS = ["direct", "model", "model, mean field", "paper (unmasked)", "hidden 32, mean latent",
           "hidden 32, mean decoded", "own field (oracle)"]


class FixedField:
    """Stands in for a model in ``transfer_garment``: a given body field per target."""

    def __init__(self, model, field_of):
        self._model = model
        self._field_of = field_of
        self.name = model.name
        self.targets = model.targets

    def check_source_body(self, mesh):
        self._model.check_source_body(mesh)

    def body_field(self, target):
        return self._field_of(target)


def field_rms(Q, true_dev, covered):
    """RMS over the covered triangles of the difference between Q and I + true deviation (per entry)."""
    d = Q.reshape(-1, 9)[covered] - (np.eye(3).reshape(9) + true_dev[covered])
    return float(np.sqrt(np.mean(d ** 2)))


def train_variants(fields, train_names, epochs, threads, seed):
    from garment_transfer.training import train_model

    part = fields.select(train_names)
    out = {}
    for key, kw in [("masked", {}), ("unmasked", {"masked": False}), ("hidden", {"hidden": [32]})]:
        model, info = train_model(part, epochs=epochs, seed=seed, threads=threads, **kw)
        out[key] = (model, info)
    return out


def run(epochs, threads, seed, garments, log):
    ds = load_dataset(MAKEHUMAN)
    garments = garments or ds.garments
    t0 = time.perf_counter()
    fields = build_training_fields(ds, SOURCE, TARGETS, keep_raw=True)
    read_s = time.perf_counter() - t0
    source_body = ds.body(SOURCE)
    rows, trainings = [], []
    for h in garments:
        train_names = [g for g in ds.garments if g != h]
        variants = train_variants(fields, train_names, epochs, threads, seed)
        for key, (_, info) in variants.items():
            trainings.append({"heldout": h, "variant": key, "seconds": info["seconds"],
                              "final_loss": info["final_loss"],
                              "final_masked_loss": info["final_masked_loss"]})
        gi = fields.garments.index(h)
        covered = fields.covered[gi]
        m, mu, mh = variants["masked"][0], variants["unmasked"][0], variants["hidden"][0]

        def own(t, gi=gi, covered=covered):
            k = TARGETS.index(t)
            dev = np.where(covered[:, None], fields.deviation[gi, k], fields.body_deviation[k])
            return dev.astype(np.float64).reshape(-1, 3, 3) + np.eye(3)

        models = {
            "direct": None,
            "model": m,
            "model, mean field": FixedField(m, lambda t, m=m: m.body_field(t, how="mean_field")),
            "paper (unmasked)": mu,
            "hidden 32, mean latent": mh,
            "hidden 32, mean decoded": FixedField(mh, lambda t, mh=mh: mh.body_field(t, how="mean_decoded")),
            "own field (oracle)": FixedField(m, own),
        }
        garment = ds.garment(h, SOURCE)
        prepared = prepare_garment(source_body, garment)
        for t in TARGETS:
            k = TARGETS.index(t)
            target_body = ds.body(t)
            ref = ds.garment(h, t)
            gt_mdc = mdc(garment.V, ref.V, garment.F)
            for name, model in models.items():
                method = "direct" if model is None else "model"
                res = transfer_garment(source_body, target_body, garment, method=method, model=model,
                                       target=t, prepared=prepared)
                if model is None:
                    from garment_transfer.gradients import deformation_gradients

                    Q = deformation_gradients(source_body.V, target_body.V, source_body.F)[0]
                else:
                    Q = model.body_field(t)
                e = evaluate(garment, garment.with_vertices(res.V), target_body, reference=ref)
                rows.append({
                    "garment": h, "target": t, "method": name,
                    "vertex_error_mm": DM_TO_MM * e["vertex_error_mean"],
                    "vertex_error_max_mm": DM_TO_MM * e["vertex_error_max"],
                    "mdc": e["mdc"], "gt_mdc": gt_mdc, "drape_relative": e["drape_error_relative"],
                    "penetration": e["penetration_ratio"],
                    "field_rms": field_rms(Q, fields.deviation[gi, k].astype(np.float64), covered),
                    "transfer_s": res.seconds["total"],
                })
        log(f"{h}: done ({time.perf_counter() - t0:.0f} s)")
    return {"rows": rows, "trainings": trainings, "read_seconds": read_s, "garments": list(garments)}


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
    main = ["direct", "model", "model, mean field", "paper (unmasked)", "own field (oracle)"]
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
    if not (MAKEHUMAN / "bodies").is_dir():
        raise SystemExit(f"MakeHuman fixtures not found at {MAKEHUMAN}")
    command = "nice .venv/bin/python benchmarks/heldout_makehuman.py " + " ".join(argv or sys.argv[1:])
    t0 = time.perf_counter()
    res = run(args.epochs, args.threads, args.seed,
              [g for g in args.garments.split(",") if g] if args.garments else None,
              lambda msg: print(msg, file=sys.stderr, flush=True))
    seconds = time.perf_counter() - t0
    text = markdown(res, args, command.strip(), seconds)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    if args.out:
        Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
