"""The garment fit model against direct transfer and the paper's model, with ablations, in one run.

Parts (``--parts``, default all):

* ``demo``: the demo's 15 training garments (and the extra generated ones, ``--extra``) train every
  model; its 5 test garments go to the targets (``--targets``). Methods: direct transfer (anchors
  everywhere, and only where the garment rests on the body), the paper's shared model (decoder at the
  mean latent), the garment fit model with anchors everywhere and with contact anchors, without the
  target label, without the garment's distance and direction, and the held-out garment's own
  embedded deformation with contact anchors (the ceiling of any body field here); with the learned
  placement (``garment_placed``, ``garment_placed_contact``, ``direct_placed``) and the held-out
  garment's own placement (``*_oracle_placed*``, ``oracle_placed*``: the ceiling of a placement).
  ``--validation g1,g2``: test on these training garments instead (held out with their loose and tight
  variants), to choose settings such as the field share (``garment_share<s>_placed``) without the test
  garments; in the ``makehuman`` part these are catalogue garments (``lab.makehuman_procedural``), one fold
  trained on every other garment, the fixture garments included.
* ``unseen_body``: one target body (``--unseen``, one of ``--targets``) is left out of training; the
  test garments go to it with label weights read from its shape (between the training bodies), against
  the same model trained on every target (``--placement``: also with the learned placement, with the body's
  own field, the garment model's and half of it (``--field-share``); ``--placement-blend``: an unseen body
  gets the blend of the placements predicted on the training bodies; ``--placement-body-offset``: the
  placement model also sees the target's offset from the source body). ``--data``/``--extra`` as for demo.
* ``between``: the test garments on bodies between two training bodies (``lab.procedural.mannequin.BETWEEN``,
  every measurement interpolated; ``python -m lab.garment_data between`` drapes them, ``unpack`` adds them to
  the ``--data`` folder), which the models were not trained on: the body's label weights from its shape and
  the blend of the training bodies' placements, against the two training bodies it lies between (their
  errors interpolated at its share) in the same run and, with ``--between-in-training``, against models
  trained on it too (``--placement-nolabel``, ``--placement-body-offset`` as for unseen_body; the placement is
  always the blend).
* ``--placement-members N`` (demo, unseen_body, between): the learned placement is the mean of N placement models
  trained with seeds seed .. seed+N-1 (``placement.PlacementEnsemble``); 1 (default): one model.
  ``--placement-residual``: each learns the offset less the training garments' mean offset per triangle
  (``placement.mean_offsets``); ``--placement-hidden``, ``--placement-lr``, ``--placement-schedule``,
  ``--placement-weight-decay``, ``--placement-weighted``: ``garment_training.train_placement_model``'s
  other training options (default: its defaults, as the recorded figures).
* ``makehuman``: leave-one-garment-out on the MakeHuman fixtures (``--makehuman-garments`` held out in
  turn; set ``GARMENT_TRANSFER_MAKEHUMAN`` when the fixtures are not in ``../shared``). The fixtures'
  garments are MakeHuman's proxy fits (body-driven); ``GARMENT_TRANSFER_MAKEHUMAN=DIR`` with the folder
  that ``python -m lab.makehuman_drape --out DIR`` writes measures against the same garments simulated by
  Blender's cloth solver instead (the reference rows are then named ``simulation``); the catalogue garments
  that ``python -m lab.makehuman_procedural --out DIR`` adds to that folder are in every fold's training set
  and never held out. Besides the methods
  in ``MH_METHODS``, ``garment_share<s>_placed`` (the garment model's field at share ``s`` with the learned
  placement) runs here too.

Usage::

    nice python -m lab.garment_model [--parts demo,unseen_body,makehuman] [--json out.json]
"""

from __future__ import annotations

import argparse
import re
import sys
import time

import numpy as np

from garment_transfer.files import write_json_atomic
from garment_transfer.learning import placement
from garment_transfer.learning.dataset import load_dataset
from garment_transfer.learning.garment_model import label_weights
from garment_transfer.learning.garment_training import (
    SCHEDULES,
    nearest_garments,
    placement_tables,
    train_garment_model,
    training_tables,
)
from garment_transfer.pipeline.metrics import evaluate
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

from . import experiment
from .experiment import run_experiment
from .makehuman_drape import failed_drapes
from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, makehuman_folder

