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
    from .obj import read_obj, write_obj
    from .registration import transfer_to_any_body

    t = time.perf_counter()
    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    garment = read_obj(args.garment)
    model = None
    if args.method == "model":
        if not args.model:
            raise GarmentTransferError("--method model needs --model MODEL.npz and --target LABEL")
        from .model import load_model

        model = load_model(args.model)
    load = time.perf_counter() - t
    result, registration = transfer_to_any_body(
        source_body, target_body, garment, cache=not args.no_cache, method=args.method, model=model,
        target=args.target, offset=args.offset, fix_penetration=not args.no_fix,
        interpolate=not args.no_interpolate)
    t = time.perf_counter()
    write_obj(args.out, garment, result.V,
              header=f"Garment Transfer: {os.path.basename(args.garment)} on "
                     f"{os.path.basename(args.target_body)} ({args.method})")
    seconds = dict(result.seconds, load=load, write=time.perf_counter() - t)
    out = {"out": args.out, "method": args.method, "target": args.target,
           "vertices": garment.n_vertices, "triangles": garment.n_triangles,
           "seconds": seconds, "penetrating_vertices": result.penetrating_vertices,
           "info": result.info, "registered": registration is not None}
    lines = [f"wrote {args.out}: {garment.n_vertices} vertices, {garment.n_faces} faces, "
             f"{result.penetrating_vertices} inside the target body, "
             f"{result.seconds['total']:.3f} s (transfer)"]
    if registration is not None:
        lines.append(_registration_line(args.source_body, args.target_body, registration))
    _emit(args, out, lines)


def _registration_line(source, target, reg):
    q = reg.quality
    return (f"registered {os.path.basename(source)} onto {os.path.basename(target)}"
            f"{' (cached)' if reg.cached else ''}: distance to the target mean {q['to_target_mean']:.4g}, "
            f"95% {q['to_target_p95']:.4g}, max {q['to_target_max']:.4g}; from the target mean "
            f"{q['from_target_mean']:.4g}, 95% {q['from_target_p95']:.4g}, max {q['from_target_max']:.4g} "
            f"(target units)")


def cmd_register(args):
    from .obj import read_obj, write_obj
    from .registration import register

    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    reg = register(source_body, target_body, cache=not args.no_cache,
                   progress=_stderr_progress("register") if args.verbose else None)
    write_obj(args.out, source_body, reg.V,
              header=f"Garment Transfer: {os.path.basename(args.source_body)} registered onto "
                     f"{os.path.basename(args.target_body)}")
    out = {"out": args.out, "source_body": args.source_body, "target_body": args.target_body,
           "vertices": source_body.n_vertices, **reg.summary()}
    _emit(args, out, [f"wrote {args.out}", _registration_line(args.source_body, args.target_body, reg)])


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
    t.add_argument("--target-body", required=True,
                   help="OBJ: the target body; the same mesh in another shape, or any body mesh of a "
                        "person in a similar pose (registered automatically, any units and axes)")
    t.add_argument("--garment", required=True, help="OBJ: the garment on the source body")
    t.add_argument("--out", required=True, help="OBJ to write (the garment's own faces, new positions)")
    t.add_argument("--method", choices=["direct", "model", "surface"], default="direct",
                   help="direct: the body's own deformation (default); model: a trained shared "
                        "deformation model; surface: follow the body only (baseline)")
    t.add_argument("--model", help="model file (.npz) for --method model")
    t.add_argument("--target", help="the model's target label for --method model")
    t.add_argument("--offset", type=float, default=None,
                   help="distance kept from the body, in the files' units "
                        "(default about 5 mm on a 1.7 m body: 0.25%% of its scale)")
    t.add_argument("--no-fix", action="store_true", help="skip the penetration fix")
    t.add_argument("--no-interpolate", action="store_true",
                   help="nearest body triangle only when carrying the field (the paper)")
    t.add_argument("--no-cache", action="store_true",
                   help="do not read or write the registration cache (see docs/registration.md)")
    t.add_argument("--json", action="store_true", help="print one JSON object")
    t.set_defaults(func=cmd_transfer)

    g = sub.add_parser("register", help="fit the source body onto any target body mesh (writes the "
                                        "source mesh in the target's shape)")
    g.add_argument("--source-body", required=True, help="OBJ: the source body (its mesh is kept)")
    g.add_argument("--target-body", required=True, help="OBJ: any body mesh of a person in a similar pose")
    g.add_argument("--out", required=True, help="OBJ to write: the source body in the target's shape")
    g.add_argument("--no-cache", action="store_true", help="do not read or write the registration cache")
    g.add_argument("--json", action="store_true", help="print one JSON object")
    g.set_defaults(func=cmd_register)

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
