"""``python -m lab <command>``: the demo, the benchmarks and the studies (``--help`` on each)."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys

from garment_transfer.cli.options import number_option, stderr_progress
from garment_transfer.errors import GarmentTransferError
from garment_transfer.files import check_outputs, json_default

from .paths import data_folders

#: Commands that are whole scripts with their own options: name -> (module, what it does).
SCRIPTS = {
    "heldout": ("lab.heldout_makehuman", "leave-one-garment-out study of the model on the MakeHuman fixtures"),
    "training-scale": ("lab.training_scale", "training time at the paper's scale; optimiser comparison"),
    "make-data": ("lab.blender.make_demo_data", "regenerate the demo dataset with Blender's cloth solver"),
    "render": ("lab.blender.render_demo", "render a demo results folder with Blender (Cycles, CPU)"),
}


def _print(args, result, lines):
    if args.json:
        print(json.dumps(result, indent=2, default=json_default))
    else:
        print("\n".join(lines))


def cmd_demo(args):
    check_outputs(folders=[args.out], input_folders=data_folders(), holds_none=True)
    from .demo import run_demo

    out = run_demo(args.out, quick=args.quick, progress=stderr_progress("demo", every=0.0),
                   render=not args.no_render)
    _print(args, out, [f"results in {args.out}"] + out.get("summary_lines", []))


def cmd_bench(args):
    from .bench import format_bench, run_bench

    out = run_bench(sizes=args.sizes, repeats=args.repeats, targets=args.targets,
                    progress=stderr_progress("bench"))
    _print(args, out, format_bench(out))


def cmd_report(args):
    check_outputs(folders=[args.dir], input_folders=data_folders(), holds_none=True, what="the report folder")
    from .report import run_report

    command = (f"python -m lab report {args.dir}" + (" --quick" if args.quick else "")
               + (f" --only {','.join(args.only)}" if args.only else ""))
    try:
        out = run_report(args.dir, quick=args.quick, progress=stderr_progress("report"), command=command,
                         only=args.only)
    except ValueError as exc:
        raise SystemExit(f"error: {exc}") from None
    path = os.path.join(args.dir, "report.md")
    _print(args, {"report": path, "seconds": out["seconds"]},
           [f"wrote {path}, report.json and {', '.join(out['plots'])} in {out['seconds']['total']:.0f} s"])


_count = number_option(int, 1, what="a whole number")


def _sizes(text):
    parse = number_option(int, 3, what="a whole number")
    try:
        return [parse(x) for x in text.split(",")]
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"in {text!r}: {exc} (garment triangle counts, comma-separated)")


def _sections(text):
    from .report import SECTIONS

    names = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in names if x not in SECTIONS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: choose from {', '.join(SECTIONS)}")
    return names


def build_parser():
    p = argparse.ArgumentParser(prog="python -m lab", description="Garment Transfer's demo, benchmarks and studies.")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="the whole method on the built-in demo data (results/)")
    d.add_argument("--out", default="results", help="results folder (default: results)")
    d.add_argument("--quick", action="store_true", help="two garments, two targets, few epochs")
    d.add_argument("--no-render", action="store_true", help="skip the Blender renders")
    d.add_argument("--json", action="store_true", help="print one JSON object")
    d.set_defaults(func=cmd_demo)
    b = sub.add_parser("bench", help="transfer speed at the paper's garment sizes against the paper's times")
    b.add_argument("--sizes", type=_sizes, default=[28000, 46000, 84000, 156000], help="garment triangle counts")
    b.add_argument("--repeats", type=_count, default=3, help="runs per size (the best is kept)")
    b.add_argument("--targets", type=_count, default=6, help="bodies in the multi-target run")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=cmd_bench)
    r = sub.add_parser("report", help="the benchmark report: every method and baseline, speed, memory, training")
    r.add_argument("dir", help="folder to write report.md, report.json and the plots into")
    r.add_argument("--quick", action="store_true", help="tiny sizes and epochs (a smoke test)")
    r.add_argument("--only", type=_sections, help="measure only these sections again (comma-separated: "
                   "quality,speed,memory,training) and keep the others from DIR/report.json")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=cmd_report)
    for name, (_, text) in SCRIPTS.items():
        sub.add_parser(name, help=f"{text} (--help for its options)", add_help=False)
    return p


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in SCRIPTS:
        return importlib.import_module(SCRIPTS[argv[0]][0]).main(argv[1:]) or 0
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except GarmentTransferError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