DEMO_METHODS = ["direct", "direct_contact", "shared", "garment", "garment_contact", "garment_nolabel_contact",
                "garment_blind_contact", "oracle_contact"]
MH_METHODS = ["direct", "direct_contact", "shared", "garment_contact", "garment_blind_contact", "oracle_contact",
              "direct_placed", "garment_placed", "garment_half_placed", "direct_oracle_placed", "garment_oracle_placed",
              "direct_nearest_placed", "direct_mixed_placed", "garment_half_nearest_placed",
              "garment_half_mixed_placed", "direct_shrunk_placed", "garment_half_shrunk_placed",
              "direct_length_placed", "garment_half_length_placed"]
FIGURES = [("vertex_error_mean", "vertex error", 1000.0), ("drape_error_relative", "drape rel.", 1.0),
           ("mdc", "MDC", 1.0), ("penetrating_vertices", "inside", 1.0)]


def summarise(rows, methods, reference, targets, scale=1000.0, unit="mm"):
    """Printed table: per target and method, the mean over test garments; ratios to direct."""
    lines = [f"{'target':10s} {'method':26s} {'vertex ' + unit:>10s} {'x direct':>8s} {'drape rel':>9s} "
             f"{'MDC':>7s} {'x direct':>8s} {'inside':>6s}"]
    table = {}
    for t in targets:
        def mean(m, key):
            v = [r[key] for r in rows if r["method"] == m and r["target"] == t and r.get(key) is not None]
            return float(np.mean(v)) if v else float("nan")

        d_ve, d_mdc = mean("direct", "vertex_error_mean"), mean("direct", "mdc")
        for m in [reference] + methods:
            ve, mdc = mean(m, "vertex_error_mean"), mean(m, "mdc")
            entry = {"vertex_error": ve * scale, "vertex_ratio": ve / d_ve, "drape_relative":
                     mean(m, "drape_error_relative"), "mdc": mdc, "mdc_ratio": mdc / d_mdc,
                     "inside": sum(r["penetrating_vertices"] for r in rows if r["method"] == m and r["target"] == t)}
            table[f"{t}/{m}"] = entry
            lines.append(f"{t:10s} {m:26s} {entry['vertex_error']:10.1f} {entry['vertex_ratio']:8.2f} "
                         f"{entry['drape_relative']:9.3f} {entry['mdc']:7.4f} {entry['mdc_ratio']:8.2f} "
                         f"{entry['inside']:6d}")
    return "\n".join(lines), table


def validation_fold(train, styles, outfits=None):
    """A validation fold that never touches the test garments: the training styles ``styles`` held out
    with their loose and tight variants, and the outfits (``outfits``: name -> its pieces' garments) with a
    piece among them. Returns (training garments, held-out garments)."""
    held = set(styles) | {f"{g}_{v}" for g in styles for v in ("loose", "tight")}
    missing = [g for g in styles if g not in train]
    if missing:
        raise SystemExit(f"--validation: {', '.join(missing)} not among the training garments")
    held |= {name for name, pieces in (outfits or {}).items() if held & set(pieces)}
    return [g for g in train if g not in held], list(styles)


def demo_part(args, say):
    ds = load_dataset(args.data)
    train = list(ds.manifest["train_garments"]) + [g for g in ds.garments if g in (args.extra or [])]
    test = list(ds.manifest["test_garments"])
    if args.validation:
        train, test = validation_fold(train, args.validation)
    say(f"demo: {len(train)} training garments, {len(test)} test garments, targets {args.targets}")
    res = run_experiment(args.data, ds.manifest["source"], args.targets, [(train, test)], args.methods,
                         args.epochs, seed=args.seed, threads=args.threads,
                         progress=lambda f, s: say(f"demo: {s}"))
    text, table = summarise(res["rows"], args.methods, "simulation", args.targets)
    return {"rows": res["rows"], "trainings": res["trainings"], "table": table, "text": text,
            "train": train, "test": test}


def with_nearest(placer, tables, targets, train, share):
    """The placement networks mixed with the training garments' nearest garments' placement at ``share``
    (``placement.MixedPlacement``, as ``train --kind garment`` writes it); 0: the networks alone."""
    if not share:
        return placer
    return placement.MixedPlacement(placer, nearest_garments(tables, targets, list(train),
                                                             width=experiment.NEAREST_WIDTH), share)


