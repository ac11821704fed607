"""Command line: ``python -m garment_transfer <command> ...`` (``--help`` on each).

Exit code 0 on success, 1 on an input or model problem (one line naming the file and what is
wrong, and no output file written), 2 on a usage error.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time

from .errors import GarmentTransferError

log = logging.getLogger("garment_transfer")


def _emit(args, result: dict, lines):
    if getattr(args, "json", False):
        print(json.dumps(result, indent=2, default=_jsonable))
    else:
        for line in lines:
            print(line)


def _jsonable(x):
    import numpy as np

    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def _stderr_progress(label, every=0.05):
    state = {"last": -1.0}

    def progress(fraction, *info):
        if fraction - state["last"] >= every or fraction >= 1.0:
            state["last"] = fraction
            extra = " ".join(f"{v:.5g}" if isinstance(v, float) else str(v) for v in info if v is not None)
            print(f"{label}: {100 * fraction:5.1f}% {extra}", file=sys.stderr, flush=True)
        return False

    return progress


def cmd_transfer(args):
    from .obj import read_obj

    if len(args.garment) > 1:
        return cmd_transfer_outfit(args)
    if len(args.out) != 1:
        raise GarmentTransferError(f"one garment needs one --out, got {len(args.out)}")
    from .obj import write_obj
    from .transfer import transfer_garment

    args.garment, args.out = args.garment[0], args.out[0]
    t = time.perf_counter()
    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    garment = read_obj(args.garment)
    model = _model_for(args)
    load = time.perf_counter() - t
    result = transfer_garment(source_body, target_body, garment, method=args.method, model=model,
                              target=args.target, offset=args.offset, fix_penetration=not args.no_fix,
                              interpolate=not args.no_interpolate,
                              resolve_crossings=not args.no_crossing_pass)
    t = time.perf_counter()
    write_obj(args.out, garment, result.V,
              header=f"Garment Transfer: {os.path.basename(args.garment)} on "
                     f"{os.path.basename(args.target_body)} ({args.method})")
    seconds = dict(result.seconds, load=load, write=time.perf_counter() - t)
    out = {"out": args.out, "method": args.method, "target": args.target,
           "vertices": garment.n_vertices, "triangles": garment.n_triangles,
           "seconds": seconds, "penetrating_vertices": result.penetrating_vertices,
           "info": result.info}
    _emit(args, out, [f"wrote {args.out}: {garment.n_vertices} vertices, {garment.n_faces} faces, "
                      f"{result.penetrating_vertices} inside the target body, "
                      f"{result.seconds['total']:.3f} s (transfer)"])


def _model_for(args):
    if args.method != "model":
        return None
    if not args.model:
        raise GarmentTransferError("--method model needs --model MODEL.npz and --target LABEL")
    from .model import load_model

    return load_model(args.model)


def outfit_out_paths(garments, outs):
    """Output files of an outfit: one --out per garment, or one existing folder for all
    (``<garment file name>`` inside it). Refuses to overwrite an input."""
    if len(outs) == 1 and os.path.isdir(outs[0]):
        paths = [os.path.join(outs[0], os.path.basename(g)) for g in garments]
    elif len(outs) == len(garments):
        paths = list(outs)
    else:
        raise GarmentTransferError(f"{len(garments)} garments need {len(garments)} --out files or one "
                                   f"existing --out folder, got {len(outs)} --out")
    if len({os.path.abspath(p) for p in paths}) != len(paths):
        raise GarmentTransferError(f"two layers would be written to the same file: {', '.join(paths)}")
    inputs = {os.path.abspath(g) for g in garments}
    for p in paths:
        if os.path.abspath(p) in inputs:
            raise GarmentTransferError(f"{p}: is an input garment; write the result elsewhere")
    return paths


def write_all_or_nothing(paths, texts):
    """Write every text to its path, or none: all go to temporary files first, then are renamed."""
    import tempfile

    temps = []
    try:
        for path, text in zip(paths, texts):
            folder = os.path.dirname(os.path.abspath(path))
            if not os.path.isdir(folder):
                raise GarmentTransferError(f"{path}: the folder {folder} does not exist")
            fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".obj", dir=folder)
            temps.append(tmp)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
        for path, tmp in zip(paths, temps):
            os.replace(tmp, path)
    finally:
        for tmp in temps:
            if os.path.exists(tmp):
                os.unlink(tmp)


def cmd_transfer_outfit(args):
    from .obj import obj_text, read_obj
    from .outfit import transfer_outfit

    paths = outfit_out_paths(args.garment, args.out)
    if args.no_fix or args.no_crossing_pass:
        raise GarmentTransferError("an outfit of several layers is always separated: "
                                   "--no-fix and --no-crossing-pass apply to one garment only")
    t = time.perf_counter()
    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    garments = [read_obj(g, name=g) for g in args.garment]
    model = _model_for(args)
    load = time.perf_counter() - t
    result = transfer_outfit(source_body, target_body, garments, offsets=args.offset, method=args.method,
                             model=model, target=args.target, interpolate=not args.no_interpolate)
    t = time.perf_counter()
    on = f"{os.path.basename(args.target_body)} ({args.method})"
    texts = [obj_text(g, V, header=f"Garment Transfer: {os.path.basename(f)} (layer {k + 1} of "
                                   f"{len(garments)}) on {on}")
             for k, (g, V, f) in enumerate(zip(garments, result.V, args.garment))]
    write_all_or_nothing(paths, texts)
    seconds = dict(result.seconds, load=load, write=time.perf_counter() - t)
    out = {"out": paths, "method": args.method, "target": args.target, "seconds": seconds,
           "layers": [{"garment": f, "out": p, "vertices": g.n_vertices, "triangles": g.n_triangles,
                       "info": i} for f, p, g, i in zip(args.garment, paths, garments, result.info)]}
    _emit(args, out, [f"wrote {p}: layer {k + 1} of {len(paths)}" for k, p in enumerate(paths)]
          + [f"{result.seconds['total']:.3f} s (outfit transfer)"])


def cmd_evaluate(args):
    from .metrics import evaluate
    from .obj import read_obj

    source = read_obj(args.source)
    result = read_obj(args.result)
    target_body = read_obj(args.target_body)
    reference = read_obj(args.reference) if args.reference else None
    source_body = read_obj(args.source_body) if args.source_body else None
    out = evaluate(source, result, target_body, reference=reference, source_body=source_body)
    _emit(args, out, [f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}" for k, v in out.items()])


def cmd_train(args):
    try:
        from .training import train_from_dataset
    except ImportError as exc:
        raise GarmentTransferError(
            f"training needs torch ({exc}); install it with: pip install torch==2.13.0") from None
    targets = [t for t in args.targets.split(",") if t]
    garments = [g for g in args.garments.split(",") if g] if args.garments else None
    summary = train_from_dataset(args.dataset, args.source, targets, garments=garments,
                                 epochs=args.epochs, latent=args.latent, seed=args.seed, out=args.out,
                                 progress=_stderr_progress("train"),
                                 masked=not args.unmasked)
    _emit(args, summary, [f"wrote {args.out}: {summary.get('epochs')} epochs, final loss "
                          f"{summary.get('final_loss')}, {summary.get('seconds', 0):.1f} s"])


def cmd_bench(args):
    if args.report:
        from .report import run_report

        quick = " --quick" if args.quick else ""
        command = f"python -m garment_transfer bench --report {args.report}{quick}"
        out = run_report(args.report, quick=args.quick, progress=_stderr_progress("report"), command=command)
        _emit(args, {"report": os.path.join(args.report, "report.md"), "seconds": out["seconds"]},
              [f"wrote {os.path.join(args.report, 'report.md')}, report.json and "
               f"{', '.join(out['plots'])} in {out['seconds']['total']:.0f} s"])
        return
    from .bench import run_bench

    out = run_bench(sizes=args.sizes, repeats=args.repeats, targets=args.targets,
                    progress=_stderr_progress("bench"))
    from .bench import format_bench

    _emit(args, out, format_bench(out))


def cmd_demo(args):
    from .demo import run_demo

    out = run_demo(args.out, quick=args.quick, progress=_stderr_progress("demo", every=0.0))
    _emit(args, out, [f"results in {args.out}"] + out.get("summary_lines", []))


def build_parser():
    p = argparse.ArgumentParser(prog="python -m garment_transfer",
                                description="Design-preserving garment transfer between body shapes.")
    p.add_argument("-v", "--verbose", action="store_true", help="log details on stderr")
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("transfer", help="move a garment from the source body onto a target body")
    t.add_argument("--source-body", required=True, help="OBJ: the body the garment is dressed on")
    t.add_argument("--target-body", required=True, help="OBJ: the same body mesh in the target shape")
    t.add_argument("--garment", required=True, action="append",
                   help="OBJ: the garment on the source body; repeat it for an outfit of several layers, "
                        "from the body out (each stays outside the ones before it)")
    t.add_argument("--out", required=True, action="append",
                   help="OBJ to write (the garment's own faces, new positions); for an outfit, one per "
                        "--garment in the same order, or one existing folder (files named as the garments)")
    t.add_argument("--method", choices=["direct", "model", "surface"], default="direct",
                   help="direct: the body's own deformation (default); model: a trained shared "
                        "deformation model; surface: follow the body only (baseline)")
    t.add_argument("--model", help="model file (.npz) for --method model")
    t.add_argument("--target", help="the model's target label for --method model")
    t.add_argument("--offset", type=float, default=None,
                   help="distance kept from the body (for an outfit: by each layer from what is under it), "
                        "in the files' units (default about 5 mm on a 1.7 m body: 0.25%% of its scale)")
    t.add_argument("--no-fix", action="store_true", help="skip the penetration fix (and the crossing pass)")
    t.add_argument("--no-crossing-pass", action="store_true",
                   help="skip the final pass that removes every garment edge through the body and body "
                        "edge through the garment (exact check)")
    t.add_argument("--no-interpolate", action="store_true",
                   help="nearest body triangle only when carrying the field (the paper)")
    t.add_argument("--json", action="store_true", help="print one JSON object")
    t.set_defaults(func=cmd_transfer)

    e = sub.add_parser("evaluate", help="quality figures of a transferred garment")
    e.add_argument("--source", required=True, help="OBJ: the garment on the source body")
    e.add_argument("--result", required=True, help="OBJ: the transferred garment")
    e.add_argument("--target-body", required=True, help="OBJ: the target body")
    e.add_argument("--reference", help="OBJ: the garment simulated/fitted on the target body")
    e.add_argument("--source-body", help="OBJ: the source body (drape error without a reference)")
    e.add_argument("--json", action="store_true", help="print one JSON object")
    e.set_defaults(func=cmd_evaluate)

    r = sub.add_parser("train", help="train a shared deformation model on a dataset folder")
    r.add_argument("--dataset", required=True, help="folder with bodies/ and garments/")
    r.add_argument("--source", required=True, help="source body name")
    r.add_argument("--targets", required=True, help="target body names, comma-separated")
    r.add_argument("--garments", help="garment names to train on, comma-separated (default: all)")
    r.add_argument("--epochs", type=int, default=1000)
    r.add_argument("--latent", type=int, default=30)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--unmasked", action="store_true", help="the paper's unmasked loss")
    r.add_argument("--out", required=True, help="model file to write (.npz)")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=cmd_train)

    b = sub.add_parser("bench", help="per-stage transfer times against the paper's")
    b.add_argument("--sizes", type=lambda s: [int(x) for x in s.split(",")],
                   default=[28000, 46000, 84000, 156000], help="garment triangle counts")
    b.add_argument("--repeats", type=int, default=3, help="runs per size (the best is kept)")
    b.add_argument("--targets", type=int, default=6, help="bodies in the multi-target run")
    b.add_argument("--report", metavar="DIR",
                   help="instead, the whole benchmark report (quality of every method on the demo data and "
                        "the MakeHuman fixtures, speed to 300K triangles, memory, training) into DIR")
    b.add_argument("--quick", action="store_true", help="with --report: tiny sizes and epochs (a smoke test)")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=cmd_bench)

    d = sub.add_parser("demo", help="the whole method on the built-in demo data")
    d.add_argument("--out", default="results", help="results folder (default: results)")
    d.add_argument("--quick", action="store_true", help="fewer garments and epochs")
    d.add_argument("--json", action="store_true", help="print one JSON object")
    d.set_defaults(func=cmd_demo)
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        args.func(args)
    except GarmentTransferError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0
