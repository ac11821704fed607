"""Training time of the shared deformation model at the paper's scale.

The paper (sect. 6.1): a body of |M| = 37,744 triangles, 15 training garments, latent 30, 1000 epochs of
scaled conjugate gradient: about 35 minutes (laptop i7-8750H + RTX 2070).

No real dataset of that size is at hand, so the fields are synthetic: on a grid body of exactly
37,744 triangles, each of the 15 garments covers a band of the body (40-80% of it) and its field is a
shared smooth "shape" part plus a garment-specific high-frequency "style" part. That is enough for
timing (the cost does not depend on the values), and the output says so.

Usage::

    nice .venv/bin/python -m lab training-scale [--epochs 1000] [--threads N] [--optimizer adam]
        [--unmasked] [--json]
    nice .venv/bin/python -m lab training-scale --compare-optimisers [--epochs 300] [--threads 1]

``--compare-optimisers`` trains on the MakeHuman fixtures (source female_average, 4 targets, one garment
held out) with each optimiser and reports the training loss, the held-out error of the predicted field
and the time: the measurement behind the default optimiser.

``--unmasked`` is the paper's network: every body triangle is an input and output (|M| * 9 = 339,696
values). The default (masked) leaves out triangles that no garment covers, as training does.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

from garment_transfer.geometry.mesh import mesh_from_polygons
from garment_transfer.learning.dataset import TrainingFields

from .paths import MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, makehuman_folder

PAPER = {"triangles": 37744, "garments": 15, "epochs": 1000, "latent": 30, "seconds": 35 * 60}


def grid_body(nx=57, ny=338):
    """A quad grid of (nx-1)*(ny-1)*2 triangles (37,744 by default), bent into a half cylinder."""
    u, v = np.meshgrid(np.linspace(0, np.pi, nx), np.linspace(0, 1.7, ny))
    V = np.stack([0.15 * np.cos(u), v, 0.15 * np.sin(u)], axis=-1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    return mesh_from_polygons(V, quads, name="grid_body")


def synthetic_fields(n_garments=15, n_targets=1, seed=0):
    """Synthetic training fields on the grid body (see the module docstring).

    Returns
    -------
    TrainingFields
    """
    rng = np.random.default_rng(seed)
    body = grid_body()
    M = body.n_triangles
    c = body.V[body.F].mean(axis=1)
    height = c[:, 1] / 1.7
    shape = np.stack([np.sin(np.pi * (j + 1) * height + j) for j in range(9)], axis=1) * 0.15
    dev = np.zeros((n_garments, n_targets, M, 9), np.float32)
    covered = np.zeros((n_garments, M), bool)
    for g in range(n_garments):
        lo = rng.uniform(0.0, 0.5)
        covered[g] = (height > lo) & (height < lo + rng.uniform(0.4, 0.8))
        style = rng.normal(0.0, 0.05, (M, 9)) * np.sin(40 * np.pi * height * (1 + g / 7))[:, None]
        for k in range(n_targets):
            d = shape * (1 + 0.3 * k) + style
            dev[g, k] = np.where(covered[g][:, None], d, 0.0)
    body_dev = np.repeat(shape[None].astype(np.float32), n_targets, axis=0)
    return TrainingFields(dev, covered, body_dev, [f"g{g}" for g in range(n_garments)],
                          [f"t{k}" for k in range(n_targets)], "grid_body", body,
                          raw_deviation=dev.copy())


#: (optimiser, learning rate, share of --epochs). SCG evaluates the gradient twice per epoch and L-BFGS
#: (with its line search) about twice: they get half the epochs, for about as many gradient evaluations.
OPTIMISER_RUNS = [("adam", 1e-3, 1.0), ("adam", 3e-3, 1.0), ("adam", 1e-2, 1.0), ("lbfgs", 1.0, 0.5),
                  ("scg", None, 0.5)]


def mean_field_error(model, held):
    """Held-out error (as in training: masked MSE, normalised) of the plain mean of the training fields."""
    err, n = 0.0, 0
    for k, t in enumerate(model.targets):
        pred = (model.body_field(t, how="mean_field").reshape(-1, 9) - np.eye(3).reshape(9)) / model.scale
        x = held.deviation[0, k].astype(np.float64) / model.scale
        c = held.covered[0]
        err += float(((pred[c] - x[c]) ** 2).sum())
        n += 9 * int(c.sum())
    return err / n


def compare_optimisers(epochs, threads, holdout="female_casualsuit01"):
    """Every optimiser on one MakeHuman fold: list of dicts (optimiser, lr, losses, seconds)."""
    from garment_transfer.learning.dataset import build_training_fields
    from garment_transfer.learning.training import train_model

    folder = makehuman_folder()
    if folder is None:
        raise SystemExit("the MakeHuman fixtures (../shared/data/makehuman) are needed for the comparison")
    fields = build_training_fields(folder, MAKEHUMAN_SOURCE, list(MAKEHUMAN_TARGETS))
    train = fields.select([g for g in fields.garments if g != holdout])
    held = fields.select([holdout])
    rows = []
    model = None
    for opt, lr, share in OPTIMISER_RUNS:
        c0 = time.process_time()
        n = max(1, int(round(epochs * share)))
        model, info = train_model(train, epochs=n, optimizer=opt, lr=lr, holdout=held, patience=10 ** 9,
                              eval_every=max(1, n // 30), threads=threads)
        hist = dict((e, v) for e, v in info["loss_history"])
        rows.append({"optimizer": opt, "lr": info["lr"], "epochs": info["epochs"],
                     "loss_at_10pct": hist.get(min(hist, key=lambda e: abs(e - n // 10))),
                     "final_loss": info["final_loss"], "best_heldout": info["best_validation_loss"],
                     "best_heldout_epoch": info["best_validation_epoch"], "seconds": info["seconds"],
                     "cpu_seconds": round(time.process_time() - c0, 2)})
        print(json.dumps(rows[-1]), file=sys.stderr)
    data = (f"MakeHuman: source {MAKEHUMAN_SOURCE}, targets {', '.join(MAKEHUMAN_TARGETS)}, {len(train.garments)} "
            f"training garments, held out {holdout}")
    return {"mean_field_heldout": mean_field_error(model, held), "data": data, "rows": rows}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--epochs", type=int, default=PAPER["epochs"])
    ap.add_argument("--garments", type=int, default=PAPER["garments"])
    ap.add_argument("--targets", type=int, default=1)
    ap.add_argument("--latent", type=int, default=PAPER["latent"])
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--optimizer", default="adam")
    ap.add_argument("--unmasked", action="store_true", help="the paper's network over every triangle")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--compare-optimisers", action="store_true",
                    help="each optimiser on a MakeHuman fold (loss, held-out error, time)")
    args = ap.parse_args(argv)

    if args.compare_optimisers:
        res = compare_optimisers(args.epochs, args.threads)
        if args.json:
            print(json.dumps(res, indent=1))
        else:
            print(res["data"])
            print("| optimiser | lr | epochs | loss at 10% | final loss | best held-out | at epoch | s "
                  "| CPU s |")
            print("|---|---|---|---|---|---|---|---|---|")
            for r in res["rows"]:
                print(f"| {r['optimizer']} | {r['lr']} | {r['epochs']} | {r['loss_at_10pct']:.4f} | "
                      f"{r['final_loss']:.4f} | {r['best_heldout']:.4f} | {r['best_heldout_epoch']} | "
                      f"{r['seconds']:.1f} | {r['cpu_seconds']:.1f} |")
            print(f"held-out error of the plain mean of the training fields: {res['mean_field_heldout']:.4f}")
        return

    from garment_transfer.learning.training import default_threads, train_model

    fields = synthetic_fields(args.garments, args.targets)
    t0, c0 = time.perf_counter(), time.process_time()
    model, info = train_model(fields, latent=args.latent, epochs=args.epochs, optimizer=args.optimizer,
                              masked=not args.unmasked, threads=args.threads)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {
        "data": "synthetic fields (no real dataset of the paper's size here): timing only",
        "body_triangles": fields.body.n_triangles, "garments": args.garments, "targets": args.targets,
        "active_triangles": info["active_triangles"], "network_values": 9 * info["active_triangles"],
        "latent": args.latent, "epochs": info["epochs"], "optimizer": info["optimizer"],
        "masked": not args.unmasked, "threads": info["threads"],
        "train_seconds": info["seconds"], "wall_seconds_with_export": round(wall, 2),
        "cpu_seconds": round(cpu, 2),
        "ms_per_epoch": round(1000 * info["seconds"] / max(info["epochs"], 1), 2),
        "final_loss": info["final_loss"], "paper_seconds": PAPER["seconds"],
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores "
                   f"(default threads {default_threads()})",
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"{out['data']}")
        print(f"body {out['body_triangles']} triangles ({out['active_triangles']} in the network, "
              f"{out['network_values']} values), {args.garments} garments x {args.targets} target(s), "
              f"latent {args.latent}, {out['optimizer']}, "
              f"{'masked' if out['masked'] else 'unmasked (paper)'}")
        print(f"{out['epochs']} epochs: {out['train_seconds']:.1f} s ({out['ms_per_epoch']} ms/epoch, "
              f"{out['cpu_seconds']:.1f} s CPU, {out['threads']} threads; load average "
              f"{out['load_average_1min']})  paper: {PAPER['seconds']} s")
        print(f"final loss {out['final_loss']:.4g}  on {out['machine']}")


if __name__ == "__main__":
    main()