def model_runs(model, half, placer, label):
    """The learned methods the unseen_body and between parts run, as (key, anchoring, transfer_garment's
    arguments): the garment model with contact anchors, and with a placement ``placer`` (None: none) the
    body's own field, the garment model's whole field (anchors everywhere and contact) and its field at the
    share of ``half``, each placed by it; ``label``: the target label (None: from the body's shape)."""
    runs = [("garment_contact", "contact", dict(method="model", model=model, target=label))]
    if placer is not None:
        runs += [("direct_placed", "everywhere", dict(method="direct", placement=placer, target=label)),
                 ("garment_placed", "everywhere", dict(method="model", model=model, placement=placer, target=label)),
                 ("garment_placed_contact", "contact", dict(method="model", model=model, placement=placer,
                                                            target=label)),
                 ("garment_half_placed", "everywhere", dict(method="model", model=half, placement=placer,
                                                            target=label))]
    return runs


UNSEEN_RUNS = ["direct", "garment_contact", "direct_placed", "garment_placed", "garment_placed_contact",
               "garment_half_placed"]


def unseen_body_part(args, say):
    """The garment fit model (and the learned placement) on a target body it was not trained on, against the
    same models trained with it; the demo's training garments and ``--extra``."""
    ds = load_dataset(args.data)
    source = ds.manifest["source"]
    train = list(ds.manifest["train_garments"]) + [g for g in ds.garments if g in (args.extra or [])]
    test = list(ds.manifest["test_garments"])
    src = ds.body(source)
    body = ds.body(args.unseen)
    say(f"unseen body: {len(train)} training garments, {len(test)} test garments to {args.unseen}")
    rows, info = [], {}
    for with_it in (True, False):
        targets = [t for t in args.targets if with_it or t != args.unseen]
        tables = training_tables(ds, source, targets, train)
        model, tinfo = train_garment_model(tables, targets, epochs=experiment.GARMENT_EPOCHS, seed=args.seed,
                                           threads=args.threads)
        placer = None
        if args.placement:
            placement_tables(ds, source, targets, train, tables)
            placer, _ = experiment.train_placement(tables, targets, seed=args.seed, threads=args.threads,
                                                   use_label=not args.placement_nolabel,
                                                   body_offset=args.placement_body_offset)
            placer = with_nearest(placer, tables, targets, train, args.nearest_garments)
            if args.placement_blend:
                placer = placement.BlendedPlacement(placer)
        weights = model.label_weights_for(body, args.unseen if with_it else None)
        info["with" if with_it else "without"] = {"targets": targets, "label_weights": weights.tolist(),
                                                  "train_seconds": tinfo["seconds"]}
        say(f"unseen body: trained on {targets} in {tinfo['seconds']:.0f}s; label weights of "
            f"{args.unseen}: {np.round(weights, 3).tolist()}")
        label = args.unseen if with_it else None
        half = model.with_field_share(args.field_share)
        for g in test:
            garment = ds.garment(g, source)
            prepared = {a: prepare_garment(src, garment, anchoring=a) for a in ("everywhere", "contact")}
            ref = ds.garment(g, args.unseen)
            runs = model_runs(model, half, placer, label)
            if with_it:
                runs.append(("direct", "everywhere", dict(method="direct")))
            for key, anchoring, kw in runs:
                r = transfer_garment(src, body, garment, prepared=prepared[anchoring], **kw)
                e = evaluate(garment, garment.with_vertices(r.V), body, reference=ref)
                e.update(garment=g, target=args.unseen, method=key if with_it or key == "direct"
                         else f"{key}_unseen")
                rows.append(e)
    bodies = np.stack([ds.body(t).V for t in args.targets if t != args.unseen])
    info["shape_weights_of_unseen"] = label_weights(body.V, bodies).tolist()

    def mean(m, k):
        return float(np.mean([r[k] for r in rows if r["method"] == m]))

    lines = [f"{'method':30s} {'vertex mm':>9s} {'drape rel':>9s} {'MDC':>7s} {'inside':>6s}"]
    shown = [m for m in UNSEEN_RUNS if any(r["method"] == m for r in rows)]
    for m in shown:
        for name in ([m] if m == "direct" else [m, f"{m}_unseen"]):
            lines.append(f"{name:30s} {1000 * mean(name, 'vertex_error_mean'):9.1f} "
                         f"{mean(name, 'drape_error_relative'):9.3f} {mean(name, 'mdc'):7.4f} "
                         f"{sum(r['penetrating_vertices'] for r in rows if r['method'] == name):6d}")
    ratios = {m: mean(f"{m}_unseen", "vertex_error_mean") / mean(m, "vertex_error_mean")
              for m in shown if m != "direct"}
    for m, x in ratios.items():
        lines.append(f"vertex error, body unseen / body in training, {m}: {x:.2f}")
    info.update(rows=rows, ratio=ratios["garment_contact"], ratios=ratios, text="\n".join(lines))
    if "garment_placed_contact" in ratios:
        info["ratio_placed"] = ratios["garment_placed_contact"]
    return info


BETWEEN_RUNS = ["direct", "garment_contact", "direct_placed", "garment_placed", "garment_half_placed"]


def between_part(args, say):
    """The test garments on bodies between two training bodies (every measurement interpolated,
    ``lab.procedural.mannequin.BETWEEN``; draped by ``python -m lab.garment_data between``), which no model
    was trained on: label weights from the body's shape, the blend of the training bodies' placements.
    Compared with the two training bodies it lies between (same models, same run) and, with
    ``--between-in-training``, with models trained on it too."""
    ds = load_dataset(args.data)
    between = ds.manifest.get("between_bodies") or {}
    if not between:
        raise SystemExit(f"{args.data}: no in-between bodies (make the folder with python -m lab.garment_data "
                         "unpack, which adds data/extra/between.npz)")
    source = ds.manifest["source"]
    train = list(ds.manifest["train_garments"]) + [g for g in ds.garments if g in (args.extra or [])]
    test = list(ds.manifest["test_garments"])
    targets = [t for t in args.targets if t not in between]
    for b, (a, c, _) in between.items():
        if a not in targets or c not in targets:
            raise SystemExit(f"{b} lies between {a} and {c}: both must be training targets (--targets)")
    # The training bodies the in-between ones lie between, each once.
    ends = list(dict.fromkeys(x for a, c, _ in between.values() for x in (a, c)))
    variants = [("unseen", targets)]
    if args.between_in_training:
        lacking = [g for g in train if not all(ds.has_garment(g, b) for b in between)]
        if lacking:
            raise SystemExit(f"--between-in-training: {len(lacking)} training garments are not draped on "
                             f"{', '.join(between)} (e.g. {lacking[0]}); run python -m lab.garment_data between")
        variants.append(("in_training", targets + list(between)))
    src = ds.body(source)
    say(f"between: {len(train)} training garments, {len(test)} test garments; training bodies {targets}; "
        f"in-between bodies {', '.join(f'{b} ({a}/{c} {t:g})' for b, (a, c, t) in between.items())}")
    rows, info = [], {"between": between, "targets": targets, "label_weights": {}}
    garments = {g: ds.garment(g, source) for g in test}
    prepared = {g: {a: prepare_garment(src, G, anchoring=a) for a in ("everywhere", "contact")}
                for g, G in garments.items()}
    for variant, tgts in variants:
        tables = training_tables(ds, source, tgts, train)
        model, tinfo = train_garment_model(tables, tgts, epochs=experiment.GARMENT_EPOCHS, seed=args.seed,
                                           threads=args.threads)
        placement_tables(ds, source, tgts, train, tables)
        placer, pinfo = experiment.train_placement(tables, tgts, seed=args.seed, threads=args.threads,
                                                   use_label=not args.placement_nolabel,
                                                   body_offset=args.placement_body_offset)
        placer = placement.BlendedPlacement(with_nearest(placer, tables, tgts, train, args.nearest_garments))
        half = model.with_field_share(args.field_share)
        say(f"between ({variant}): trained on {tgts} in {tinfo['seconds']:.0f} + {pinfo['seconds']:.0f} s")
        if variant == "unseen":
            bodies = [(b, None) for b in between] + [(t, t) for t in ends]
        else:
            bodies = [(b, b) for b in between]
        for body_name, label in bodies:
            body = ds.body(body_name)
            weights = model.label_weights_for(body, label)
            info["label_weights"][f"{body_name} ({variant})"] = dict(zip(tgts, np.round(weights, 4).tolist()))
            runs = [r for r in model_runs(model, half, placer, label) if r[0] in BETWEEN_RUNS]
            if variant == "unseen":
                runs.insert(0, ("direct", "everywhere", dict(method="direct")))
            for g, G in garments.items():
                ref = ds.garment(g, body_name)
                for key, anchoring, kw in runs:
                    r = transfer_garment(src, body, G, prepared=prepared[g][anchoring], **kw)
                    e = evaluate(G, G.with_vertices(r.V), body, reference=ref)
                    e.update(garment=g, target=body_name, method=key if variant == "unseen" else f"{key}_in_training")
                    rows.append(e)
            say(f"between ({variant}): {body_name} done")

    def mean(m, t, k="vertex_error_mean"):
        vals = [r[k] for r in rows if r["method"] == m and r["target"] == t]
        return float(np.mean(vals)) if vals else float("nan")

    lines = [f"{'body':12s} {'method':26s} {'vertex mm':>9s} {'x direct':>8s} {'drape rel':>9s} {'MDC x dir':>9s} "
             f"{'inside':>6s}"]
    for t in list(between) + ends:
        for m in BETWEEN_RUNS + [f"{k}_in_training" for k in BETWEEN_RUNS[1:]]:
            if np.isnan(mean(m, t)):
                continue
            lines.append(f"{t:12s} {m:26s} {1000 * mean(m, t):9.1f} {mean(m, t) / mean('direct', t):8.2f} "
                         f"{mean(m, t, 'drape_error_relative'):9.3f} "
                         f"{mean(m, t, 'mdc') / mean('direct', t, 'mdc'):9.2f} "
                         f"{sum(r['penetrating_vertices'] for r in rows if r['method'] == m and r['target'] == t):6d}")
    ratios = {}
    for b, (a, c, share) in between.items():
        for m in BETWEEN_RUNS[1:]:
            # The training bodies' errors interpolated at the in-between body's share.
            at_share = (1 - share) * mean(m, a) + share * mean(m, c)
            at_share_rel = (1 - share) * mean(m, a) / mean("direct", a) + share * mean(m, c) / mean("direct", c)
            ratios[f"{b}/{m}"] = {"to_training_bodies": mean(m, b) / at_share,
                                  "to_training_bodies_x_direct": (mean(m, b) / mean("direct", b)) / at_share_rel,
                                  "to_itself_in_training": mean(m, b) / mean(f"{m}_in_training", b)}
            x = ratios[f"{b}/{m}"]
            lines.append(f"{b} {m}: vertex error / its training bodies' ({a}, {c}) {x['to_training_bodies']:.2f}; "
                         f"in units of direct's {x['to_training_bodies_x_direct']:.2f}"
                         + ("" if np.isnan(x["to_itself_in_training"]) else
                            f"; / itself in training {x['to_itself_in_training']:.2f}"))
    info.update(rows=rows, ratios=ratios, text="\n".join(lines))
    return info


def makehuman_folds(garments, manifest, held=None, failed=()):
    """Leave-one-garment-out folds of a MakeHuman folder: each held-out garment (``held``, else every fixture
    garment) tested on its own, trained on the folder's other garments. Garments of the procedural catalogue
    (``procedural_garments``, lab.makehuman_procedural) train every fold and are never held out by default;
    a looser cut of a fixture garment (``variants``, lab.makehuman_drape --loose) trains every fold but its
    original's; a garment whose drape failed (``failed``, lab.makehuman_drape.failed_drapes) is neither
    trained on nor tested. Returns (held, [(training, [held garment]), ...])."""
    procedural = manifest.get("procedural_garments", [])
    variants = manifest.get("variants", {})
    garments = [g for g in garments if g not in failed]
    held = [g for g in held if g not in failed] if held else \
        [g for g in garments if g not in procedural and g not in variants]
    return held, [([g for g in garments if g != h and variants.get(g) != h], [h]) for h in held]


def makehuman_part(args, say):
    folder = makehuman_folder()
    if folder is None:
        say("makehuman: fixtures not found (set GARMENT_TRANSFER_MAKEHUMAN); skipped")
        return None
    ds = load_dataset(folder)
    failed = {} if args.keep_failed_drapes or "placed_by" not in ds.manifest else \
        failed_drapes(ds, MAKEHUMAN_SOURCE, list(MAKEHUMAN_TARGETS))
    for g, slid in failed.items():
        say(f"makehuman: {g} left out, its drape slid off the shoulders on "
            + ", ".join(f"{t} ({100 * d:.1f}% of the body's height)" for t, d in slid.items()))
    held, folds = makehuman_folds(ds.garments, ds.manifest, args.makehuman_garments, failed)
    if args.validation:
        # One fold: catalogue garments held out with their variants, every fixture garment in training.
        train, held = validation_fold([g for g in ds.garments if g not in failed], args.validation,
                                      ds.manifest.get("outfits"))
        folds = [(train, held)]
    methods = [m for m in args.methods if m in MH_METHODS or re.fullmatch(r"garment_share[0-9.]+(_mixed)?_placed", m)]
    # The fixtures' own garments are MakeHuman's proxy fits; lab.makehuman_drape writes the same garments
    # simulated by the cloth solver (its manifest says so).
    reference = "simulation" if "placed_by" in ds.manifest else "fitted"
    res = run_experiment(folder, MAKEHUMAN_SOURCE, list(MAKEHUMAN_TARGETS), folds, methods, args.epochs,
                         reference=reference, seed=args.seed, threads=args.threads,
                         progress=lambda f, s: say(f"makehuman: {s}"))
    # Decimetres: vertex errors in mm are 100 x.
    text, table = summarise(res["rows"], methods, reference, list(MAKEHUMAN_TARGETS), scale=100.0)
    return {"rows": res["rows"], "trainings": res["trainings"], "table": table, "text": text, "held_out": held,
            "reference": reference, "folder": str(folder), "failed_drapes": failed}


def placement_options(args):
    """The ``train_placement_model`` arguments the command line sets (those given only)."""
    hidden = None if args.placement_hidden is None else tuple(int(x) for x in args.placement_hidden.split(","))
    return {k: v for k, v in (("hidden", hidden), ("lr", args.placement_lr), ("schedule", args.placement_schedule),
                              ("weight_decay", args.placement_weight_decay),
                              ("weighted", args.placement_weighted or None),
                              ("residual", args.placement_residual or None)) if v is not None}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", default="demo,unseen_body,makehuman")
    ap.add_argument("--data", default=str(DEMO_DATA))
    ap.add_argument("--targets", default="pear,heavy,hourglass")
    ap.add_argument("--extra", default="", help="extra training garments of --data, comma-separated")
    ap.add_argument("--unseen", default="hourglass")
    ap.add_argument("--between-in-training", action="store_true",
                    help="between: also train with the in-between bodies (every training garment draped on them)")
    ap.add_argument("--validation", default="",
                    help="demo, makehuman: test on these training garments instead (held out with their _loose and "
                         "_tight variants; makehuman: catalogue garments, one fold with every fixture garment "
                         "in training), to choose settings without the test garments")
    ap.add_argument("--makehuman-garments", default="female_casualsuit01,male_casualsuit02")
    ap.add_argument("--keep-failed-drapes", action="store_true",
                    help="makehuman: also train and test on garments whose drape slid off the shoulders "
                         "(lab.makehuman_drape.failed_drapes; left out by default)")
    ap.add_argument("--methods", default=",".join(DEMO_METHODS),
                    help="keys of lab.experiment.METHODS (MakeHuman runs those of them in MH_METHODS)")
    ap.add_argument("--epochs", type=int, default=300, help="epochs of the paper's shared model")
    ap.add_argument("--garment-epochs", type=int, default=experiment.GARMENT_EPOCHS,
                    help="passes over the samples of the garment fit model")
    ap.add_argument("--placement", action="store_true",
                    help="unseen_body: also the garment model with the learned placement")
    ap.add_argument("--placement-nolabel", action="store_true",
                    help="unseen_body, between: the placement model without the target label (body features only)")
    ap.add_argument("--placement-body-offset", action="store_true",
                    help="unseen_body, between: the placement model also sees the target's offset from the source body")
    ap.add_argument("--placement-blend", action="store_true",
                    help="unseen_body: an unseen body gets the blend of the placements predicted on the training "
                         "bodies, by its label weights (placement.BlendedPlacement)")
    ap.add_argument("--placement-epochs", type=int, default=experiment.PLACEMENT_EPOCHS,
                    help="passes over the samples of the placement model")
    ap.add_argument("--placement-members", type=int, default=experiment.PLACEMENT_MEMBERS,
                    help="placement models trained with seeds seed, seed+1, ... and averaged "
                         "(placement.PlacementEnsemble); 1: one model")
    ap.add_argument("--field-members", type=int, default=experiment.FIELD_MEMBERS,
                    help="garment fit models trained with seeds seed, seed+1, ... and their fields averaged "
                         "(experiment.FieldEnsemble); 1: one model")
    ap.add_argument("--placement-hidden", default=None,
                    help="hidden layer widths of the placement model, comma-separated (default "
                         "garment_training.train_placement_model's)")
    ap.add_argument("--placement-lr", type=float, default=None, help="the placement model's learning rate")
    ap.add_argument("--placement-schedule", choices=SCHEDULES, default=None,
                    help="the placement model's learning rate decay (garment_training.SCHEDULES)")
    ap.add_argument("--placement-weight-decay", type=float, default=None,
                    help="the placement model's decoupled weight decay (AdamW)")
    ap.add_argument("--placement-weighted", action="store_true",
                    help="the placement model's loss weighted by the garment points bound to each triangle")
    ap.add_argument("--placement-residual", action="store_true",
                    help="the placement model learns the offset less the training garments' mean offset per "
                         "triangle (placement.mean_offsets), as train --kind garment does by default")
    ap.add_argument("--placement-smoothing", type=float, default=placement.SMOOTHING_SHARE,
                    help="smoothing length of the placement (its training targets and predictions), as a share "
                         "of the body scale")
    ap.add_argument("--nearest-garments", type=float, default=0.0,
                    help="unseen_body, between: the share of the nearest garments' placement mixed with the "
                         "networks' (placement.MixedPlacement; train --kind garment's default is "
                         "placement.LIBRARY_SHARE); 0: the networks alone. The demo and makehuman parts run it "
                         "as the methods *_mixed_placed (not shrunk) and *_shrunk_placed")
    ap.add_argument("--nearest-width", type=float, default=None,
                    help="the nearest garments' similarity width (default placement.SIMILARITY_WIDTH)")
    ap.add_argument("--shrink-disagreement", type=float, default=experiment.DISAGREEMENT_SHRINK,
                    help="the *_shrunk_placed methods' factor c of placement.shrink_gain (default 1): the mixed "
                         "placement shrunk where its two predictions disagree")
    ap.add_argument("--field-share", type=float, default=0.5,
                    help="unseen_body: the garment model's field share of garment_half_placed")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    args.targets = args.targets.split(",")
    args.methods = args.methods.split(",")
    experiment.GARMENT_EPOCHS = args.garment_epochs
    placement.SMOOTHING_SHARE = args.placement_smoothing
    experiment.PLACEMENT_EPOCHS = args.placement_epochs
    experiment.PLACEMENT_MEMBERS = args.placement_members
    experiment.FIELD_MEMBERS = args.field_members
    experiment.PLACEMENT_OPTIONS = placement_options(args)
    experiment.NEAREST_WIDTH = args.nearest_width
    experiment.DISAGREEMENT_SHRINK = args.shrink_disagreement
    args.extra = [g for g in args.extra.split(",") if g]
    args.validation = [g for g in args.validation.split(",") if g]
    args.makehuman_garments = [g for g in args.makehuman_garments.split(",") if g]
    t0 = time.perf_counter()

    def say(text):
        print(f"[{time.perf_counter() - t0:6.0f}s] {text}", flush=True)

    out = {"command": " ".join(["python -m lab.garment_model", *(argv if argv is not None else sys.argv[1:])])}
    for part in args.parts.split(","):
        fn = {"demo": demo_part, "unseen_body": unseen_body_part, "between": between_part,
              "makehuman": makehuman_part}[part]
        out[part] = fn(args, say)
        if out[part]:
            print(f"\n== {part}\n{out[part]['text']}\n", flush=True)
        if args.json:
            write_json_atomic(args.json, out)
    for key in args.methods:
        print(f"{key:26s} {experiment.method_of(key).label}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
